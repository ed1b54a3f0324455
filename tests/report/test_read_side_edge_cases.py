"""Read-side commands (``report``, ``inspect``, ``diff``, ``migrate``) on unusual but legal stores: encodings with no
rows, hybrid probes that store no chain, probes that failed, a black capture, quantized encodings whose float
source holds other probes, unmeasured capture noise, moved probes, stores with no encoding in common; and the
report's output folder on a full disk. Figures are checked against h5py reads of the store and closed forms
(``schemas/store-v1.md``, ``schemas/store-reflection.md``), JSON with a parser that refuses NaN/Infinity."""

import json
import re
import shutil
import subprocess
import uuid
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import pytest

from bakery.environment.io import write_exr
from bakery.probe import Probe
from bakery.report import build_report, write_report
from bakery.store.format import read_store, write_store
from harness import bake_cubes, bake_image


def strict_json(text: str):
    """json.loads that raises on NaN / Infinity (what a strict consumer does)."""

    def refuse(constant: str):
        raise ValueError(f"non-strict JSON constant {constant}")

    return json.loads(text, parse_constant=refuse)


@dataclass
class Ran:
    returncode: int
    stdout: str
    stderr: str


def cli(*args) -> Ran:
    """The command line in this process (click's runner: the same code path without interpreter start-up)."""
    from click.testing import CliRunner

    from bakery.cli import main

    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=True)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return Ran(result.exit_code, result.stdout, result.stderr)


def h5_row_bytes(path: Path, encoding: str) -> dict[str, int]:
    """{field: bytes of one row} of an encoding's per-probe datasets, read with h5py (probe_index excluded)."""
    with h5py.File(path, "r") as f:
        group = f["encodings"][encoding]
        return {key: item.dtype.itemsize * int(np.prod(item.shape[1:], dtype=np.int64))
                for key, item in group.items() if isinstance(item, h5py.Dataset) and key != "probe_index"}


def h5_probe_count(path: Path, encoding: str) -> int:
    with h5py.File(path, "r") as f:
        return int(f["encodings"][encoding]["probe_index"].shape[0])


@pytest.fixture(scope="module")
def cube_store(tmp_path_factory) -> Path:
    """Four probes: two irradiance-only (zh3, zh3_deringed, zh3_quantized), two reflection-only (shexp and a
    shexp_hybrid whose α range needs no chain: first_level = L)."""
    d = tmp_path_factory.mktemp("read_side")
    rng = np.random.default_rng(7)
    cubes = rng.uniform(0.05, 1.0, size=(4, 6, 8, 8, 3)).astype(np.float32)
    probes = [Probe(f"/World/P/p{i}", kinds=("irradiance",) if i < 2 else ("reflection",), position=(i, 1.0, 0.0))
              for i in range(4)]
    bake_cubes(d / "s.h5", probes, cubes, encodings=("zh3", "zh3_deringed", "zh3_quantized", "shexp", "shexp_hybrid"),
               encoding_settings={"shexp_hybrid": {"alpha_min": 0.9, "keep_capture": False}})
    return d / "s.h5"


# --------------------------------------------------------------------------------------------------- memory
def test_memory_figures_are_the_stores_dataset_bytes_and_the_documented_sizes(cube_store):
    data, _ = build_report(cube_store, previews=False)
    strict_json(json.dumps(data, allow_nan=False))
    documented = {"zh3": 60, "zh3_deringed": 60, "zh3_quantized": 16, "shexp": 404}  # schemas: bytes per probe
    for name, entry in data["memory"]["encodings"].items():
        per_row = sum(h5_row_bytes(cube_store, name).values())
        rows = h5_probe_count(cube_store, name)
        assert entry["bytes_per_probe"] == per_row, name
        assert entry["probes"] == rows and entry["total_bytes"] == per_row * rows, name
        if name in documented:
            assert per_row == documented[name]
    kinds = {"irradiance": 2 * (60 + 60 + 16), "reflection": 2 * (404 + sum(h5_row_bytes(cube_store,
                                                                                          "shexp_hybrid").values()))}
    assert data["memory"]["total_bytes_per_kind"] == kinds


def test_a_hybrid_probe_without_chain_uploads_its_sh_exponential_and_lights_only(cube_store):
    """first_level = L: the levels are zero-filled in the store's fixed layout and not uploaded; the probe uploads
    the shexp_lights fields + first_level = 404 + 8·24 + 4 bytes (schemas/store-reflection.md)."""
    with h5py.File(cube_store, "r") as f:
        group = f["encodings/shexp_hybrid"]
        first = group["first_level"][()].reshape(-1)
        levels = sorted(k for k in group if k.startswith("level"))
        assert np.all(first == len(levels))  # no chain
        assert all(not np.any(group[k][()]) for k in levels)
    data, html = build_report(cube_store, previews=False)
    entry = data["memory"]["encodings"]["shexp_hybrid"]
    row_bytes = h5_row_bytes(cube_store, "shexp_hybrid")
    assert entry["bytes_per_probe"] == sum(row_bytes.values())  # the stored layout keeps every level
    assert entry["upload_bytes_per_probe"] == {"mean": 600.0, "min": 600, "max": 600}
    assert 404 + 8 * 24 + 4 == 600 == sum(v for k, v in row_bytes.items() if not k.startswith("level"))
    assert entry["upload_total_bytes"] == 2 * 600
    # an encoding without first_level uploads its whole row
    assert data["memory"]["encodings"]["shexp"]["upload_bytes_per_probe"]["mean"] == 404
    assert "uploaded bytes/probe" in html


def test_an_encoding_with_no_rows_is_in_the_memory_table_and_nowhere_else(cube_store, tmp_path):
    contents = read_store(cube_store)
    for name in ("zh3_deringed", "shexp"):
        contents.encodings[name]["fields"] = {k: v[:0] for k, v in contents.encodings[name]["fields"].items()}
        contents.diagnostics = {k: v for k, v in contents.diagnostics.items() if not k.endswith(f"/{name}")}
    path = write_store(tmp_path / "empty_rows.h5", contents)
    result = write_report(path, tmp_path / "rep")  # the irradiance errors, deringing and quantization used to raise
    data = strict_json(Path(result["json"]).read_text())
    for name in ("zh3_deringed", "shexp"):
        assert h5_probe_count(path, name) == 0
        assert data["memory"]["encodings"][name]["probes"] == 0
        assert data["memory"]["encodings"][name]["total_bytes"] == 0
        assert name not in data["errors"] and name not in data["negative_share"]
    assert "zh3_deringed" not in data["deringing"]
    # zh3_quantized's float source (zh3_deringed: its settings say dering) holds no probe: nothing to compare
    assert "zh3_quantized" not in data["quantization"]


def test_quantization_error_covers_only_the_probes_its_float_source_holds(cube_store, tmp_path):
    contents = read_store(cube_store)
    source = contents.encodings["zh3_deringed"]["fields"]
    contents.encodings["zh3_deringed"]["fields"] = {k: v[:1] for k, v in source.items()}  # probe 0 only
    contents.diagnostics = {k: v for k, v in contents.diagnostics.items() if not k.endswith("/zh3_deringed")}
    path = write_store(tmp_path / "subset.h5", contents)
    data, _ = build_report(path, previews=False)  # evaluating the source for probe 1 used to raise
    with h5py.File(path, "r") as f:
        quantized = f["encodings/zh3_quantized/probe_index"][()].tolist()
        deringed = f["encodings/zh3_deringed/probe_index"][()].tolist()
    q = data["quantization"]["zh3_quantized"]
    assert q["summary"]["count"] == len(set(quantized) & set(deringed)) == 1
    measured = [i for i, v in zip(quantized, q["per_probe"], strict=True) if v is not None]
    assert measured == deringed
    assert data["deringing"]["zh3_deringed"]["probes"] == 1


# --------------------------------------------------------------------------------------------------- failures
def test_failed_probes_are_listed_by_report_and_inspect(tmp_path):
    rng = np.random.default_rng(1)
    cubes = rng.uniform(0.05, 1.0, size=(3, 6, 4, 4, 3)).astype(np.float32)
    cubes[1] = 3e38  # overflows float32 when encoded: the probe fails and is left out of the store
    probes = [Probe(f"/World/P/p{i}", kinds=("irradiance",), position=(i, 0.0, 0.0)) for i in range(3)]
    bake_cubes(tmp_path / "s.h5", probes, cubes, encodings=("zh3",))
    with h5py.File(tmp_path / "s.h5", "r") as f:
        stored = [n.decode() for n in f["probes/name"][()]]
        failed = json.loads(f.attrs["failed_probes"])
    assert "/World/P/p1" in failed and "/World/P/p1" not in stored
    result = write_report(tmp_path / "s.h5", tmp_path / "rep", previews=False)
    assert strict_json(Path(result["json"]).read_text())["failed_probes"] == failed
    assert "Failed probes" in Path(result["html"]).read_text()
    shown = cli("inspect", tmp_path / "s.h5")
    assert shown.returncode == 0 and "/World/P/p1" in shown.stdout and "failed" in shown.stdout
    assert strict_json(cli("inspect", tmp_path / "s.h5", "--json").stdout)["failed_probes"] == failed


# --------------------------------------------------------------------------------------------------- black capture
def test_relative_errors_against_a_black_capture_are_unmeasured_not_zero(tmp_path):
    """A relative error against a reference that is 0 everywhere is 0/0 (the SH exponential leaves ~1e-12, an
    infinite relative error): null in the JSON, "not measured" on the page, never a made-up 0 (or "+0%")."""
    write_exr(tmp_path / "black.exr", np.zeros((16, 32, 3), np.float32), half=False)
    with pytest.warns(UserWarning, match="black"):
        bake_image(tmp_path / "black.exr", tmp_path / "b.h5", face_size=8, encodings=("zh3", "shexp"))
    result = write_report(tmp_path / "b.h5", tmp_path / "rep", previews=False)
    data = strict_json(Path(result["json"]).read_text())
    assert data["reference_available"] is True
    curves = data["reflection_alpha_curves"]
    for material in ("chrome", "glass"):
        assert all(v is None for row in curves["encodings"]["shexp"][material] for v in row)
        assert all(v is None for row in curves["bias"]["shexp"][material] for v in row)
    assert data["errors"]["shexp"]["summary"] == {"count": 0} and data["worst_probes"]["shexp"] == []
    html = Path(result["html"]).read_text()
    cells = re.findall(r"<td[^>]*>([^<]*)</td>", html)
    assert cells and not any(re.search(r"\bnan\b|\binf|[+-]0%", c, re.IGNORECASE) for c in cells)


# --------------------------------------------------------------------------------------------------- output folder
def test_report_into_a_folder_of_user_files_leaves_them_untouched(cube_store, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    (out / "data.json").write_text('{"mine": 1}')
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    write_report(cube_store, out, previews=False)
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.name in before} == before
    assert sorted(p.name for p in out.iterdir()) == ["data.json", "notes.txt", "report.html", "report.json"]


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs (root and a kernel that lets this process mount; skipped otherwise)."""
    mount = tmp_path / f"tiny-{uuid.uuid4().hex[:6]}"
    mount.mkdir()
    if shutil.which("mount") is None or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs",
                                                        str(mount)], capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    yield mount
    subprocess.run(["umount", str(mount)], capture_output=True)


def test_report_on_a_full_disk_leaves_no_folder_behind(tiny_disk):
    (tiny_disk / "filler").write_bytes(b"\0" * 60_000)
    result = cli("report", Path(__file__).parent / "missing.h5", "-o", tiny_disk / "a" / "b")
    assert result.returncode == 2  # (sanity: an unreadable store is refused before anything is created)
    assert sorted(p.name for p in tiny_disk.iterdir()) == ["filler"]
    store = tiny_disk.parent / "store.h5"
    rng = np.random.default_rng(0)
    bake_cubes(store, [Probe("/P", kinds=("irradiance",))], rng.uniform(0.1, 1, (1, 6, 4, 4, 3)).astype(np.float32),
               encodings=("sh3",))
    result = cli("report", store, "-o", tiny_disk / "a" / "b", "--no-previews")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "No space left" in lines[0]
    assert sorted(p.name for p in tiny_disk.iterdir()) == ["filler"]  # no empty a/b left behind


# --------------------------------------------------------------------------------------------------- inspect, diff
def test_inspect_json_is_strict_where_capture_noise_was_not_measured(cube_store, tmp_path):
    contents = read_store(cube_store)
    contents.diagnostics["capture/sh_noise"] = np.array([0.01, np.inf, np.nan, 0.02], dtype=np.float32)
    path = write_store(tmp_path / "noise.h5", contents)
    result = cli("inspect", path, "--probes", "*", "--json")
    assert result.returncode == 0, result.stderr
    rows = strict_json(result.stdout)  # inf / NaN used to be printed as Infinity / NaN
    assert [r["sh_noise"] for r in rows] == [pytest.approx(0.01), None, None, pytest.approx(0.02)]
    strict_json(cli("inspect", path, "--json").stdout)


def test_diff_of_a_copy_says_identical(cube_store, tmp_path):
    shutil.copy(cube_store, tmp_path / "copy.h5")
    result = cli("diff", cube_store, tmp_path / "copy.h5")
    assert result.returncode == 0 and result.stdout.startswith("identical: 4 probes, 5 encodings")
    report = strict_json(cli("diff", cube_store, tmp_path / "copy.h5", "--json").stdout)
    assert report["identical"] is True and report["unchanged"] == 4 and report["changed"] == {}


def test_diff_reports_moved_probes_and_probes_with_no_encoding_in_common(cube_store, tmp_path):
    contents = read_store(cube_store)
    contents.probe_positions = contents.probe_positions.copy()
    contents.probe_positions[0] += (0.0, 0.0, 2.5)
    moved = write_store(tmp_path / "moved.h5", contents)
    report = strict_json(cli("diff", cube_store, moved, "--json").stdout)
    with h5py.File(cube_store, "r") as a, h5py.File(moved, "r") as b:
        distance = float(np.linalg.norm(b["probes/position"][0] - a["probes/position"][0]))
    assert report["moved"] == {"/World/P/p0": pytest.approx(distance)} and distance == pytest.approx(2.5)
    assert report["identical"] is False and report["unchanged"] == 4  # same stored values

    only_irradiance = read_store(cube_store)
    only_irradiance.encodings = {k: v for k, v in only_irradiance.encodings.items() if k == "zh3"}
    only_reflection = read_store(cube_store)
    only_reflection.encodings = {k: v for k, v in only_reflection.encodings.items() if k == "shexp"}
    a = write_store(tmp_path / "irr.h5", only_irradiance)
    b = write_store(tmp_path / "refl.h5", only_reflection)
    report = strict_json(cli("diff", a, b, "--json").stdout)
    # every probe is in both stores, but no encoding is: nothing was compared, so nothing is "unchanged"
    assert report["unchanged"] == 0 and report["changed"] == {} and report["identical"] is False
    assert report["not_compared"] == [f"/World/P/p{i}" for i in range(4)]
    assert "not compared 4" in cli("diff", a, b).stdout
