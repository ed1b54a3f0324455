"""A minimal engine-side reader of a bakery baked layer: pxr + numpy only, no bakery import.

    python examples/engine_reader.py scene.bake.usda [normals.npy] [--stage-normals] [-o irradiance.npz]

It does what an engine's importer does (docs/engine-integration.md): find the prims with ``BakeryBakedProbeAPI``,
read each ``bakery:irradiance:<encoding>:<field>`` array with its customData ``shape`` and ``probeCount``, and
evaluate the irradiance exactly as bakery's shaders (bakery/shaders/bakery_core.glsl) and Python API do — here in
numpy, one function per stored layout. Prints a summary; with ``-o`` writes ``{"<prim>|<encoding>": (probeCount, N, 3)}``.

Directions: the arrays are in bakery's bake frame (right-handed, +Y up), so ``normals.npy`` holds bake-frame unit
normals and the summary's "+Y" is up, whatever the stage's axis. A Z-up layer's world (stage) direction (x, y, z) is
(x, z, −y) in the bake frame: with ``--stage-normals`` the normals (and the summary's "+Y") are in the stage's frame
instead (the layer's ``upAxis``, copied from the scene; :func:`stage_to_bake`). ``metersPerUnit`` plays no part.

The settings evaluation depends on are read from the layer too (``uniform bakery:settings:<encoding>:<key>``): the
hallucination ``curve`` (c2, c1) and the quantized layouts' ``sqrt_companding``; a layer without them (older bakes)
means the defaults, ``curve = (0.6, 0.08)`` and ``sqrt_companding = true``.
"""

from __future__ import annotations

import argparse
import sys
from math import pi, sqrt

import numpy as np
from pxr import Usd, UsdGeom

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
A0, A1, A2 = pi, 2.0 * pi / 3.0, pi / 4.0  # cosine-lobe band factors
PAPER_CURVE = (0.6, 0.08)  # ZH3 paper Eq. 21: f2^0 = (0.6 p² + 0.08 p) f0
BOUND_L1, BOUND_L2 = sqrt(3.0), sqrt(15.0) / 2.0
BOUND_ZONAL = (-sqrt(5.0) / 2.0, sqrt(5.0))


# ------------------------------------------------------------------------------------------------ reading
def read_layer(path: str) -> dict[str, dict[str, np.ndarray]]:
    """{prim path: {attribute name: (probeCount, *shape)}} for every prim carrying BakeryBakedProbeAPI (and the
    encodings' ``bakery:settings:…`` values)."""
    stage = Usd.Stage.Open(path)
    prims = {}
    for prim in stage.TraverseAll():
        # The authored apiSchemas list op: works whether or not bakery's schema plugin is registered
        # (PXR_PLUGINPATH_NAME=<bakery>/usd/schema makes GetAppliedSchemas() list it too).
        schemas = prim.GetMetadata("apiSchemas")
        if schemas is None or "BakeryBakedProbeAPI" not in schemas.GetAddedOrExplicitItems():
            continue
        values = {}
        for attr in prim.GetAttributes():
            parts = attr.GetName().split(":")
            if len(parts) != 4 or not attr.HasAuthoredValue():
                continue
            if parts[1] == "settings":  # uniform runtime settings of an encoding: plain values
                value = attr.Get()
                values[attr.GetName()] = tuple(value) if hasattr(value, "__len__") else value
                continue
            if parts[1] not in ("irradiance", "reflection"):
                continue
            shape = [int(d) for d in attr.GetCustomDataByKey("shape")]
            count = int(attr.GetCustomDataByKey("probeCount"))
            values[attr.GetName()] = np.asarray(attr.Get()).reshape([count, *shape])  # float3[] → (..., 3)
        prims[str(prim.GetPath())] = values
    return prims


def stage_to_bake(directions: np.ndarray, up_axis: str) -> np.ndarray:
    """Stage-frame directions (N, 3) → bake frame: a Z-up stage's (x, y, z) is (x, z, −y) (−90° about X); Y-up is
    unchanged (docs/engine-integration.md, "Frame")."""
    d = np.asarray(directions, dtype=np.float64)
    return np.stack([d[:, 0], d[:, 2], -d[:, 1]], axis=-1) if up_axis == "Z" else d


def layer_up_axis(path: str) -> str:
    """The layer's ``upAxis`` (bakery copies the scene's), "Y" when unauthored (UsdGeom's fallback)."""
    return str(UsdGeom.GetStageUpAxis(Usd.Stage.Open(path)))


# ------------------------------------------------------------------------------------------------ evaluation
def basis2(n: np.ndarray) -> np.ndarray:
    """Real SH bands 0–2 in bakery's convention (Y1,-1 = -c y, Y1,0 = c z, Y1,1 = -c x): (N, 3) → (N, 9)."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    c1, c2, c20, c22 = sqrt(3 / (4 * pi)), sqrt(15 / (4 * pi)), sqrt(5 / (16 * pi)), sqrt(15 / (16 * pi))
    return np.stack([np.full_like(x, 0.5 / sqrt(pi)), -c1 * y, c1 * z, -c1 * x, c2 * x * y, -c2 * y * z,
                     c20 * (3 * z * z - 1), -c2 * x * z, c22 * (x * x - y * y)], axis=-1)


def sh_irradiance(sh: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Radiance SH (P, 4 or 9, 3) → irradiance (P, N, 3): Σ_l A_l Σ_m f_lm Y_lm(n)."""
    factors = np.array([A0, A1, A1, A1, A2, A2, A2, A2, A2])[: sh.shape[1]]
    return np.einsum("nk,pkc->pnc", basis2(n)[:, : sh.shape[1]] * factors, sh)


def luminance_axis(sh: np.ndarray) -> np.ndarray:
    """Shared zonal axis (P, 3): normalize(Σ_c w_c (−f1,1, −f1,−1, f1,0)_c), (0, 0, 1) when it vanishes."""
    u = np.stack([-sh[:, 3] @ LUMINANCE, -sh[:, 1] @ LUMINANCE, sh[:, 2] @ LUMINANCE], axis=-1)
    norm = np.linalg.norm(u, axis=-1, keepdims=True)
    return np.where(norm > 1e-30, u / np.where(norm > 1e-30, norm, 1.0), [0.0, 0.0, 1.0])


def zh3_irradiance(sh: np.ndarray, zonal: np.ndarray, n: np.ndarray) -> np.ndarray:
    """sh2 term + (π/4) f2^0 √(5/16π)(3 (a·n)² − 1)."""
    t = luminance_axis(sh) @ n.T  # (P, N)
    return sh_irradiance(sh, n) + (A2 * sqrt(5 / (16 * pi)) * (3 * t * t - 1))[..., None] * zonal[:, None, :]


def hallucinated_zonal(sh: np.ndarray, curve=PAPER_CURVE) -> np.ndarray:
    """ZH3 paper Listing 1: p = |v_c·a| / f0_c, f2^0 = (c2 p² + c1 p) f0."""
    v = np.stack([-sh[:, 3], -sh[:, 1], sh[:, 2]], axis=1)  # (P, 3 xyz, 3 rgb)
    f0 = sh[:, 0]
    p = np.abs(np.einsum("pj,pjc->pc", luminance_axis(sh), v))
    p = np.where(f0 > 0, p / np.where(f0 > 0, f0, 1.0), 0.0)
    return (curve[0] * p * p + curve[1] * p) * f0


def hallucinated_solved_irradiance(fields: dict[str, np.ndarray], n: np.ndarray, curve=PAPER_CURVE) -> np.ndarray:
    """`zh3_hallucinated_solved`: Listing 1 with the zonal term times `zonal_scale` / 64 (version 1.2.0; 1.1.0
    stores carry a 0/1 flag `hallucinate` instead, 1.0.0 stores neither: scale 1)."""
    sh = fields["radiance_sh"].astype(np.float64)
    if "zonal_scale" in fields:
        scale = np.asarray(fields["zonal_scale"]).reshape(-1, 1) / 64.0
    else:
        scale = np.asarray(fields.get("hallucinate", np.ones((len(sh), 1)))).reshape(-1, 1).astype(np.float64)
    return zh3_irradiance(sh, hallucinated_zonal(sh, curve) * scale, n)


def small_float(code: np.ndarray, mantissa_bits: int) -> np.ndarray:
    """Unsigned float with a 5-bit exponent: the float16 whose bits are code << (10 − mantissa_bits)."""
    return (code.astype(np.uint32) << (10 - mantissa_bits)).astype(np.uint16).view(np.float16).astype(np.float64)


def unpack(packed: np.ndarray, bounds: list[tuple[float, float]], sqrt_companding: bool = True) -> np.ndarray:
    """uint8 layout (P, B) → radiance coefficients (P, 1 + len(bounds), 3): R11G11B10F DC + SNORM8 ratios × DC."""
    word = packed[:, :4].copy().view("<u4")[:, 0]
    f0 = np.stack([small_float(word & 0x7FF, 6), small_float((word >> 11) & 0x7FF, 6), small_float(word >> 22, 5)], -1)
    s = np.maximum(packed[:, 4:].copy().view(np.int8).reshape(len(packed), -1, 3) / 127.0, -1.0)  # −128 = −127
    t = s * np.abs(s) if sqrt_companding else s
    lo = np.array([b[0] for b in bounds])[None, :, None]
    hi = np.array([b[1] for b in bounds])[None, :, None]
    return np.concatenate([f0[:, None], t * np.where(t >= 0, hi, -lo) * f0[:, None]], axis=1)


ZH3_BOUNDS = [(-BOUND_L1, BOUND_L1)] * 3 + [BOUND_ZONAL]
SH3_BOUNDS = [(-BOUND_L1, BOUND_L1)] * 3 + [(-BOUND_L2, BOUND_L2)] * 2 + [BOUND_ZONAL] + [(-BOUND_L2, BOUND_L2)] * 2


def _radiance(fields: dict[str, np.ndarray], name: str) -> np.ndarray:
    return fields[name].astype(np.float64)


#: Encoding name → irradiance (P, N, 3) from its fields {field: (P, *shape)} at normals (N, 3) and its settings
#: {key: value} (absent: the defaults): the same table as bakery/shaders/manifest.json, in numpy.
EVALUATORS = {
    "sh2": lambda f, n, s: sh_irradiance(_radiance(f, "radiance_sh"), n),
    "sh3": lambda f, n, s: sh_irradiance(_radiance(f, "radiance_sh"), n),
    "zh3": lambda f, n, s: zh3_irradiance(_radiance(f, "radiance_sh"), _radiance(f, "zonal_l2"), n),
    "zh3_solved": lambda f, n, s: zh3_irradiance(_radiance(f, "radiance_sh"), _radiance(f, "zonal_l2"), n),
    "zh3_deringed": lambda f, n, s: zh3_irradiance(_radiance(f, "radiance_sh"), _radiance(f, "zonal_l2"), n),
    "zh3_hallucinated": lambda f, n, s: zh3_irradiance(
        _radiance(f, "radiance_sh"), hallucinated_zonal(_radiance(f, "radiance_sh"), s.get("curve", PAPER_CURVE)), n),
    "zh3_hallucinated_solved": lambda f, n, s: hallucinated_solved_irradiance(f, n, s.get("curve", PAPER_CURVE)),
    "zh3_quantized": lambda f, n, s: (lambda c: zh3_irradiance(c[:, :4], c[:, 4], n))(
        unpack(f["packed"], ZH3_BOUNDS, bool(s.get("sqrt_companding", True)))),
    "sh3_quantized": lambda f, n, s: sh_irradiance(
        unpack(f["packed"], SH3_BOUNDS, bool(s.get("sqrt_companding", True))), n),
}


def evaluate(encoding: str, fields: dict[str, np.ndarray], n: np.ndarray,
             settings: dict[str, object] | None = None) -> np.ndarray | None:
    """Irradiance (P, N, 3) of one encoding, or None for one this reader does not know (reflection encodings are
    evaluated by the shaders: bakery/shaders/)."""
    evaluator = EVALUATORS.get(encoding)
    return None if evaluator is None else evaluator(fields, n, settings or {})


def irradiance_of_layer(path: str, normals: np.ndarray) -> dict[str, np.ndarray]:
    """{"<prim>|<encoding>": irradiance (probeCount, N, 3)} for every irradiance encoding of the layer."""
    out = {}
    for prim, values in read_layer(path).items():
        by_encoding: dict[str, dict[str, np.ndarray]] = {}
        settings: dict[str, dict[str, object]] = {}
        for name, array in values.items():
            _, kind, encoding, field = name.split(":")
            if kind == "irradiance":
                by_encoding.setdefault(encoding, {})[field] = array
            elif kind == "settings":
                settings.setdefault(encoding, {})[field] = array
        for encoding, fields in sorted(by_encoding.items()):
            value = evaluate(encoding, fields, normals, settings.get(encoding))
            if value is not None:
                out[f"{prim}|{encoding}"] = value
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("layer")
    parser.add_argument("normals", nargs="?", help=".npy of unit normals (N, 3), bake frame (+Y up); default: the "
                        "six axes")
    parser.add_argument("--stage-normals", action="store_true",
                        help="the normals are in the stage's frame (the layer's upAxis), not the bake frame")
    parser.add_argument("-o", "--output", help="write the irradiance as .npz")
    args = parser.parse_args(argv)
    normals = np.load(args.normals) if args.normals else np.concatenate([np.eye(3), -np.eye(3)])
    normals = np.asarray(normals, dtype=np.float64)
    if args.stage_normals:
        normals = stage_to_bake(normals, layer_up_axis(args.layer))
    result = irradiance_of_layer(args.layer, normals)
    for key, value in result.items():
        print(f"{key}: {value.shape[0]} probe(s), irradiance at +Y {np.round(value[:, 1].mean(axis=0), 4)}"
              if not args.normals else f"{key}: {value.shape}")
    if args.output:
        np.savez(args.output, **result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
