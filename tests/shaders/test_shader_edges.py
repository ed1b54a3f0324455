"""The shader library against the Python API at the edges the store specification defines.

``test_shader_library.py`` renders baked example stores at generic rows. Here synthetic probes, encoded in memory by
the encoding classes of ``bakery/encodings/`` (the reference, with their ``evaluate_irradiance`` /
``evaluate_reflection``), are rendered by the same WebGL2 pipeline (``shader_pipeline.build_jobs`` on a small
in-memory store, one Chromium launch) at the rows where the rules of ``schemas/store-v1.md`` and
``schemas/store-reflection.md`` switch:

    α          0, 10⁻⁷, 1, the lights' floor 0.002, every `shexp_hybrid` chain level α, both edges of the E0 and E1
               blends, the crossovers, the `splitsum` level α's and every stored `alpha_range` end (the SH-exp clamp),
               each also 0.1 % below and above (float32-rounded: the GPU and the reference see the same α)
    view       v = n, n·v = 0.5 and 0.03, n·v = 0 exactly (axis-aligned pairs: 0 in float32 and float64), just below
               the horizon (−10⁻⁴), −0.3, −0.999 and v = −n bit for bit (the clamp's fixed tangent), normals with
               |n_x| > 0.9 and not (the two fixed-tangent branches)
    F0         0, 1 and a mixed RGB F0
    probes     a sky with a sun, a black probe, the same sky × 10⁴ (float16 chain levels clamped at 65504);
               `shexp_hybrid` probes with every first_level 0 … L (the levels below first_level keep their data
               here, so a shader that read them would be caught) and stored alpha_ranges other than the settings';
               quantized layouts with the DC at the R11G11B10F maximum, a denormal DC and the codes ±127, 0, −128

Tolerances are those of ``test_shader_library.py`` (docs/engine-integration.md §4): exact lookups 2⁻¹⁹ of the
probe's peak (+ 2⁻¹⁶ of the value for reflection), GPU filtering 2⁻⁸ of the peak.
"""

from __future__ import annotations

import contextlib
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import shader_pipeline
from bakery.encodings import ENCODINGS
from bakery.probe import ProbeBatch
from bakery.reflection.validation import check_directions
from bakery.sphere.cubemap import cube_texel_directions
from shader_pipeline import ULP_PEAK, build_jobs, chromium_binary, run_jobs, tolerance

#: Chain face size of the synthetic `shexp_hybrid` probes (levels α = 0, 0.144, 0.273, 0.496, 0.991).
HYBRID_FACE = 16
#: Stored `alpha_range`s other than the settings' (the SH-exp clamp must use the probe's own range).
ALPHA_RANGES = ((0.05, 0.6), (0.3, 0.9))


# ------------------------------------------------------------------------------------------------------ probes
class MemoryStore:
    """The part of :class:`bakery.api.ProbeStore` that ``shader_pipeline.build_jobs`` reads, over fields held in
    memory; evaluation is the encoding classes' own (the same code ``ProbeStore.evaluate_*`` runs)."""

    def __init__(self) -> None:
        self.encodings: dict[str, SimpleNamespace] = {}
        self._encoding: dict = {}
        self._fields: dict[str, dict[str, np.ndarray]] = {}

    def add(self, encoding, fields: dict[str, np.ndarray]) -> None:
        name = encoding.name
        self.encodings[name] = SimpleNamespace(settings=encoding.settings, kind=encoding.kind)
        self._encoding[name] = encoding
        count = len(next(iter(fields.values())))
        self._fields[name] = {**fields, "probe_index": np.arange(count, dtype=np.int32)}

    def fields(self, name: str) -> dict[str, np.ndarray]:
        return dict(self._fields[name])

    def shared(self, name: str) -> dict[str, np.ndarray]:
        return self._encoding[name].shared_tables()

    def _stored(self, name: str) -> dict[str, np.ndarray]:
        return {k: v for k, v in self._fields[name].items() if k != "probe_index"}

    def evaluate_irradiance(self, name: str, normals: np.ndarray) -> np.ndarray:
        return self._encoding[name].evaluate_irradiance(self._stored(name), check_directions(normals, "normals"))

    def evaluate_reflection(self, name, view, normal, alpha, f0) -> np.ndarray:
        return self._encoding[name].evaluate_reflection(self._stored(name), self.shared(name), view, normal, alpha, f0)


def sky_cubes(face: int) -> np.ndarray:
    """(3, 6, N, N, 3): a coloured sky with a sun (a light cluster for `shexp_lights`), black, the sky × 10⁴."""
    d = cube_texel_directions(face)
    sun = np.array([0.3, 0.8, 0.5]) / np.linalg.norm([0.3, 0.8, 0.5])
    sky = 0.5 + 0.4 * d[..., 1:2] * np.array([0.8, 0.9, 1.2]) + (d @ sun > 0.97)[..., None] * np.array([50.0, 45, 40])
    sky = sky.astype(np.float32)
    return np.stack([sky, np.zeros_like(sky), sky * np.float32(1e4)])


def _encode(name: str, batch: ProbeBatch, **params):
    encoding = ENCODINGS[name](**params)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the float16 clamps of the bright probe's chain levels
        return encoding, encoding.encode(batch)


def _packed_dc(r: int, g: int, b: int) -> np.ndarray:
    """The 4 DC bytes of R11G11B10F codes (r, g: 11 bits, b: 10 bits)."""
    return np.array([r | (g << 11) | (b << 22)], "<u4").view(np.uint8)


#: R11G11B10F codes: the largest finite values (65024, 65024, 64512) and the smallest denormal.
DC_MAX = (30 << 6 | 63, 30 << 6 | 63, 30 << 5 | 31)
DC_DENORMAL = (1, 1, 1)


def quantized_fields(size: int) -> np.ndarray:
    """(P, size) packed layouts: the DC at the format maximum with zero ratios, with extreme codes (±127, −128) and
    with random codes; the maximum in R only; a denormal DC; a black probe (all zero)."""
    rng = np.random.default_rng(7)
    ratios = size - 4
    extreme = np.resize(np.array([127, -127, -128, 0, 64, -64], np.int8), ratios)
    rows = [
        (DC_MAX, np.zeros(ratios, np.int8)),
        (DC_MAX, extreme),
        (DC_MAX, rng.integers(-127, 128, ratios).astype(np.int8)),
        ((DC_MAX[0], 700, 300), rng.integers(-127, 128, ratios).astype(np.int8)),
        (DC_DENORMAL, extreme[::-1].copy()),
        ((0, 0, 0), np.zeros(ratios, np.int8)),
    ]
    return np.stack([np.concatenate([_packed_dc(*dc), codes.view(np.uint8)]) for dc, codes in rows])


def edge_stores() -> dict[str, MemoryStore]:
    batch = ProbeBatch(sky_cubes(HYBRID_FACE))
    stores = {"edge": MemoryStore(), "paper": MemoryStore(), "levels": MemoryStore(), "linear": MemoryStore()}
    for name in ENCODINGS:
        if name in ("zh3_quantized", "sh3_quantized"):
            continue
        params = {"face_size": HYBRID_FACE} if name in ("splitsum", "shexp_hybrid") else {}
        encoding, fields = _encode(name, batch, **params)
        if name == "zh3_hallucinated_solved":  # the ends of the code range: 255 (s = 3.98) and 0 (sh2)
            fields["zonal_scale"] = np.array([[255], [64], [0]], np.uint8)
        if name in ("shexp", "shexp_lights", "shexp_hybrid"):  # probes 0 and 2: their own fitted range
            fields["alpha_range"] = np.array([ALPHA_RANGES[0], fields["alpha_range"][1], ALPHA_RANGES[1]],
                                             np.float32)
        stores["edge"].add(encoding, fields)
    stores["paper"].add(*_encode("shexp", batch, albedo_normalized=False))
    # shexp_hybrid: every first_level 0 … L of the sky and the bright sky; the whole chain is kept (not zero-filled)
    encoding, fields = _encode("shexp_hybrid", batch, face_size=HYBRID_FACE)
    levels = len(encoding.settings["level_alphas"])
    pick = np.array([0, 2] * (levels + 1))
    fields = {k: np.asarray(v)[pick] for k, v in fields.items()}
    fields["first_level"] = np.repeat(np.arange(levels + 1), 2)[:, None].astype(np.int32)
    stores["levels"].add(encoding, fields)
    for companding, label in ((True, "edge"), (False, "linear")):
        stores[label].add(ENCODINGS["zh3_quantized"](sqrt_companding=companding), {"packed": quantized_fields(16)})
        stores[label].add(ENCODINGS["sh3_quantized"](sqrt_companding=companding), {"packed": quantized_fields(28)})
    return stores


# ------------------------------------------------------------------------------------------------------ rows
def _unit(x) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    return x / np.linalg.norm(x)


#: Normals: generic ones, axes, and |n_x| > 0.9 (the other fixed-tangent branch of the horizon clamp).
NORMALS = [_unit(n) for n in ([0.3, 0.5, 0.81], [1, 0, 0], [0, 1, 0], [0, 0, -1], [-0.6, 0.2, -0.77],
                              [0.95, 0.1, -0.2], [0.05, -0.99, 0.1])]
#: n·v of the views (1: v = n; 0: an axis-aligned pair; −1: v = −n bit for bit; −1 + 5·10⁻⁷ and −1 + 5·10⁻¹¹:
#: views 10⁻³ and 10⁻⁵ rad from −n, whose tangent the horizon clamp must still follow).
COS_VIEW = (1.0, 0.5, 0.03, 0.0, -1e-4, -0.3, -0.999, -(1.0 - 5e-7), -(1.0 - 5e-11), -1.0)
F0S = (np.zeros(3), np.ones(3), np.array([0.04, 0.5, 1.0]))


def edge_alphas() -> np.ndarray:
    """α rows (float32 values as float64): 0, 10⁻⁷, 1, and each switching α of the specification 0.1 % below, at
    and above it."""
    hybrid = ENCODINGS["shexp_hybrid"](face_size=HYBRID_FACE).settings
    splitsum = ENCODINGS["splitsum"]().settings
    shexp = ENCODINGS["shexp"]().settings
    switching = [*hybrid["level_alphas"][1:], *hybrid["e0_blend"], *hybrid["e1_blend"], hybrid["crossover"],
                 hybrid["tail_crossover"], *splitsum["level_alphas"][1:], shexp["alpha_min"], 0.002,
                 *[a for r in ALPHA_RANGES for a in r]]
    values = [0.0, 1e-7, 1.0] + [a * s for a in switching for s in (1 - 1e-3, 1.0, 1 + 1e-3)]
    return np.unique(np.clip(np.float32(values), 0.0, 1.0)).astype(np.float64)


def reflection_rows() -> dict[str, np.ndarray]:
    """Every (α, n·v, F0) of the edges, the normal cycling through :data:`NORMALS`; float32 values as float64."""
    rows: dict[str, list] = {"view": [], "normal": [], "alpha": [], "f0": []}
    axes = [np.eye(3)[i] * sign for i in range(3) for sign in (1.0, -1.0)]
    k = 0
    for alpha in edge_alphas():
        for cos in COS_VIEW:
            for f0 in F0S:
                n = NORMALS[k % len(NORMALS)]
                t = _unit(np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 0.0, 1.0]))
                t = _unit(np.cross(t, n)) if k % 2 else t
                if cos == 0.0:
                    n, view = axes[k % 6], axes[(k + 2) % 6]
                elif cos == -1.0:
                    view = -np.float32(n)
                else:
                    view = cos * n + np.sqrt(1.0 - cos * cos) * t
                rows["view"].append(np.float32(view))
                rows["normal"].append(np.float32(n))
                rows["alpha"].append(np.float32(alpha))
                rows["f0"].append(np.float32(f0))
                k += 1
    return {key: np.asarray(value, np.float32).astype(np.float64) for key, value in rows.items()}


def irradiance_rows() -> dict[str, np.ndarray]:
    normals = np.concatenate([np.eye(3), -np.eye(3), shader_pipeline.fibonacci(26), [_unit([1, 1, 1])]])
    return {"normal": np.float32(normals).astype(np.float64)}


@contextlib.contextmanager
def edge_inputs():
    """``build_jobs`` evaluates at ``shader_pipeline``'s input rows: the edge rows instead, while building."""
    saved = shader_pipeline.irradiance_inputs, shader_pipeline.reflection_inputs
    irradiance, reflection = irradiance_rows(), reflection_rows()
    shader_pipeline.irradiance_inputs = lambda: irradiance
    shader_pipeline.reflection_inputs = lambda: reflection
    try:
        yield
    finally:
        shader_pipeline.irradiance_inputs, shader_pipeline.reflection_inputs = saved


# ------------------------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def stores():
    return edge_stores()


@pytest.fixture(scope="module")
def edge_run(stores, tmp_path_factory):
    if chromium_binary() is None:
        pytest.skip("headless Chromium is not installed (apt-get install -y chromium)")
    jobs = []
    with edge_inputs():
        for label, store in stores.items():
            store_jobs, missing = build_jobs(store, label, variants=("fetch", "sample"))
            assert not missing, f"{label}: no shader entry point for {missing}"
            jobs += store_jobs
    run = run_jobs(jobs, tmp_path_factory.mktemp("webgl_edges"))
    assert not run.errors, "\n".join(f"{k}: {v}" for k, v in run.errors.items())
    return jobs, run


def _row_labels(kind: str) -> np.ndarray:
    """A short description of each row (for failure messages)."""
    if kind == "irradiance":
        return np.array([f"n={np.round(n, 3).tolist()}" for n in irradiance_rows()["normal"]])
    rows = reflection_rows()
    cos = np.sum(rows["view"] * rows["normal"], axis=1)
    return np.array([f"alpha={a:.7g} n.v={c:+.4g}{' (v=-n)' if np.all(v == -n) else ''} f0={f.tolist()}"
                     for a, c, v, n, f in zip(rows["alpha"], cos, rows["view"], rows["normal"], rows["f0"],
                                              strict=True)])


def _failures(job, gpu: np.ndarray) -> list[str]:
    ref = job.reference
    bound = tolerance(ENCODINGS[job.encoding].kind, job.variant, ref)
    bad = ~(np.abs(gpu - ref) <= bound)  # NaN fails
    labels = _row_labels(ENCODINGS[job.encoding].kind)
    return [f"{job.id} probe {p} {labels[m]}: GPU {gpu[p, m].tolist()} API {ref[p, m].tolist()}"
            for p, m in zip(*np.nonzero(np.any(bad, axis=-1)), strict=True)]


# ------------------------------------------------------------------------------------------------------ tests
def test_the_rows_reach_every_edge(stores):
    """The rows and probes reach what the module doc lists (so that the comparisons below test the edges)."""
    rows = reflection_rows()
    alphas = set(rows["alpha"].tolist())
    hybrid = stores["edge"].encodings["shexp_hybrid"].settings
    switching = [*hybrid["level_alphas"][1:], *hybrid["e0_blend"], *hybrid["e1_blend"], 0.2, *ALPHA_RANGES[0],
                 *ALPHA_RANGES[1], 0.04, 0.16, 0.36, 0.64]
    for a in switching:
        a = float(np.float32(a))
        below = [b for b in alphas if a * (1 - 2e-3) < b < a]
        above = [b for b in alphas if a < b < a * (1 + 2e-3)]
        assert a in alphas and below and above, f"alpha {a}: not reached at, below and above"
    assert {0.0, 1.0} <= alphas
    cos = np.sum(rows["view"] * rows["normal"], axis=1)
    assert np.any(cos == 0.0) and np.any((cos < 0) & (cos > -1e-3))
    assert np.any(np.all(rows["view"] == -rows["normal"], 1)) and np.any(np.all(rows["view"] == rows["normal"], 1))
    assert np.any(np.all(rows["f0"] == 0.0, 1)) and np.any(np.all(rows["f0"] == 1.0, 1))
    first = np.asarray(stores["levels"].fields("shexp_hybrid")["first_level"]).reshape(-1)
    assert set(first.tolist()) == set(range(len(hybrid["level_alphas"]) + 1))  # every k0, k0 = L: no chain


@pytest.mark.parametrize("encoding", list(ENCODINGS))
def test_shaders_match_the_api_at_the_edges(edge_run, encoding):
    jobs, run = edge_run
    mine = [job for job in jobs if job.encoding == encoding]
    assert mine, f"no job for {encoding}"
    failures = [line for job in mine for line in _failures(job, run.results[job.id])]
    assert not failures, f"{len(failures)} rows outside the float32 tolerance:\n" + "\n".join(failures[:20])


def test_quantized_dc_at_the_format_maximum(edge_run):
    """DC codes at the R11G11B10F maximum decode to 65024 (R, G) and 64512 (B): with zero ratios E(n) = π·f0·Y00
    = f0·√π/2 for every normal (closed form), and the GPU gives it."""
    jobs, run = edge_run
    expected = np.array([65024.0, 65024.0, 64512.0]) * np.sqrt(np.pi) / 2.0
    for job in jobs:
        if job.encoding in ("zh3_quantized", "sh3_quantized"):
            np.testing.assert_allclose(job.reference[0], np.broadcast_to(expected, job.reference[0].shape),
                                       rtol=1e-12)
            np.testing.assert_allclose(run.results[job.id][0], job.reference[0], rtol=ULP_PEAK)


def test_black_probes_evaluate_to_zero(edge_run):
    """Black probes (closed form: E = 0): exactly 0 for the linear encodings and the chains; the SH exponentials
    store a very negative log-DC (exp of it ≈ 10⁻¹²; the black probe's lights have zero flux)."""
    jobs, run = edge_run
    for job in jobs:
        probe = {"zh3_quantized": 5, "sh3_quantized": 5}.get(job.encoding, 1)
        if job.store == "levels":
            continue
        gpu = run.results[job.id][probe]
        assert np.all(np.abs(job.reference[probe]) <= 1e-9), job.id
        assert np.all(np.abs(gpu) <= 1e-9), f"{job.id}: black probe gives {np.abs(gpu).max()}"
        if job.encoding in ("sh2", "sh3", "zh3", "zh3_quantized", "sh3_quantized", "splitsum"):
            assert np.all(gpu == 0.0), job.id


def test_the_reference_is_continuous_at_the_horizon(stores):
    """E(n·v = 0) equals E just above and just below the horizon (store-reflection.md: "E at n·v < 0 equals E at
    the clamped view and is continuous at n·v = 0"), here with a light cluster seen at a grazing view."""
    store = stores["edge"]
    light = np.asarray(store.fields("shexp_lights")["light_direction"])[0, 0].astype(np.float64)
    normal = np.array([0.0, 1.0, 0.0])
    away = _unit([-light[0], 0.0, -light[2]])  # on the horizon (n·v = 0 exactly), opposite the light's azimuth
    views = np.array([np.sqrt(1.0 - e * e) * away + e * normal for e in (1e-9, 0.0, -1e-9)])
    e = store.evaluate_reflection("shexp_lights", views, np.tile(normal, (3, 1)), 0.05, 1.0)[0]
    np.testing.assert_allclose(e[1], e[0], rtol=1e-4)
    np.testing.assert_allclose(e[1], e[2], rtol=1e-4)


def test_the_reference_lights_follow_the_half_vector_of_the_specification():
    """One light of flux 1, no SH-exp part (log-DC −200), F0 = 1: E = D(h)·V·⟨n, l⟩ with h = normalize(v + l) and
    l the stored (float32) direction as a unit vector (closed form), at a grazing view facing the light."""
    encoding = ENCODINGS["shexp_lights"]()
    stored = np.float32([0.3562906, 0.81437856, 0.45808795])  # |l| = 1 + 3.5·10⁻⁹ in float64
    light = stored.astype(np.float64) / np.linalg.norm(stored.astype(np.float64))
    tangent = _unit(np.cross(light, [1.0, 0.0, 0.0]))
    normal = 1e-3 * light + np.sqrt(1.0 - 1e-6) * tangent  # n·l = 10⁻³
    view = _unit(-light + 1e-4 * _unit(np.cross(normal, light)) + 2e-3 * normal)  # n·v ≈ 10⁻³, 1 + v·l ≈ 2·10⁻⁶
    p = np.zeros((1, 25, 3), np.float32)
    p[0, 0] = -200.0
    directions = np.tile(np.float32([0.0, 1.0, 0.0]), (1, 8, 1))
    directions[0, 0] = stored
    flux = np.zeros((1, 8, 3), np.float32)
    flux[0, 0] = 1.0
    fields = {"p": p, "q": np.zeros((1, 8, 3), np.float32), "alpha_range": np.float32([[0.2, 1.0]]),
              "light_direction": directions, "light_flux": flux}
    alpha = 0.05
    e = encoding.evaluate_reflection(fields, encoding.shared_tables(), view, normal, alpha, 1.0)[0, 0]
    a2 = alpha * alpha
    n_l, n_v = normal @ light, normal @ view
    n_h = normal @ _unit(view + light)
    d = a2 / (np.pi * (n_h * n_h * (a2 - 1.0) + 1.0) ** 2)
    v_term = 0.5 / (n_l * np.sqrt(n_v * n_v * (1 - a2) + a2) + n_v * np.sqrt(n_l * n_l * (1 - a2) + a2))
    np.testing.assert_allclose(e, d * v_term * n_l, rtol=1e-3)
