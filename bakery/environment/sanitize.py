"""Sanitising radiance: count and replace NaN, infinite and negative texels (pure numpy)."""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass

import numpy as np

from bakery.errors import SanitizedInputWarning


@dataclass(frozen=True)
class SanitizeReport:
    """Counts of texels (any channel) replaced by :func:`sanitize_radiance`, recorded in the store.

    Replacement rules: NaN → 0, −Inf → 0, negative → 0, +Inf → the largest finite value of that channel (0 if none).
    """

    texels: int
    nan: int
    positive_inf: int
    negative_inf: int
    negative: int
    min_value: float
    max_value: float

    @property
    def replaced(self) -> int:
        return self.nan + self.positive_inf + self.negative_inf + self.negative

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def sanitize_radiance(radiance: np.ndarray, source: str = "<array>") -> tuple[np.ndarray, SanitizeReport]:
    """Return a finite, non-negative float32 copy of ``radiance`` (..., C) and the counts of what was replaced.

    Emits :class:`SanitizedInputWarning` naming ``source`` when anything was replaced.
    """
    values = np.asarray(radiance, dtype=np.float32)
    flat = values.reshape(-1, values.shape[-1])
    lowest, highest = (float(flat.min()), float(flat.max())) if flat.size else (0.0, 0.0)
    if flat.size and 0.0 <= lowest and np.isfinite(highest):
        # the common case in two passes (min and max propagate NaN: both finite and the least ≥ 0 means nothing to
        # replace); the full count below takes seconds for an 8K latlong
        return values, SanitizeReport(texels=int(flat.shape[0]), nan=0, positive_inf=0, negative_inf=0, negative=0,
                                      min_value=lowest, max_value=highest)
    nan = np.isnan(flat)
    pos_inf = np.isposinf(flat)
    neg_inf = np.isneginf(flat)
    finite = np.isfinite(flat)
    negative = finite & (flat < 0)
    with np.errstate(invalid="ignore"):
        finite_values = np.where(finite, flat, np.nan)
        min_value = float(np.nanmin(finite_values)) if finite.any() else 0.0
        max_value = float(np.nanmax(finite_values)) if finite.any() else 0.0
    report = SanitizeReport(
        texels=int(flat.shape[0]),
        nan=int(nan.any(axis=1).sum()),
        positive_inf=int(pos_inf.any(axis=1).sum()),
        negative_inf=int(neg_inf.any(axis=1).sum()),
        negative=int(negative.any(axis=1).sum()),
        min_value=min_value,
        max_value=max_value,
    )
    if report.replaced == 0:
        return values, report
    channel_max = np.where(finite.any(axis=0), np.nanmax(np.where(finite, flat, -np.inf), axis=0), 0.0)
    cleaned = np.where(finite & (flat >= 0), flat, 0.0)
    cleaned = np.where(pos_inf, np.maximum(channel_max, 0.0)[None, :], cleaned).astype(np.float32)
    warnings.warn(
        f"{source}: replaced {report.nan} NaN, {report.positive_inf} +Inf, {report.negative_inf} -Inf and "
        f"{report.negative} negative texels of {report.texels} (NaN/-Inf/negative → 0, +Inf → channel maximum)",
        SanitizedInputWarning,
        stacklevel=2,
    )
    return cleaned.reshape(values.shape), report
