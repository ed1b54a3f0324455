"""The hybrid's sharp chain below its first kernel level, against the kernel applied exactly: ``bakery bench
sharp-chain`` (issue 12: "≤ 1.3× the idealised split-sum at every α", between the reflection bench's α points).

Protocol
    Environments: ``env_paths`` (HDR images), each resampled to the cube grid at ``face_size`` N
    (:func:`bakery.environment.resample_to_cube`): the capture every chain is built from.
    Chains: ``shexp_hybrid`` at N with no gap level, and with ``gap_level`` and G = 1 … ``max_gap_levels`` gap levels
    (α_1/2, α_1/4, …), each encoded from the capture and evaluated by its own ``evaluate_reflection`` at v = n (so
    r = n and n·v = 1) and F0 = 1: E = c(n, α)·(A + B)(1, α), c the chain read at α. Every α asked must lie below
    the E0 blend's lower end (0.178 at the defaults), where the hybrid is the chain alone (its SH-exponential part,
    fitted with a small design here, has weight 0).
    Reference: the capture prefiltered exactly at the α read (:func:`bakery.environment.reflection_reference.
    cube_prefiltered`: the normalised v = n GGX kernel integrated over every texel, converged) × the same (A + B).
    The radiance it filters is the capture as the runtime reconstructs it: with ``supersample`` S > 1 (default 4),
    the capture's bilinear reconstruction (:func:`bakery.sphere.cubemap.sample_cube_bilinear`, the read of every
    level and of the α = 0 level itself) resampled at S·N; S = 1: the texels as piecewise-constant radiance. The
    two differ where the kernel is narrower than a texel (the reflected lobe's width ≈ 2α against a texel's 2/N
    radians: α ≲ 1/N), and there the reconstruction, not the chain, decides the error (face 64, ``park``, α =
    0.003: the two references differ by a relative MSE of 0.34; 2026-12-07) — so rank chains at such α only
    against the reconstruction they are read with.
    Floor: a level prefiltered at exactly the α read, at N (:func:`bakery.reflection.splitsum.prefilter_level`,
    float32, bilinear): what a chain with a level at every α would give (not a strict bound: a blend of two levels
    can land closer to the reference).
    Metric: relative MSE Σ (E − E_ref)² / Σ E_ref² over ``directions`` Fibonacci directions, per environment;
    geometric mean over environments.

Returns a dict (``alphas``, ``level_alphas`` per chain, ``relative_mse`` per chain and α, per environment and
geometric mean); prints the table through ``echo``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

#: α read by default: below α_1/4 … α_1 at faces 64 and 128 (α_1 = 0.038 / 0.019).
DEFAULT_ALPHAS = (0.003, 0.005, 0.0075, 0.01, 0.015, 0.02, 0.03)
#: The SH-exponential part's design (unused below the E0 blend; small so that encoding is quick).
_SMALL_FIT = {"n_normals": 16, "n_views": 16, "fit_face_size": 8}
FLOOR = "level at exactly the α read"


def chain_encoders(face_size: int, max_gap_levels: int = 2) -> dict[str, object]:
    """{label: SHExpHybrid} at ``face_size``: no gap level, then G = 1 … ``max_gap_levels``."""
    from bakery.encodings.hybrid import SHExpHybrid

    encoders = {"no gap level": SHExpHybrid(face_size=face_size, **_SMALL_FIT)}
    for g in range(1, max_gap_levels + 1):
        encoders[f"gap_levels = {g}"] = SHExpHybrid(face_size=face_size, gap_level=True, gap_levels=g, **_SMALL_FIT)
    return encoders


def bilinear_reconstruction(cube: np.ndarray, supersample: int) -> np.ndarray:
    """The cube (6, N, N, C) as the runtime reads it (bilinear, :func:`bakery.sphere.cubemap.sample_cube_bilinear`)
    at the texel centres of an S·N cube → (6, S·N, S·N, C) float32; S = 1 returns the cube."""
    from bakery.sphere.cubemap import cube_texel_directions, sample_cube_bilinear

    if supersample == 1:
        return cube
    size = cube.shape[1] * supersample
    directions = cube_texel_directions(size).reshape(-1, 3)
    return sample_cube_bilinear(cube, directions).reshape(6, size, size, -1).astype(np.float32)


def run_sharp_chain_bench(env_paths: list[Path], face_size: int = 64, alphas: tuple[float, ...] = DEFAULT_ALPHAS,
                          directions: int = 600, max_gap_levels: int = 2, supersample: int = 4,
                          echo: Callable[[str], None] | None = print) -> dict:
    """Run the protocol (module doc) and return the result dict; the table goes through ``echo`` (None: silent)."""
    from bakery.environment import resample_to_cube
    from bakery.environment.io import read_environment
    from bakery.environment.reflection_reference import CubeTexels, cube_prefiltered
    from bakery.probe import ProbeBatch
    from bakery.reflection.splitsum import prefilter_level
    from bakery.reflection.tables import lookup_table
    from bakery.sphere.cubemap import sample_cube_bilinear
    from bakery.sphere.fibonacci import fibonacci_directions

    if not env_paths:
        raise ValueError("give at least one environment image")
    if not (isinstance(supersample, int) and supersample >= 1):
        raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
    encoders = chain_encoders(face_size, max_gap_levels)
    first = next(iter(encoders.values()))
    blend_low = first.blends[0][0]
    alphas = tuple(float(a) for a in alphas)
    if not all(0.0 < a < blend_low for a in alphas):
        raise ValueError(f"every alpha must be in (0, {blend_low:.3g}) (below the E0 blend, where the hybrid is its "
                         f"chain alone), got {alphas}")
    d = fibonacci_directions(directions)
    dfg = first.shared_tables()["dfg"]
    albedo = {a: lookup_table(dfg, np.ones(len(d)), np.full(len(d), a)).sum(axis=1)[:, None] for a in alphas}
    errors: dict[str, dict[float, list[float]]] = {name: {a: [] for a in alphas} for name in [*encoders, FLOOR]}
    for path in env_paths:
        cube = resample_to_cube(read_environment(Path(path))[0], face_size).astype(np.float32)
        texels = CubeTexels(bilinear_reconstruction(cube, supersample))
        fields = {name: enc.encode(ProbeBatch(cube[None])) for name, enc in encoders.items()}
        for a in alphas:
            reference = cube_prefiltered(texels, d, a) * albedo[a]
            energy = float(np.sum(reference**2))
            rows = np.full(len(d), a)
            for name, enc in encoders.items():
                e = enc.evaluate_reflection(fields[name], enc.shared_tables(), d, d, rows, np.ones(len(d)))[0]
                errors[name][a].append(float(np.sum((e - reference) ** 2)) / energy)
            level = prefilter_level(cube, a, face_size, first.chain)
            floor = sample_cube_bilinear(level, d) * albedo[a]
            errors[FLOOR][a].append(float(np.sum((floor - reference) ** 2)) / energy)

    def geomean(values: list[float]) -> float:
        return float(np.exp(np.mean(np.log(np.maximum(values, 1e-300)))))

    result = {
        "protocol": {"face_size": face_size, "directions": directions, "environments": [str(p) for p in env_paths],
                     "supersample": supersample,
                     "reference": ("the kernel applied exactly to the capture's bilinear reconstruction at "
                                   f"{supersample}x" if supersample > 1 else
                                   "the kernel applied exactly to the capture's texels (piecewise constant)"),
                     "metric": "relative MSE vs the kernel applied exactly at the alpha read, geometric mean"},
        "alphas": list(alphas),
        "level_alphas": {name: [float(x) for x in enc.chain.level_alphas()] for name, enc in encoders.items()},
        "relative_mse": {name: {str(a): {"geomean": geomean(v), "per_environment": v} for a, v in by_alpha.items()}
                         for name, by_alpha in errors.items()},
    }
    if echo is not None:
        echo(format_table(result))
    return result


def format_table(result: dict) -> str:
    """The geometric-mean table (Markdown): one row per chain and the floor, one column per α."""
    alphas = result["alphas"]
    protocol = result["protocol"]
    lines = [f"Sharp chain at face {protocol['face_size']}: relative MSE against {protocol['reference']} "
             f"(geometric mean over {len(protocol['environments'])} environments, {protocol['directions']} "
             "directions)", "",
             "| α read | " + " | ".join(f"{a:g}" for a in alphas) + " |",
             "|---|" + "---|" * len(alphas)]
    for name, by_alpha in result["relative_mse"].items():
        cells = " | ".join(f"{by_alpha[str(a)]['geomean']:.1e}" for a in alphas)
        lines.append(f"| {name} | {cells} |")
    lines += ["", "Level alphas: " + "; ".join(f"{name}: " + ", ".join(f"{x:.4g}" for x in la[:5]) + ", …"
                                              for name, la in result["level_alphas"].items())]
    return "\n".join(lines)
