"""``bakery report``: memory accounting closed forms, report contents on image and multi-probe stores, generic
pick-up of every registered encoding (including a test-only reflection encoding), atomic output, and the page
rendered by headless Chromium without console messages and with its plots present."""

import json
import re
import shutil
import struct
import subprocess
import tempfile
import zlib
from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.encodings import ENCODINGS, Encoding, FieldSpec, NoParams, register
from bakery.environment.io import write_exr
from bakery.errors import StoreFormatError
from bakery.probe import Probe
from bakery.report import build_report, write_report
from bakery.report.memory import ChainSettings, chain_bytes
from bakery.report.png import encode_png
from harness import bake_cubes, bake_image

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def sun_environment(path: Path, height: int = 32, sun: float = 200.0) -> Path:
    h, w = height, 2 * height
    rows = (np.arange(h) + 0.5) / h
    sky = np.zeros((h, w, 3), dtype=np.float32)
    sky[...] = np.array([0.3, 0.5, 1.0]) * (1.2 - rows)[:, None, None]
    sky[h // 2:] = np.array([0.2, 0.15, 0.1])
    sky[h // 4, w // 3] = sun
    write_exr(path, sky, half=False)
    return path


@pytest.fixture(scope="module")
def image_store(tmp_path_factory):
    d = tmp_path_factory.mktemp("report_image")
    env = sun_environment(d / "sun.exr")
    bake_image(env, d / "sun.h5", face_size=8,
               encodings=tuple(n for n, c in ENCODINGS.items() if c.kind == "irradiance"))
    return d / "sun.h5"


@pytest.fixture(scope="module")
def scene_store(tmp_path_factory):
    """Ten probes named like prim paths, synthetic captures (one with a bright 'lamp'), irradiance only."""
    d = tmp_path_factory.mktemp("report_scene")
    rng = np.random.default_rng(3)
    n = 8
    cubes = rng.uniform(0.05, 1.0, size=(10, 6, n, n, 3)).astype(np.float32)
    cubes[7, 2, 3, 3] = 5000.0  # a lamp in one probe: the worst probe for the low orders
    probes = [Probe(f"/World/Probes/probe_{i}", kinds=("irradiance",), position=(float(i), 1.0, 0.0))
              for i in range(10)]
    irradiance = tuple(n for n, c in ENCODINGS.items() if c.kind == "irradiance")
    bake_cubes(d / "scene.h5", probes, cubes, face_size=n, encodings=irradiance)
    return d / "scene.h5"


# --------------------------------------------------------------------------------------------------- closed forms
def test_split_sum_chain_bytes_closed_form():
    # N = 64, 6 levels, 32 minimum: cube faces 64, 32×5 → 6·(64² + 5·32²) = 55 296 texels.
    sizes = chain_bytes(ChainSettings(64, 6, 32))
    assert sizes["cube_rgba16f"] == 55_296 * 8 and sizes["cube_bc6h"] == 55_296
    # octahedral: 128² + 64² + 4·32² = 24 576 texels
    assert sizes["octahedral_rgba16f"] == 24_576 * 8 and sizes["octahedral_bc6h"] == 24_576
    # levels below a 4×4 block still cost a block
    assert chain_bytes(ChainSettings(2, 1, 1))["cube_bc6h"] == 6 * 16


def test_png_encoder_round_trip():
    rgb = np.random.default_rng(0).integers(0, 256, size=(5, 7, 3), dtype=np.uint8)
    data = encode_png(rgb)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = struct.unpack(">II", data[16:24])
    assert (w, h) == (7, 5)
    length = struct.unpack(">I", data[33:37])[0]
    raw = zlib.decompress(data[41:41 + length])
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(5, 1 + 7 * 3)
    assert np.all(rows[:, 0] == 0) and np.array_equal(rows[:, 1:].reshape(5, 7, 3), rgb)


# --------------------------------------------------------------------------------------------------- contents
def test_report_of_an_image_store_covers_every_stored_encoding(image_store, tmp_path):
    result = write_report(image_store, tmp_path / "rep")
    data = json.loads(Path(result["json"]).read_text())
    store = bakery.open_store(image_store)
    assert data["reference_available"] is True
    assert set(data["memory"]["encodings"]) == set(store.encodings)
    for name, info in store.encodings.items():
        entry = data["memory"]["encodings"][name]
        assert entry["bytes_per_probe"] == info.bytes_per_probe
        assert entry["total_bytes"] == info.bytes_per_probe * info.probe_count
        if info.kind == "irradiance":
            assert data["errors"][name]["summary"]["count"] == 1
            # the report's figure is the store's diagnostic
            assert data["errors"][name]["per_probe"][0] == pytest.approx(
                float(store.diagnostics[f"reference_error/{name}"][0]), rel=1e-6)
    # every quantized encoding is compared with a stored float source
    for name, q in data["quantization"].items():
        assert q["source"] in store.encodings and q["summary"]["max"] < 0.2
    html = Path(result["html"]).read_text()
    for plot in ("error-vs-memory", "error-distribution", "memory", "negative-share"):
        assert f'data-plot="{plot}"' in html
    assert 'alt="reference"' in html  # the diffuse sphere under the exact reference
    # self-contained: nothing is fetched (xmlns is a name, not a request)
    assert not re.search(r'(src|href)="(?!data:)|url\(', html) and "<script" not in html


def test_report_of_a_multi_probe_store_names_worst_probes(scene_store, tmp_path):
    data, html = build_report(scene_store)
    assert data["probes"] == 10 and data["reference_available"] is False
    # the probe with the lamp is the worst for linear SH (its error is dominated by the lamp's missing bands)
    assert data["worst_probes"]["sh2"][0]["probe"] == "/World/Probes/probe_7"
    assert data["previews"]["irradiance"]["worst"]["probe"] == "/World/Probes/probe_7"
    assert "/World/Probes/probe_7" in html
    # deringing removes every negative direction; the stored diagnostics are what the report shows
    if "zh3_deringed" in data["negative_share"]:
        assert data["negative_share"]["zh3_deringed"]["summary"]["max"] == 0.0
        assert data["deringing"]["zh3_deringed"]["before"] == "zh3"
        assert data["deringing"]["zh3_deringed"]["max_after"] == 0.0
    assert "No reflection encodings" in html or any(
        e["kind"] == "reflection" for e in data["memory"]["encodings"].values())


def test_report_with_a_single_encoding_and_no_reference_diagnostics(tmp_path):
    env = sun_environment(tmp_path / "e.exr", height=16)
    bake_image(env, tmp_path / "s.h5", face_size=4, encodings=("sh2",), reference_errors=False)
    data, html = build_report(tmp_path / "s.h5")
    # errors computed from the capture when the store has no diagnostics
    assert list(data["errors"]) == ["sh2"] and data["errors"]["sh2"]["summary"]["count"] == 1
    assert data["quantization"] == {} and data["reflection_alpha_curves"] == {}


def test_failed_report_leaves_existing_outputs_untouched(image_store, tmp_path):
    out = tmp_path / "rep"
    write_report(image_store, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    bad = tmp_path / "bad.h5"
    bad.write_bytes(image_store.read_bytes()[:1000])
    with pytest.raises(StoreFormatError, match="bad.h5"):
        write_report(bad, out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


# --------------------------------------------------------------------------------------------------- reflection
@pytest.fixture
def toy_reflection_encoding():
    """A test-only reflection encoding (mean radiance × F0), registered for the test and removed after it: checks
    that the report picks up reflection encodings from the registry without naming them."""

    class MeanRadiance(Encoding):
        name = "test_mean_radiance"
        kind = "reflection"
        description = "test only: mean radiance times F0"
        Params = NoParams

        def field_specs(self):
            return (FieldSpec("mean", (3,), "float32", "mean radiance"),)

        def encode(self, batch):
            return {"mean": batch.texels().mean(axis=1).astype(np.float32)}

        def evaluate_reflection(self, fields, shared, view, normal, alpha, f0):
            f0 = np.asarray(f0, float).reshape(len(view), -1)
            return fields["mean"].astype(float)[:, None, :] * f0[None]

    register(MeanRadiance)
    yield MeanRadiance.name
    ENCODINGS.pop(MeanRadiance.name, None)


REFLECTION = [n for n, c in ENCODINGS.items() if c.kind == "reflection"]
SMALL_SETTINGS = {"face_size": 8, "min_face_size": 4, "fit_face_size": 8}


@pytest.mark.slow
@pytest.mark.skipif(not REFLECTION, reason="no reflection encoding registered")
def test_report_with_every_registered_reflection_encoding(toy_reflection_encoding, tmp_path):
    """Every registered reflection encoding, and one registered by the test alone (the report names none of them),
    in one store and one report (one converged reference: the report's costliest part)."""
    env = sun_environment(tmp_path / "e.exr", height=16)
    settings = {}
    for name in REFLECTION:
        defaults = ENCODINGS[name]().settings
        settings[name] = {k: v for k, v in SMALL_SETTINGS.items() if k in defaults}
    encodings = (*REFLECTION, toy_reflection_encoding)
    bake_image(env, tmp_path / "s.h5", face_size=8, encodings=("sh2", *encodings), encoding_settings=settings)
    data, html = build_report(tmp_path / "s.h5")
    curves = data["reflection_alpha_curves"]
    for name in encodings:
        curve = curves["encodings"][name]
        assert all(len(curve[m][0]) == len(curves["alphas"]) for m in ("chrome", "glass"))
        assert all(np.isfinite(v) for m in ("chrome", "glass") for v in curve[m][0])
        assert data["errors"][name]["kind"] == "reflection"
        assert data["memory"]["ratios"][name]["vs_split_sum_cube_bc6h"] > 0
    assert 'data-plot="error-vs-memory-reflection"' in html
    assert 'data-plot="alpha-chrome"' in html and 'data-plot="alpha-glass"' in html
    assert "chrome α=0.25" in html and data["memory"]["probes_of_kind"]["reflection"] == 1


# --------------------------------------------------------------------------------------------------- chromium
def chromium_binary():
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("headless Chromium is not installed (apt-get install -y chromium chromium-driver)")


def run_chromium(url: str, *extra: str) -> subprocess.CompletedProcess:
    with tempfile.TemporaryDirectory() as profile:
        return subprocess.run([chromium_binary(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                               "--enable-logging=stderr", "--v=0", *extra, url],
                              capture_output=True, text=True, timeout=120)


def console_messages(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if ":CONSOLE" in line]


def test_console_capture_works(tmp_path):
    """The harness itself: a page that logs an error is caught (so 'no messages' below means something)."""
    page = tmp_path / "bad.html"
    page.write_text('<html><body><script>console.error("harness-check")</script></body></html>')
    result = run_chromium(page.as_uri(), "--dump-dom")
    assert any("harness-check" in m for m in console_messages(result.stderr)), result.stderr[-2000:]


def test_report_renders_in_headless_chromium(image_store, tmp_path):
    paths = write_report(image_store, tmp_path / "rep")
    url = Path(paths["html"]).resolve().as_uri()
    dom = run_chromium(url, "--dump-dom")
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert console_messages(dom.stderr) == []
    for plot in ("error-vs-memory", "error-distribution", "memory", "negative-share"):
        assert f'data-plot="{plot}"' in dom.stdout
    assert dom.stdout.count('src="data:image/png;base64,') >= 2
    shot = tmp_path / "shot.png"
    result = run_chromium(url, f"--screenshot={shot}", "--window-size=1280,1600")
    assert result.returncode == 0 and shot.stat().st_size > 20_000  # a blank page compresses to a few kB


# --------------------------------------------------------------------------------------------------- pareto bench
def test_pareto_front_flags_non_dominated_points():
    from bakery.bench.pareto import pareto_front

    points = [(1.0, 0.5), (2.0, 0.1), (3.0, 0.2), (1.0, 0.6), (0.5, 0.9)]
    assert pareto_front(points) == [True, True, False, False, True]


@pytest.mark.slow
def test_quick_pareto_bench_covers_the_registry_and_round_trips(tmp_path):
    from bakery.bench.pareto import compare_pareto, run_pareto_bench

    envs = tmp_path / "envs"
    envs.mkdir()
    sun_environment(envs / "a.exr", height=16)
    result = run_pareto_bench(envs, tmp_path / "out", quick=True, repeats=1)
    saved = json.loads((tmp_path / "out" / "pareto.json").read_text())
    assert saved["rows"] == json.loads(json.dumps(result["rows"]))
    assert {r["encoding"] for r in saved["rows"]} == set(ENCODINGS)
    ok = [r for r in saved["rows"] if "error" in r]
    assert all(np.isfinite(r["error"]["mean"]) and r["time_per_probe_s"]["warm"] > 0 for r in ok)
    for kind in {r["kind"] for r in ok}:
        assert any(r["pareto"] for r in ok if r["kind"] == kind)
    assert (tmp_path / "out" / "pareto_irradiance.svg").read_text().startswith("<svg")
    assert "| variant |" in (tmp_path / "out" / "pareto.md").read_text()
    same = compare_pareto(saved, saved)
    assert len(same) == len(ok) and all(c["time_ratio"] == 1.0 for c in same)


def test_report_page_shows_the_capture_noise_of_rendered_probes(tmp_path):
    """Issue 11: the relative SH noise each rendered capture achieved is on the page (summary + noisiest probes),
    equal to the store's ``capture/sh_noise`` and ordered noisiest first."""
    from usd_scenes import header, material, plane_mesh, probe, write

    text = (header() + material("Grey", diffuse=(0.5, 0.5, 0.5))
            + plane_mesh("Floor", 5.0, "/Grey")
            + '\ndef DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'
            + probe("Open", (0.0, 1.0, 0.0)) + probe("Low", (0.0, 0.05, 0.0)))
    scene = write(tmp_path / "noise.usda", text)
    bakery.bake(scene, tmp_path / "noise.h5", encodings=("sh3",), face_size=4, samples=2, bounces=1,
                resume=False)
    data, html = build_report(tmp_path / "noise.h5", previews=False)
    stored = np.asarray(bakery.api.open_store(tmp_path / "noise.h5").diagnostics["capture/sh_noise"])
    noise = data["capture_sh_noise"]
    assert noise["summary"]["count"] == 2 and np.isclose(noise["summary"]["max"], stored.max())
    assert [w["noise"] for w in noise["noisiest"]] == sorted(stored.tolist(), reverse=True)
    assert "Capture noise" in html and noise["noisiest"][0]["probe"] in html
