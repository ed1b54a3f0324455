"""PNG data URIs (:func:`bakery.png.encode_png`) and tone mapping for the report's preview images. Pure numpy + zlib.

Tone map (display-referred preview, not a measurement): x' = 1 − exp(−k·x) per channel with one exposure k per row
of images (so that images in a row are comparable), then the sRGB OETF. Negative radiance (SH ringing) cannot be
displayed; such pixels are painted magenta so that ringing stays visible.
"""

from __future__ import annotations

import base64

import numpy as np

from bakery.png import encode_png

#: Colour used for pixels whose value is negative in any channel.
NEGATIVE_COLOUR = np.array([255, 0, 255], dtype=np.uint8)


def png_data_uri(rgb: np.ndarray) -> str:
    return "data:image/png;base64," + base64.b64encode(encode_png(rgb)).decode("ascii")


def srgb_oetf(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def exposure_for(values: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Exposure k mapping the mean luminance of the (masked) finite, positive pixels to about 0.4 after tone mapping."""
    v = np.asarray(values, dtype=np.float64)
    lum = v[..., 0] * 0.2126 + v[..., 1] * 0.7152 + v[..., 2] * 0.0722
    if mask is not None:
        lum = lum[mask]
    lum = lum[np.isfinite(lum) & (lum > 0)]
    if lum.size == 0:
        return 1.0
    return float(0.5 / np.mean(lum))


def tone_map(values: np.ndarray, exposure: float, mask: np.ndarray | None = None,
             background: tuple[int, int, int] = (40, 40, 46)) -> np.ndarray:
    """(H, W, 3) radiance → uint8 sRGB; pixels outside ``mask`` get ``background``, negative ones magenta."""
    v = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=1e30, neginf=-1e30)
    mapped = srgb_oetf(1.0 - np.exp(-exposure * np.maximum(v, 0.0)))
    out = np.round(mapped * 255.0).astype(np.uint8)
    negative = np.any(v < 0, axis=-1)
    out[negative] = NEGATIVE_COLOUR
    if mask is not None:
        out[~mask] = np.array(background, dtype=np.uint8)
    return out
