"""Bad inputs through the real command line (``python -m bakery.cli`` in subprocesses): truncated or corrupt images
and stores, missing files, wrong attribute types, absurd header resolutions, unwritable outputs, broken USD scenes.

Every case must give a clear message naming the file (or prim), a non-zero exit code that says what kind of failure
it was (2 bad input, 3 bad settings, 5 check errors), no traceback, and leave existing outputs byte-identical.
"""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

import bakery
from bakery.environment.io import write_exr

EXISTING = b"previous output: must survive a failed run\n"


def run(*args, cwd=None) -> subprocess.CompletedProcess:
    env = {**os.environ, "SOURCE_DATE_EPOCH": "1700000000"}
    return subprocess.run([sys.executable, "-m", "bakery.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=300)


def assert_clean_failure(result: subprocess.CompletedProcess, code: int, *needles: str) -> None:
    assert result.returncode == code, (result.returncode, result.stderr[-3000:])
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    for needle in needles:
        assert needle in result.stderr + result.stdout, (needle, result.stderr[-3000:])


@pytest.fixture
def good_exr(tmp_path) -> Path:
    path = tmp_path / "good.exr"
    write_exr(path, np.random.default_rng(0).uniform(0.0, 2.0, size=(32, 64, 3)).astype(np.float32))
    return path


_ORIGINAL: dict[Path, bytes] = {}


@pytest.fixture
def existing(tmp_path, good_exr) -> Path:
    """A previous store at the output path, which a failed run must leave untouched (byte-identical)."""
    path = tmp_path / "existing.h5"
    bakery.bake(good_exr, path, face_size=4, encodings=("sh2",), reference_errors=False)
    _ORIGINAL[path] = path.read_bytes()
    return path


def untouched(path: Path) -> bool:
    return path.read_bytes() == _ORIGINAL[path]


def no_temporaries(directory: Path) -> bool:
    return not [p for p in directory.iterdir() if ".tmp" in p.name]


# ------------------------------------------------------------------------------------------------ images
def _truncated_exr(good: Path, d: Path) -> Path:
    p = d / "truncated.exr"
    p.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    return p


def _corrupt_exr(good: Path, d: Path) -> Path:
    data = bytearray(good.read_bytes())
    for i in range(400, len(data) - 8, 7):  # keep the header, scramble the compressed scanline chunks
        data[i] ^= 0x5A
    p = d / "corrupt.exr"
    p.write_bytes(bytes(data))
    return p


def _garbage_exr(good: Path, d: Path) -> Path:
    p = d / "garbage.exr"
    p.write_bytes(np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    return p


def _empty_hdr(good: Path, d: Path) -> Path:
    p = d / "empty.hdr"
    p.write_bytes(b"")
    return p


def _header_only_hdr(good: Path, d: Path) -> Path:
    p = d / "header_only.hdr"
    p.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 64 +X 128\n")
    return p


def _huge_hdr(good: Path, d: Path) -> Path:
    """A Radiance header claiming 200000 × 100000 = 2·10¹⁰ pixels (80 GB as float RGB)."""
    p = d / "huge.hdr"
    p.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 200000\n" + bytes(64))
    return p


def _huge_exr(good: Path, d: Path) -> Path:
    """A valid EXR whose dataWindow attribute is rewritten to claim 60000 × 30000 pixels (1.8·10⁹)."""
    data = bytearray(good.read_bytes())
    key = b"dataWindow\x00box2i\x00"
    at = data.index(key) + len(key)
    assert struct.unpack("<i", data[at:at + 4])[0] == 16
    data[at + 4:at + 20] = struct.pack("<iiii", 0, 0, 59999, 29999)
    key = b"displayWindow\x00box2i\x00"
    at = data.index(key) + len(key)
    data[at + 4:at + 20] = struct.pack("<iiii", 0, 0, 59999, 29999)
    p = d / "huge.exr"
    p.write_bytes(bytes(data))
    return p


def _odd_aspect(good: Path, d: Path) -> Path:
    p = d / "odd_aspect.exr"
    write_exr(p, np.ones((10, 37, 3), dtype=np.float32))
    return p


IMAGE_CASES = {
    "truncated_exr": (_truncated_exr, ()),
    "corrupt_exr": (_corrupt_exr, ()),
    "garbage_exr": (_garbage_exr, ()),
    "empty_hdr": (_empty_hdr, ()),
    "header_only_hdr": (_header_only_hdr, ()),
    "huge_hdr": (_huge_hdr, ()),
    "huge_exr": (_huge_exr, ("header",)),
}
IMAGE_CASES["odd_aspect"] = (_odd_aspect, ("layout",))


@pytest.mark.parametrize("case", list(IMAGE_CASES))
def test_bad_environment_images_fail_cleanly_and_keep_outputs(case, good_exr, existing, tmp_path):
    make, needles = IMAGE_CASES[case]
    bad = make(good_exr, tmp_path)
    result = run("bake", bad, "-o", existing, "-e", "sh2", "--face-size", "4")
    assert_clean_failure(result, 2, bad.name, *needles)
    assert untouched(existing) and no_temporaries(tmp_path)


def test_missing_environment_image(existing, tmp_path):
    result = run("bake", tmp_path / "nowhere.hdr", "-o", existing)
    assert_clean_failure(result, 2, "nowhere.hdr", "not found")
    assert untouched(existing)


def test_unknown_encoding_is_a_settings_error(good_exr, existing):
    result = run("bake", good_exr, "-o", existing, "-e", "no_such_encoding", "--face-size", "4")
    assert_clean_failure(result, 3, "no_such_encoding")
    assert untouched(existing)


@pytest.mark.parametrize("face_size", ["0", "-3", "100000"])
def test_absurd_face_size_is_a_settings_error(good_exr, existing, face_size):
    result = run("bake", good_exr, "-o", existing, "-e", "sh2", "--face-size", face_size)
    assert_clean_failure(result, 3, "face_size")
    assert untouched(existing)


# ------------------------------------------------------------------------------------------------ outputs
def test_output_directory_missing(good_exr, tmp_path):
    result = run("bake", good_exr, "-o", tmp_path / "no" / "such" / "dir" / "s.h5", "-e", "sh2", "--face-size", "4")
    assert_clean_failure(result, 2, "s.h5")


def test_output_is_a_directory(good_exr, tmp_path):
    target = tmp_path / "store.h5"
    target.mkdir()
    (target / "keep.txt").write_text("keep")
    result = run("bake", good_exr, "-o", target, "-e", "sh2", "--face-size", "4")
    assert_clean_failure(result, 2, "store.h5", "directory")
    assert (target / "keep.txt").read_text() == "keep"


def test_output_parent_is_a_file(good_exr, tmp_path):
    result = run("bake", good_exr, "-o", good_exr / "s.h5", "-e", "sh2", "--face-size", "4")
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr[-3000:]
    assert "s.h5" in result.stderr


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0,
                    reason="root ignores directory permissions; tests/faults/test_filesystems.py covers read-only "
                           "and immutable folders with a tmpfs")
def test_output_directory_not_writable(good_exr, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    (locked / "s.h5").write_bytes(EXISTING)
    locked.chmod(0o555)
    try:
        result = run("bake", good_exr, "-o", locked / "s.h5", "-e", "sh2", "--face-size", "4")
        assert_clean_failure(result, 2, "s.h5")
        assert (locked / "s.h5").read_bytes() == EXISTING
    finally:
        locked.chmod(0o755)


# ------------------------------------------------------------------------------------------------ stores (HDF5)
@pytest.fixture
def store(tmp_path, good_exr) -> Path:
    path = tmp_path / "good.h5"
    bakery.bake(good_exr, path, face_size=4, encodings=("sh2", "zh3"))
    return path


def _truncated(store: Path, d: Path) -> Path:
    p = d / "truncated.h5"
    p.write_bytes(store.read_bytes()[: store.stat().st_size // 2])
    return p


def _zeroed_superblock(store: Path, d: Path) -> Path:
    data = bytearray(store.read_bytes())
    data[:64] = bytes(64)
    p = d / "zeroed.h5"
    p.write_bytes(bytes(data))
    return p


def _foreign_hdf5(store: Path, d: Path) -> Path:
    p = d / "foreign.h5"
    with h5py.File(p, "w") as f:
        f["data"] = np.arange(3)
    return p


def _not_hdf5(store: Path, d: Path) -> Path:
    p = d / "text.h5"
    p.write_text("this is not HDF5\n")
    return p


def _edited(name: str, edit) -> callable:
    def make(store: Path, d: Path) -> Path:
        p = d / f"{name}.h5"
        shutil.copy(store, p)
        with h5py.File(p, "a") as f:
            edit(f)
        return p
    return make


def _newer_major(f):
    f.attrs["format_version"] = "9.0.0"


def _version_not_a_version(f):
    f.attrs["format_version"] = "banana"


def _missing_positions(f):
    del f["probes/position"]


def _bytes_per_probe_wrong_type(f):
    f["encodings/sh2"].attrs["bytes_per_probe"] = "forty-eight"


def _settings_not_json(f):
    f["encodings/sh2"].attrs["settings"] = "{not json"


STORE_CASES = {
    "truncated": (_truncated, ()),
    "zeroed_superblock": (_zeroed_superblock, ()),
    "foreign_hdf5": (_foreign_hdf5, ("not a bakery probe store",)),
    "not_hdf5": (_not_hdf5, ()),
    "newer_major": (_edited("newer", _newer_major), ("9.0.0", "upgrade")),
    "missing_positions": (_edited("no_positions", _missing_positions), ()),
}
#: Wrong attribute types that currently escape as Python exceptions (exit 1 + traceback): reported to the lead.
#: Malformed metadata (formerly known gaps, now StoreFormatError naming the file).
STORE_CASES_MALFORMED = {
    "version_not_a_version": (_edited("bad_version", _version_not_a_version), ()),
    "bytes_per_probe_wrong_type": (_edited("bad_bpp", _bytes_per_probe_wrong_type), ()),
    "settings_not_json": (_edited("bad_settings", _settings_not_json), ()),
}


@pytest.mark.parametrize("case", list(STORE_CASES) + list(STORE_CASES_MALFORMED))
def test_bad_stores_fail_cleanly_in_inspect(case, store, tmp_path):
    make, needles = {**STORE_CASES, **STORE_CASES_MALFORMED}[case]
    bad = make(store, tmp_path)
    before = bad.read_bytes()
    result = run("inspect", bad)
    assert_clean_failure(result, 2, bad.name, *needles)
    assert bad.read_bytes() == before


def test_missing_store(tmp_path):
    assert_clean_failure(run("inspect", tmp_path / "gone.h5"), 2, "gone.h5", "not found")


# ------------------------------------------------------------------------------------------------ report command
@pytest.mark.parametrize("case", ["truncated", "foreign_hdf5", "not_hdf5"])
def test_report_on_bad_store_keeps_previous_report(case, store, tmp_path):
    out = tmp_path / "rep"
    first = run("report", store, "-o", out)
    assert first.returncode == 0, first.stderr[-3000:]
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    bad = STORE_CASES[case][0](store, tmp_path)
    assert_clean_failure(run("report", bad, "-o", out), 2, bad.name)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_report_into_a_file_path(store, tmp_path):
    target = tmp_path / "report_is_a_file"
    target.write_bytes(EXISTING)
    assert_clean_failure(run("report", store, "-o", target), 2, target.name)
    assert target.read_bytes() == EXISTING


# ------------------------------------------------------------------------------------------------ USD scenes
@pytest.fixture
def usd_ok():
    import usd_scenes

    return usd_scenes


def test_truncated_usda_check_and_bake(usd_ok, tmp_path, existing):
    s = usd_ok
    full = s.header() + s.material("M") + s.box_mesh("Box", 1.0, "/M") + s.probe("P", (0, 3, 0))
    path = tmp_path / "truncated.usda"
    path.write_text(full[: len(full) * 2 // 3])
    check = run("check", path)
    assert check.returncode != 0 and "Traceback" not in check.stderr and "truncated.usda" in check.stdout + check.stderr
    bake = run("bake", path, "-o", existing)
    assert_clean_failure(bake, 2, "truncated.usda")
    assert untouched(existing)


def test_usda_syntax_error_is_one_line_naming_file_and_line(usd_ok, tmp_path, existing):
    """The parser's message (file:line:column and what it expected) on one line, without pxr's C++ location."""
    s = usd_ok
    text = s.header() + 'def Xform "A" (\n    kind = "component" stray\n)\n{\n}\n' + s.probe("P")
    path = s.write(tmp_path / "syntax.usda", text)
    line = text.splitlines().index('    kind = "component" stray') + 1
    bake = run("bake", path, "-o", existing)
    assert_clean_failure(bake, 2)
    errors = [row for row in (bake.stdout + bake.stderr).splitlines() if row.strip()]
    assert len(errors) == 1, errors
    assert f"syntax.usda:{line}:" in errors[0] and "stray" in errors[0], errors
    assert "pxrInternal" not in errors[0] and ".cpp" not in errors[0] and ".h " not in errors[0], errors
    assert untouched(existing)
    check = run("check", path)  # the same message as the issue of the scene's root
    assert check.returncode == 5 and f"syntax.usda:{line}:" in check.stdout and "pxrInternal" not in check.stdout


def test_missing_referenced_dome_texture_names_the_prim(usd_ok, tmp_path, existing):
    s = usd_ok
    path = s.write(tmp_path / "dome.usda",
                   s.header() + 'def DomeLight "Sky"\n{\n    asset inputs:texture:file = @./nowhere.hdr@\n}\n'
                   + s.probe("P"))
    check = run("check", path)
    assert check.returncode == 5 and "/Sky" in check.stdout and "nowhere.hdr" in check.stdout + check.stderr
    bake = run("bake", path, "-o", existing)
    assert bake.returncode != 0 and "Traceback" not in bake.stderr and "/Sky" in bake.stderr
    assert untouched(existing)


def test_missing_sublayer_is_reported(usd_ok, tmp_path):
    s = usd_ok
    text = s.header().replace("(", "(\n    subLayers = [@./missing_layer.usda@]", 1) + s.probe("P")
    path = s.write(tmp_path / "sub.usda", text)
    check = run("check", path)
    assert "Traceback" not in check.stderr
    assert "missing_layer.usda" in check.stdout + check.stderr


def test_wrong_attribute_type_names_the_prim(usd_ok, tmp_path, existing):
    s = usd_ok
    body = s.probe("P", (0, 3, 0)).replace("{", '{\n    string xformOp:translate = "up there"\n    uniform token[] '
                                           'xformOpOrder = ["xformOp:translate"]', 1)
    path = s.write(tmp_path / "types.usda", s.header() + body)
    check = run("check", path)
    assert "Traceback" not in check.stderr
    bake = run("bake", path, "-o", existing)
    if bake.returncode == 0:
        pytest.fail(f"a string-typed xformOp was baked silently: {bake.stderr[-2000:]}")
    assert "Traceback" not in bake.stderr and "/P" in bake.stderr
    assert untouched(existing)


@pytest.mark.parametrize("args,needle", [
    (["--volume", "2,x,2"], "'--volume'"), (["--volume", "2,2"], "3 comma-separated"),
    (["--volume", "2,0,2"], ">= 1"), (["--jobs", "a"], "'--jobs'"), (["--reflection", "-1"], "'--reflection'"),
])
def test_bench_scale_options_are_checked_before_any_work(tmp_path, args, needle):
    """Comma-separated counts were parsed with int() in the command: a ValueError traceback, exit 1."""
    result = run("bench", "scale", "-o", tmp_path / "out", *args)
    assert_clean_failure(result, 2, needle)
    assert not (tmp_path / "out").exists()


def test_a_folder_or_clashing_image_names_are_named_as_such(good_exr, existing, tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    shutil.copy(good_exr, tmp_path / "a" / "sky.exr")
    shutil.copy(good_exr, tmp_path / "b" / "sky.exr")
    assert_clean_failure(run("bake", tmp_path / "a", "-o", existing), 2, "a: is a directory, not an environment image")
    assert_clean_failure(run("bake", tmp_path / "a" / "sky.exr", tmp_path / "b" / "sky.exr", "-o", existing), 2,
                         str(tmp_path / "a" / "sky.exr"), str(tmp_path / "b" / "sky.exr"), "distinct file names")
    assert untouched(existing)


def test_encodings_no_probe_takes_are_a_settings_error(tmp_path):
    """``-e shexp`` on a scene of irradiance probes used to write an empty store and layer with exit 0."""
    from usd_scenes import box_mesh, header, material, probe, write

    text = header() + material("M", diffuse=(0.7, 0.7, 0.7), emissive=(1.0, 1.0, 1.0)) + box_mesh("Box", 2.0, "/M")
    scene = write(tmp_path / "irr.usda", text + probe("A", (0.2, 0.1, 0.0)))
    result = run("bake", scene, "-o", tmp_path / "irr.h5", "-e", "shexp", "--face-size", "4", "--samples", "1")
    assert_clean_failure(result, 3, "irr.usda", "shexp (reflection)", "irradiance probes")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["irr.usda"]
