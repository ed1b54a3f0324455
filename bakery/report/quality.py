"""Quality figures of a probe store: per-probe error against the reference, negative-irradiance share, quantization
error, per-α reflection error, and the worst/median probes. Everything is read through :mod:`bakery.api`.

Notation
    E_ref(n)    exact irradiance: brute-force cosine convolution of the probe's full-resolution capture
    relative RMSE  √Σ(E − E_ref)² / √ΣE_ref² over the store's quality directions (root ``settings``
                ``quality_directions``, 1024 by default: ``schemas/store-v1.md`` "Quality directions") and RGB
    relative MSE (reflection)  Σ(E − E_ref)² / ΣE_ref² over the (v, n) rows of one α and one F0 and RGB (seed 000
                Fig. 4–7 uses MSE; normalising by ΣE_ref² makes probes of different brightness comparable)
    bias (reflection)  ΣE / ΣE_ref − 1 over the same rows and RGB (signed brightness error)

Not measurable is not zero
    A relative figure against a reference that is 0 everywhere is NaN (null in the JSON, "–" on the page) and left
    out of every summary. The store's ``reference_error/<enc>`` diagnostics say 0 (encoding black too) or +inf
    (encoding not black) for a black reference (``schemas/store-v1.md``, ``/diagnostics``); the report reads both as
    not measurable (:func:`_measurable`).

Reflection reference (:func:`reference_reflection`)
    E0 = ∫ L f_DV ⟨n, l⟩ dl and E1 = ∫ L f_DV (1 − v·h)⁵ ⟨n, l⟩ dl of the capture's texels, each texel's radiance
    constant over its exact footprint ([SHExp] Eq. 5–8): the converged reference, the same code as the reflection
    bench's (:func:`bakery.environment.reflection_reference.environment_reflection`; method and measurements in
    :mod:`bakery.reflection.reference`, "Converged reference"). Texel centres, plus, for every texel where the GGX
    lobe is narrow on the texel's scale (small α, coarse images, grazing views), the texel's exact-footprint
    integral over adaptive sub-texels; α = 0 (the mirror): the texel containing r. A quadrature at texel centres
    alone made the figures wrong at small α on any image and at every α on small ones (a uniform 32 × 16 sky, which
    the encodings reproduce to ~1e-5, was reported at 0.85–0.94 at α = 0.02); the GGX importance sampling that
    replaced it for narrow lobes missed a sun in the lobe's tail. The page lists the method per α
    (:func:`reference_method`).

Reference availability
    A store baked from an environment image records its ``source``; the capture is then re-read (and sanitised the
    same way as in the bake) to compute references the store does not hold. It is used only if its flux ∫L dω
    equals the store's ``input/flux_source`` (the image the store was baked from, not another file of that name
    or the same file read with another layout; a fingerprint of three numbers: a mirrored or rotated copy of the
    image passes; an image given with ``--environment`` is used anyway, with a warning and the page saying so); a
    relative ``source`` is looked up from the working directory, then beside the store. Scene
    stores do not keep captures: their reference errors come only from the stored diagnostics and preview renders
    are shown without reference.

References
    [SHExp] Silvennoinen et al., HPG 2025 (seed 000).
"""

from __future__ import annotations

import json
import math
import warnings
import weakref
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from bakery.errors import UnsupportedEncodingWarning
from bakery.sphere.fibonacci import fibonacci_directions

#: Normals of the quality metrics when the store does not record its ``quality_directions`` (the bake's default).
QUALITY_DIRECTIONS = 1024
#: Relative tolerance of the re-read capture's flux against the store's ``input/flux_source``.
FLUX_TOLERANCE = 1e-4
#: GGX α of the per-α curves: the reflection bench's grid over the whole range (issue 12: 0 … 1, not only the paper's
#: α ≥ 0.25), α = 0 the mirror.
CURVE_ALPHAS = (0.0, 0.02, 0.04, 0.0625, 0.1, 0.16, 0.25, 0.36, 0.49, 0.64, 0.81, 1.0)
#: F0 of the chrome and glass spheres (seed 000 Fig. 4).
MATERIALS = {"chrome": 1.0, "glass": 0.04}


#: Stores already warned about, with the encodings skipped (one warning per store and encoding).
_WARNED: weakref.WeakKeyDictionary[Any, set[str]] = weakref.WeakKeyDictionary()


def evaluable(store: Any, name: str) -> bool:
    """Whether this bakery can evaluate the stored encoding ``name``. A store written by a newer bakery may hold an
    encoding this one does not know (or a newer major version of one): the report skips it in its quality figures
    and previews (it stays in the memory table) with an :class:`~bakery.errors.UnsupportedEncodingWarning`, once."""
    reason = store.unsupported_reason(name) if hasattr(store, "unsupported_reason") else None
    if reason is None:
        return True
    try:
        warned = _WARNED.setdefault(store, set())
    except TypeError:  # not weak-referenceable: warn every time
        warned = set()
    if name not in warned:
        warned.add(name)
        warnings.warn(f"{getattr(store, 'path', 'store')}: {reason}; skipped in the report's quality figures and "
                      "previews", UnsupportedEncodingWarning, stacklevel=2)
    return False


def encodings_of_kind(store: Any, kind: str) -> list[str]:
    """The stored encodings of ``kind`` that this bakery can evaluate (:func:`evaluable`) and that hold at least one
    probe (an encoding with no rows is legal: it is in the memory table, with nothing to measure)."""
    return [name for name, info in store.encodings.items()
            if info.kind == kind and info.probe_count > 0 and evaluable(store, name)]


def probe_rows(store: Any, encoding: str) -> np.ndarray:
    """Indices into ``store.probe_names`` of the rows of ``encoding``."""
    return np.asarray(store.fields(encoding)["probe_index"], dtype=np.int64)


def _per_probe(store: Any, key: str, encoding: str) -> np.ndarray | None:
    """A per-probe diagnostic as (P_k,) aligned with the encoding's rows (diagnostics may be (P,) or (P_k,))."""
    if key not in store.diagnostics:
        return None
    values = np.asarray(store.diagnostics[key], dtype=np.float64).reshape(len(store.diagnostics[key]), -1)[:, 0]
    rows = probe_rows(store, encoding)
    if values.shape[0] == len(store.probe_names):
        return values[rows]
    if values.shape[0] == rows.shape[0]:
        return values
    return None


def quality_directions(store: Any) -> int:
    """N of the store's quality directions (root ``settings`` JSON ``quality_directions``; 1024 when absent): the
    normals its ``reference_error`` / ``negative_fraction`` diagnostics were measured at, and the report's."""
    try:
        value = json.loads(str(store.attributes.get("settings") or "{}")).get("quality_directions")
    except (TypeError, ValueError, AttributeError):
        value = None
    return int(value) if isinstance(value, int) and value > 0 else QUALITY_DIRECTIONS


@dataclass
class CaptureReference:
    """The full-resolution capture of one probe: the image and its quadrature (one sample per texel, exact solid
    angles); ``texels`` is the image as the converged reflection reference reads it (module doc)."""

    image: Any  # bakery.environment.layouts.EnvironmentImage
    samples: Any  # bakery.sphere.grid.SphericalSamples
    path: str | None = None
    #: whether its flux equals the store's input/flux_source (None: the store has none, e.g. a scene store)
    flux_matches_store: bool | None = None
    _texels: Any = field(default=None, repr=False)
    #: the last few (E0, E1) by (α, rows): the previews ask for the same rows once per material
    _reflections: dict[tuple[float, bytes, bytes], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict,
                                                                                        repr=False)

    @property
    def texels(self) -> Any:
        """:class:`bakery.environment.reflection_reference.ImageTexels` of the image (built once)."""
        if self._texels is None:
            from bakery.environment.reflection_reference import ImageTexels

            self._texels = ImageTexels(self.image, self.samples)
        return self._texels

    @cached_property
    def black(self) -> bool:
        return not np.any(np.asarray(self.samples.radiance) > 0)


def load_reference_samples(store: Any, environment: str | Path | None = None) -> list[CaptureReference] | None:
    """Per-probe full-resolution captures (:class:`CaptureReference`), or None when no capture is available or the
    image found is not the one the store was baked from (module doc)."""
    if environment is not None and not Path(environment).is_file():
        from bakery.errors import ImageError

        raise ImageError(f"{environment}: environment image for the report's references not found")
    source = environment or store.attributes.get("source")
    if source is None or str(store.attributes.get("source_kind", "image")) == "usd" and environment is None:
        return None
    from bakery.errors import BakeryWarning

    if len(store.probe_names) != 1:
        if environment is not None:  # asked for, and not used: say so rather than report "no reference" silently
            warnings.warn(f"{environment}: --environment gives the capture of a one-probe store; "
                          f"{getattr(store, 'path', 'the store')} has {len(store.probe_names)} probes, so the report "
                          "uses their stored diagnostics only", BakeryWarning, stacklevel=2)
        return None
    candidates = [Path(str(source))]
    store_path = getattr(store, "path", None)
    if environment is None and not candidates[0].is_absolute() and store_path is not None:
        candidates.append(Path(store_path).parent / candidates[0])
    candidates = [c for c in dict.fromkeys(candidates) if c.is_file()]
    if not candidates:
        return None
    from bakery.environment.io import read_environment
    from bakery.environment.resample import environment_samples

    layout = store.attributes.get("source_layout")
    expected = (np.asarray(store.diagnostics["input/flux_source"], dtype=np.float64).reshape(-1, 3)[0]
                if "input/flux_source" in store.diagnostics else None)
    for path in candidates:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            image, _ = read_environment(path, layout=str(layout) if layout else None)
        samples = environment_samples(image)
        flux = np.asarray(samples.flux(), dtype=np.float64)
        matches = None if expected is None else bool(np.all(
            np.abs(flux - expected) <= FLUX_TOLERANCE * max(float(np.max(np.abs(expected))), 1e-30)))
        if matches is not False:
            return [CaptureReference(image, samples, str(path), matches)]
        mismatch = (f"{path}: not the image {getattr(store, 'path', 'the store')} was baked from (its flux "
                    f"{flux.round(6).tolist()} differs from the store's input/flux_source "
                    f"{expected.round(6).tolist()})")
        if environment is not None:  # asked for: used, and the page says it is not the baked image
            warnings.warn(f"{mismatch}; the report measures against it as asked (--environment)", BakeryWarning,
                          stacklevel=2)
            return [CaptureReference(image, samples, str(path), False)]
        warnings.warn(f"{mismatch}; not used as the report's reference", BakeryWarning, stacklevel=2)
    return None


def reference_irradiance_for(reference: Any, normals: np.ndarray) -> np.ndarray:
    from bakery.irradiance.reference import reference_irradiance

    samples = reference.samples if isinstance(reference, CaptureReference) else reference
    return reference_irradiance(samples, normals, dtype=np.float32)


def _relative_rmse(values: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(P,) relative RMSE of (P, N, C) against (P, N, C); NaN (not measurable: null in the JSON) where the reference
    is 0 everywhere (:func:`_ratio`)."""
    num = np.sqrt(np.sum((values - reference) ** 2, axis=(1, 2)))
    den = np.sqrt(np.sum(reference**2, axis=(1, 2)))
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


def black_references(store: Any, rows: np.ndarray) -> np.ndarray:
    """(len(rows),) bool: probes whose reference radiance is 0 everywhere, from the store's diagnostics (image bakes:
    ``input/flux_source`` = 0 in every channel; else ``band_energy`` of band 0 = 0, i.e. a capture with no DC: all
    zero, radiance being ≥ 0 after sanitising); False where the store does not say."""
    out = np.zeros(len(rows), dtype=bool)
    for key, black in (("input/flux_source", lambda v: np.all(v == 0, axis=1)),
                       ("band_energy", lambda v: v[:, 0] == 0)):
        if key in store.diagnostics:
            values = np.asarray(store.diagnostics[key], dtype=np.float64)
            values = values.reshape(len(values), -1)
            if values.shape[0] == len(store.probe_names):
                out |= np.asarray(black(values[rows]), dtype=bool) & np.all(np.isfinite(values[rows]), axis=1)
    return out


def _measurable(store: Any, values: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """A stored relative error with the not-measurable cases as NaN (module doc): +inf and anything against a black
    reference (the store writes 0 there when the encoding is black too)."""
    values = np.asarray(values, dtype=np.float64).copy()
    values[np.isinf(values) | black_references(store, rows)] = np.nan
    return values


def irradiance_errors(store: Any, references: list[Any] | None) -> dict[str, np.ndarray]:
    """{encoding: (P_k,) relative RMSE vs E_ref}: stored diagnostics, else computed from the capture at the store's
    quality directions; NaN where not measurable (module doc)."""
    out: dict[str, np.ndarray] = {}
    normals = fibonacci_directions(quality_directions(store))
    cache: dict[int, np.ndarray] = {}
    for name in encodings_of_kind(store, "irradiance"):
        rows = probe_rows(store, name)
        stored = _per_probe(store, f"reference_error/{name}", name)
        if stored is not None:
            stored = _measurable(store, stored, rows)
        if stored is not None and (references is None or np.all(np.isfinite(stored))):
            # NaN rows (probes baked without a reference, black references) stay NaN: unmeasured, not counted in
            # the summary, but the encoding is listed (with no measured probe: "–")
            out[name] = stored
            continue
        if references is None:
            continue
        ref = np.stack([cache.setdefault(int(i), reference_irradiance_for(references[i], normals)) for i in rows])
        out[name] = _relative_rmse(store.evaluate_irradiance(name, normals), ref)
    return out


def negative_shares(store: Any) -> dict[str, np.ndarray]:
    """{encoding: (P_k,) share of the store's quality directions where any channel's irradiance < 0} (stored, else
    computed at the same directions)."""
    normals = fibonacci_directions(quality_directions(store))
    out = {}
    for name in encodings_of_kind(store, "irradiance"):
        stored = _per_probe(store, f"negative_fraction/{name}", name)
        if stored is None:
            stored = np.mean(np.any(store.evaluate_irradiance(name, normals) < 0, axis=-1), axis=1)
        out[name] = np.asarray(stored, dtype=np.float64)
    return out


def quantization_source(store: Any, name: str) -> str | None:
    """The float encoding a quantized one was built from: ``<base>_quantized`` → ``<base>_deringed`` when its
    settings say ``dering``, else ``<base>``; None if that encoding is not stored."""
    if not name.endswith("_quantized"):
        return None
    base = name[: -len("_quantized")]
    candidates = ([f"{base}_deringed"] if store.encodings[name].settings.get("dering") else []) + [base]
    return next((c for c in candidates if c in store.encodings and evaluable(store, c)), None)


def quantization_errors(store: Any) -> dict[str, dict[str, Any]]:
    """{quantized: {"source", "relative_rmse": (P_k,)}} of quantized irradiance vs its float source, aligned with the
    quantized encoding's rows; NaN for a probe the source does not hold (each probe of a scene may list its own
    encodings)."""
    normals = fibonacci_directions(quality_directions(store))
    out = {}
    for name in encodings_of_kind(store, "irradiance"):
        source = quantization_source(store, name)
        if source is None:
            continue
        rows = probe_rows(store, name)
        shared = np.isin(rows, probe_rows(store, source))
        if not np.any(shared):
            continue
        names = [store.probe_names[i] for i in rows[shared]]
        quantized = store.evaluate_irradiance(name, normals, probes=names)
        reference = store.evaluate_irradiance(source, normals, probes=names)
        relative = np.full(len(rows), np.nan)
        relative[shared] = _relative_rmse(quantized, reference)
        out[name] = {"source": source, "relative_rmse": relative}
    return out


def curve_rows(count: int = 128, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic (v, n) pairs: Fibonacci normals, views uniform on each normal's hemisphere, those closer than
    n·v = 0.05 to the horizon tilted up to n·v = 0.05 exactly (same azimuth)."""
    n = fibonacci_directions(count)
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where(np.sum(v * n, axis=1, keepdims=True) < 0, -v, v)
    nv = np.sum(v * n, axis=1, keepdims=True)
    tangent = v - nv * n
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
    low = 0.05
    v = np.where(nv < low, low * n + np.sqrt(1.0 - low * low) * tangent, v)
    return v / np.linalg.norm(v, axis=1, keepdims=True), n


def reference_method(reference: CaptureReference, alpha: float) -> dict[str, Any]:
    """How :func:`reference_reflection` integrates at ``alpha`` (:func:`bakery.reflection.reference.reference_method`:
    {"method": "mirror" | "adaptive", "subdivision", "samples"})."""
    from bakery.reflection.reference import reference_method as method

    return method(reference.texels, alpha)


def reference_reflection(reference: Any, v: np.ndarray, n: np.ndarray, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """(E0, E1) (M, C) of the capture's texels at GGX ``alpha`` (module doc: the converged reference of
    :mod:`bakery.environment.reflection_reference`; bare samples without their image: texel centres)."""
    v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
    n = np.asarray(n, dtype=np.float64).reshape(-1, 3)
    if not isinstance(reference, CaptureReference):  # bare samples (no image): centres only, as before
        from scipy.spatial import cKDTree

        from bakery.reflection.reference import integrate_reflection, mirror_reflection

        if alpha > 0:
            return integrate_reflection(reference, v, n, np.full(len(v), alpha))
        tree = cKDTree(np.asarray(reference.directions, dtype=np.float64))
        return mirror_reflection(lambda d: np.asarray(reference.radiance, dtype=np.float64)[tree.query(d)[1]], v, n)
    if reference.black:
        channels = np.asarray(reference.samples.radiance).shape[1]
        return np.zeros((len(v), channels)), np.zeros((len(v), channels))
    from bakery.environment.reflection_reference import environment_reflection

    key = (float(alpha), v.tobytes(), n.tobytes())
    if key not in reference._reflections:
        if len(reference._reflections) >= 4:
            reference._reflections.pop(next(iter(reference._reflections)))
        reference._reflections[key] = environment_reflection(reference.texels, v, n, alpha)
    e0, e1 = reference._reflections[key]
    return e0.copy(), e1.copy()


def reflection_alpha_curves(store: Any, references: list[Any] | None, rows_per_alpha: int = 128) -> dict[str, Any]:
    """Per reflection encoding, material and α: relative MSE and signed brightness bias (Σ E / Σ E_ref − 1) vs the
    reference of the capture (:func:`reference_reflection`; needs the capture): ``encodings[name][material]`` and
    ``bias[name][material]``, each (P_k, len(alphas)); ``reference`` says how each α was integrated (first probe)."""
    names = encodings_of_kind(store, "reflection")
    if not names or references is None:
        return {}
    from bakery.reflection.reference import reflected_radiance

    v, n = curve_rows(rows_per_alpha)
    out: dict[str, Any] = {"alphas": list(CURVE_ALPHAS), "rows_per_alpha": rows_per_alpha, "encodings": {},
                           "bias": {}}
    first = references[0] if isinstance(references[0], CaptureReference) else None
    if first is not None:
        out["reference"] = [{"alpha": a, **reference_method(first, a)} for a in CURVE_ALPHAS]
    cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    for name in names:
        rows = probe_rows(store, name)
        per_material = {m: np.zeros((len(rows), len(CURVE_ALPHAS))) for m in MATERIALS}
        bias = {m: np.zeros((len(rows), len(CURVE_ALPHAS))) for m in MATERIALS}
        for j, alpha in enumerate(CURVE_ALPHAS):
            a = np.full(len(v), alpha)
            for r, i in enumerate(rows):
                key = (int(i), j)
                if key not in cache:
                    cache[key] = reference_reflection(references[i], v, n, alpha)
                e0, e1 = cache[key]
                for material, f0 in MATERIALS.items():
                    ref = reflected_radiance(e0, e1, np.full(len(v), f0))
                    est = store.evaluate_reflection(name, v, n, a, np.full(len(v), f0),
                                                    probes=[store.probe_names[i]])[0]
                    per_material[material][r, j] = _ratio(float(np.sum((est - ref) ** 2)), float(np.sum(ref**2)))
                    total = float(np.sum(ref))
                    bias[material][r, j] = _ratio(float(np.sum(est)) - total, total)
        out["encodings"][name] = {m: per_material[m].tolist() for m in MATERIALS}
        out["bias"][name] = {m: bias[m].tolist() for m in MATERIALS}
    return out


def _ratio(num: float, den: float) -> float:
    """num / den of a relative figure; NaN (not measurable: null in the JSON, "–" on the page) when den = 0, i.e. the
    reference is black over every row — never a made-up 0 (the SH-exponential fits leave ~1e-12 where the capture is
    black, which would be an infinite relative error)."""
    return num / den if den != 0 else math.nan


def alpha_table(curves: dict[str, Any]) -> list[dict[str, Any]]:
    """Rows of the report's per-α table: {"encoding", "material", "relative_mse": [per α, mean over the measured
    probes], "bias": [per α, mean over the measured probes]}; NaN (null) where no probe was measurable."""
    rows = []
    for name, per_material in curves.get("encodings", {}).items():
        for material, values in per_material.items():
            bias = curves.get("bias", {}).get(name, {}).get(material)
            rows.append({"encoding": name, "material": material, "relative_mse": _measured_mean(values),
                         "bias": _measured_mean(bias) if bias is not None else None})
    return rows


def _measured_mean(values: Any) -> list[float]:
    """Column means (probes × α → per α) over the finite entries: one black probe (NaN, not measurable) does not
    blank its α for every other probe."""
    v = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(v)
    count = finite.sum(axis=0)
    total = np.where(finite, v, 0.0).sum(axis=0)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan).tolist()


#: Preview role of the probe shown when no error of the kind was measured (it is neither "worst" nor "median").
UNRANKED_ROLE = "first (no error measured)"


def pick_probes(store: Any, errors: dict[str, np.ndarray], kind: str) -> dict[str, int]:
    """{"worst": probe, "median": probe} by the median over ``kind``'s encodings of each probe's measured error;
    {UNRANKED_ROLE: first probe of the kind} when no error of the kind was measured (not called worst or median)."""
    names = [n for n in encodings_of_kind(store, kind) if n in errors]
    rows = [i for i, k in enumerate(store.probe_kinds) if kind in k.split(",")]
    unranked = {UNRANKED_ROLE: rows[0]} if rows else {}
    if not names:
        return unranked
    score = np.full(len(store.probe_names), np.nan)
    stacks: dict[int, list[float]] = {}
    for name in names:
        for i, e in zip(probe_rows(store, name), errors[name], strict=True):
            stacks.setdefault(int(i), []).append(float(e))
    for i, values in stacks.items():  # median over the encodings that measured the probe
        finite = [x for x in values if math.isfinite(x)]
        score[i] = float(np.median(finite)) if finite else math.nan
    valid = np.flatnonzero(np.isfinite(score))
    if valid.size == 0:
        return unranked
    order = valid[np.argsort(score[valid], kind="stable")]
    return {"worst": int(order[-1]), "median": int(order[(len(order) - 1) // 2])}


def worst_probes(store: Any, errors: dict[str, np.ndarray], count: int = 5) -> dict[str, list[dict[str, Any]]]:
    """{encoding: up to ``count`` probes with the largest error, largest first}; unmeasured (NaN) probes are not
    listed (errors come through :func:`irradiance_errors` / :func:`reflection_alpha_curves`, where a black
    reference's 0 or +inf is NaN)."""
    out = {}
    for name, values in errors.items():
        rows = probe_rows(store, name)
        values = np.asarray(values, dtype=np.float64)
        measured = np.flatnonzero(~np.isnan(values))
        order = measured[np.argsort(-values[measured], kind="stable")][:count]
        out[name] = [{"probe": store.probe_names[rows[k]], "error": float(values[k]),
                      "position": [float(x) for x in store.probe_positions[rows[k]]]} for k in order]
    return out


def summarise(values: np.ndarray) -> dict[str, float]:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"count": 0}
    return {"count": int(v.size), "mean": float(v.mean()), "median": float(np.median(v)),
            "p90": float(np.percentile(v, 90)), "max": float(v.max()), "min": float(v.min())}
