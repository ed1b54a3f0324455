"""Bad input to the read/evaluate side of the Python API (``bakery.open_store``, ``ProbeStore.evaluate_*``,
``select_probes``) and to ``bakery inspect`` / ``bakery report``: every user mistake and every malformed store is a
:class:`bakery.errors.BakeryError` naming the argument or the store and the dataset/attribute (a one-line message and a
non-zero exit in the CLI), never a raw TypeError/KeyError/IndexError/AttributeError/NotImplementedError or a numpy
broadcast error; documented contracts keep their base classes (``ValueError`` naming ``alpha``, KeyError for unknown
names, NotImplementedError for the wrong kind). A store written by a newer bakery with an encoding this one does not
know still reports (the encoding is skipped with a warning)."""

from __future__ import annotations

import copy
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from harness import bake_cubes

import bakery
from bakery.encodings import ENCODINGS
from bakery.errors import (
    ArgumentError,
    BakeryError,
    EncodingKindError,
    EvaluationError,
    StoreFormatError,
    UnknownEncodingError,
    UnknownProbeError,
    UnsupportedEncodingWarning,
)
from bakery.probe import PROBE_KINDS, Probe
from bakery.sphere.cubemap import cube_texel_directions
from bakery.store.diff import diff_stores
from bakery.store.format import read_store, write_store

FACE = 8
IRRADIANCE = ("sh2", "zh3_hallucinated_solved")
REFLECTION = ("shexp", "shexp_lights", "splitsum", "shexp_hybrid")
SETTINGS = {"splitsum": {"min_face_size": 4}, **{n: {"fit_face_size": 8} for n in ("shexp", "shexp_lights",
                                                                                    "shexp_hybrid")}}
PROBES = [Probe(f"/probe_{i}", PROBE_KINDS, position=(float(i), 0.0, 0.0)) for i in range(3)]


def run(*args) -> subprocess.CompletedProcess:
    env = {**os.environ, "SOURCE_DATE_EPOCH": "1700000000"}
    return subprocess.run([sys.executable, "-m", "bakery.cli", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=300)


def assert_one_line_failure(result: subprocess.CompletedProcess, *needles: str) -> None:
    assert result.returncode not in (0, None), result.stderr[-3000:]
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), result.stderr[-3000:]
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


@pytest.fixture(scope="module")
def store_path(tmp_path_factory) -> Path:
    d = cube_texel_directions(FACE)
    sky = (0.5 + 0.5 * d[..., 1:2]) * np.array([0.2, 0.3, 0.6])
    cubes = np.stack([sky + 0.1 * i for i in range(len(PROBES))]).astype(np.float32)
    path = tmp_path_factory.mktemp("api_input") / "small.h5"
    bake_cubes(path, PROBES, cubes, encodings=IRRADIANCE + REFLECTION, jobs=1, encoding_settings=SETTINGS,
               reference_errors=False)
    return path


@pytest.fixture(scope="module")
def store(store_path):
    return bakery.open_store(store_path)


def rows(count: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = n + 0.5 * rng.normal(size=(count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True), n


# ------------------------------------------------------------------------------------------------ open_store (D12)
@pytest.mark.parametrize("path", [None, 5, 2.5, b"probes.h5", "", ["a.h5"]])
def test_open_store_rejects_what_is_not_a_path(path):
    with pytest.raises(ArgumentError, match="store path") as error:
        bakery.open_store(path)
    assert isinstance(error.value, BakeryError) and repr(path)[:10] in str(error.value)


def test_a_directory_is_not_reported_as_missing(tmp_path):
    with pytest.raises(StoreFormatError, match="is a directory") as error:
        bakery.open_store(tmp_path)
    assert str(tmp_path) in str(error.value) and "not found" not in str(error.value)


def test_a_directory_in_the_cli_is_a_one_line_error(tmp_path):
    assert_one_line_failure(run("inspect", tmp_path), str(tmp_path), "is a directory")


# ------------------------------------------------------------------------------------------------ names and kinds
@pytest.mark.parametrize("method", ["evaluate_irradiance", "evaluate_reflection", "fields", "shared", "rows"])
def test_an_encoding_the_store_does_not_hold(store, method):
    calls = {"evaluate_irradiance": lambda: store.evaluate_irradiance("zh3", [0.0, 1.0, 0.0]),
             "evaluate_reflection": lambda: store.evaluate_reflection("nope", [0, 0, 1], [0, 0, 1], 0.5, 0.04),
             "fields": lambda: store.fields("nope"), "shared": lambda: store.shared("nope"),
             "rows": lambda: store.rows("nope", None)}
    with pytest.raises(KeyError) as error:  # the documented KeyError still catches it
        calls[method]()
    assert isinstance(error.value, UnknownEncodingError) and isinstance(error.value, BakeryError)
    message = str(error.value)
    assert message.startswith(store.path) and "no encoding" in message and "sh2" in message  # stored names listed


@pytest.mark.parametrize("name, method", [(n, "irradiance") for n in REFLECTION]
                         + [(n, "reflection") for n in IRRADIANCE])
def test_the_wrong_kind_names_the_encoding_its_kind_and_the_method(store, name, method):
    kind = ENCODINGS[name].kind
    with pytest.raises(EncodingKindError) as error:
        if method == "irradiance":
            store.evaluate_irradiance(name, [0.0, 1.0, 0.0])
        else:
            store.evaluate_reflection(name, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], 0.5, 0.04)
    assert isinstance(error.value, NotImplementedError) and isinstance(error.value, BakeryError)
    message = str(error.value)
    assert store.path in message and name in message and kind in message and f"evaluate_{kind}" in message


@pytest.mark.parametrize("name", IRRADIANCE + REFLECTION)
def test_the_wrong_kind_on_an_encoding_object(store, name):
    encoding = ENCODINGS[name].from_settings(store.encodings[name].settings)
    with pytest.raises(EncodingKindError, match=name):
        if encoding.kind == "reflection":
            encoding.evaluate_irradiance({}, np.array([[0.0, 1.0, 0.0]]))
        else:
            encoding.evaluate_reflection({}, {}, np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]), 0.5, 0.04)


# ------------------------------------------------------------------------------------------------ probes / region
def test_probes_empty_gives_an_empty_result(store):
    v, n = rows(4)
    assert store.evaluate_irradiance("sh2", n, probes=[]).shape == (0, 4, 3)
    for name in REFLECTION:
        assert store.evaluate_reflection(name, v, n, 0.3, 0.04, probes=[]).shape == (0, 4, 3)


def test_probes_as_one_string_is_one_probe(store):
    v, n = rows(4)
    np.testing.assert_array_equal(store.evaluate_irradiance("sh2", n, probes="/probe_1"),
                                  store.evaluate_irradiance("sh2", n, probes=["/probe_1"]))
    assert store.evaluate_reflection("splitsum", v, n, 0.3, 0.04, probes="/probe_2").shape == (1, 4, 3)


@pytest.mark.parametrize("probes, error_type, needle", [
    (["/nowhere"], UnknownProbeError, "/nowhere"),
    (5, ArgumentError, "probes"),
    ([1, 2], ArgumentError, "probes"),
    ([["/probe_1"]], ArgumentError, "probes"),
])
def test_bad_probes(store, probes, error_type, needle):
    with pytest.raises(error_type, match=re.escape(needle)) as error:
        store.evaluate_irradiance("sh2", [0.0, 1.0, 0.0], probes=probes)
    assert isinstance(error.value, BakeryError)
    if error_type is UnknownProbeError:
        assert isinstance(error.value, KeyError) and store.path in str(error.value)


@pytest.mark.parametrize("region", [(0, 0, 0), (0, 0, 0, 1, 1, 1, 1), "0,0,0,1,1,1", (0, 0, 0, 1, None, 1),
                                    (0, 0, 0, 1, float("nan"), 1), 7])
def test_region_must_be_six_numbers(store, region):
    with pytest.raises(ArgumentError, match="region must be 6 numbers"):
        store.select_probes(region=region)


def test_region_and_pattern_select(store):
    assert store.select_probes(region=(0.5, -1, -1, 2.5, 1, 1)) == [1, 2]
    assert store.select_probes("/probe_[01]", region=[-np.inf] * 3 + [np.inf] * 3) == [0, 1]
    with pytest.raises(ArgumentError, match="pattern"):
        store.select_probes(pattern=3)


# ------------------------------------------------------------------------------------------ irradiance inputs (D12/D13)
@pytest.mark.parametrize("normals, needle", [
    (np.ones((3, 2)), "shape (N, 3)"),  # was reshaped to (2, 3) and evaluated
    (np.ones((2, 2, 3)), "shape (N, 3)"),
    (np.ones(6), "shape (N, 3)"),
    ([[0.0, 1.0, 0.0], [np.nan, 0.0, 1.0]], "finite"),
    ([0.0, np.inf, 0.0], "finite"),
    ([[0.0, 0.0, 0.0]], "non-zero length"),
    ("up", "numbers"),
    (None, "numbers"),
])
def test_bad_normals(store, normals, needle):
    with pytest.raises(EvaluationError, match="normals") as error:
        store.evaluate_irradiance("sh2", normals)
    assert isinstance(error.value, ValueError) and needle in str(error.value)


def test_normals_of_one_row_and_many_rows(store):
    _, n = rows(6)
    many = store.evaluate_irradiance("zh3_hallucinated_solved", n)
    assert many.shape == (3, 6, 3)
    np.testing.assert_array_equal(store.evaluate_irradiance("zh3_hallucinated_solved", n[2]), many[:, 2:3])
    # a float32 unit normal evaluates as the same values in float64
    np.testing.assert_array_equal(store.evaluate_irradiance("sh2", n.astype(np.float32)),
                                  store.evaluate_irradiance("sh2", n.astype(np.float32).astype(np.float64)))


@pytest.mark.parametrize("scale", [1e-200, 1e-3, 10.0, 1e200])
def test_only_the_direction_of_normals_and_views_counts(store, scale):
    """Directions are normalised by the reader, as a shader's normalize() would (before: sh2 irradiance 6x at
    |n| = 10, shexp 0 at |n| = 10 and +inf at |v| = 10, NaN or an IndexError at components of 1e200)."""
    v, n = rows(6)
    for name in IRRADIANCE:
        np.testing.assert_allclose(store.evaluate_irradiance(name, n * scale), store.evaluate_irradiance(name, n),
                                   rtol=1e-12, atol=0, err_msg=name)
    for name in REFLECTION:
        unit = store.evaluate_reflection(name, v, n, 0.3, 0.04)
        for view, normal in ((v * scale, n), (v, n * scale)):
            np.testing.assert_allclose(store.evaluate_reflection(name, view, normal, 0.3, 0.04), unit, rtol=1e-9,
                                       atol=0, err_msg=name)


@pytest.mark.parametrize("normal", [np.array([0.0, 1.0, 0.0]) + 0.5j, np.array([False, True, False])])
def test_complex_and_boolean_arguments_are_refused(store, normal):
    """numpy would drop an imaginary part (with only a ComplexWarning) and read True as 1."""
    with pytest.raises(EvaluationError, match="normals must be numbers"):
        store.evaluate_irradiance("sh2", normal)
    with pytest.raises(EvaluationError, match="alpha must be numbers"):
        store.evaluate_reflection("shexp", [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], normal.any(), 0.04)


# ---------------------------------------------------------------------------------------------- reflection inputs (D13)
BAD_REFLECTION = {  # (view, normal, alpha, f0) → the argument the message must name
    "f0_nan": (lambda v, n: (v, n, 0.3, np.nan), "f0"),
    "f0_above_one": (lambda v, n: (v, n, 0.3, np.full(len(v), 1.5)), "f0"),
    "f0_negative": (lambda v, n: (v, n, 0.3, -0.1), "f0"),
    "f0_inf_rgb": (lambda v, n: (v, n, 0.3, np.tile([0.1, np.inf, 0.1], (len(v), 1))), "f0"),
    "f0_rgb_as_1d_one_row": (lambda v, n: (v[:1], n[:1], 0.3, np.array([0.9, 0.6, 0.5])), "f0"),
    "f0_wrong_length": (lambda v, n: (v, n, 0.3, np.full(len(v) + 1, 0.04)), "f0"),
    "f0_wrong_channels": (lambda v, n: (v, n, 0.3, np.full((len(v), 4), 0.04)), "f0"),
    "f0_text": (lambda v, n: (v, n, 0.3, "glass"), "f0"),
    "alpha_nan": (lambda v, n: (v, n, np.nan, 0.04), "alpha"),
    "alpha_above_one": (lambda v, n: (v, n, np.full(len(v), 1.5), 0.04), "alpha"),
    "alpha_wrong_length": (lambda v, n: (v, n, np.full(len(v) + 2, 0.3), 0.04), "alpha"),
    "alpha_2d": (lambda v, n: (v, n, np.full((len(v), 2), 0.3), 0.04), "alpha"),
    "view_last_axis_2": (lambda v, n: (np.ones((3, 2)), np.ones((3, 2)), 0.3, 0.04), "view"),
    "normal_last_axis_2": (lambda v, n: (v, np.ones((len(v), 2)), 0.3, 0.04), "normal"),
    "view_normal_rows_differ": (lambda v, n: (v[:2], n, 0.3, 0.04), "view and normal"),
    "view_nan": (lambda v, n: (np.where(np.arange(len(v))[:, None] == 1, np.nan, v), n, 0.3, 0.04), "view"),
    "normal_zero": (lambda v, n: (v, np.zeros_like(n), 0.3, 0.04), "normal"),
}


@pytest.mark.parametrize("case", list(BAD_REFLECTION))
@pytest.mark.parametrize("name", REFLECTION)
def test_bad_reflection_inputs_through_the_api(store, name, case):
    make, argument = BAD_REFLECTION[case]
    view, normal, alpha, f0 = make(*rows(5))
    with pytest.raises(ValueError, match=argument) as error:  # the documented ValueError …
        store.evaluate_reflection(name, view, normal, alpha, f0)
    assert isinstance(error.value, EvaluationError)  # … is a BakeryError


@pytest.mark.parametrize("case", ["f0_nan", "f0_rgb_as_1d_one_row", "view_last_axis_2", "alpha_nan"])
@pytest.mark.parametrize("name", REFLECTION)
def test_bad_reflection_inputs_on_an_encoding_object(store, name, case):
    """The same checks on the encoding's own evaluate_reflection (one shared place, not per encoding)."""
    encoding = ENCODINGS[name].from_settings(store.encodings[name].settings)
    fields = {k: v for k, v in store.fields(name).items() if k != "probe_index"}
    make, argument = BAD_REFLECTION[case]
    with pytest.raises(EvaluationError, match=argument):
        encoding.evaluate_reflection(fields, store.shared(name), *make(*rows(5)))


@pytest.mark.parametrize("name", REFLECTION)
def test_equivalent_argument_forms_give_identical_results(store, name):
    v, n = rows(4)
    alpha = np.array([0.05, 0.3, 0.6, 1.0])
    f0 = np.array([0.04, 0.5, 1.0, 0.0])
    rgb = np.array([[0.9, 0.6, 0.5]])
    full = store.evaluate_reflection(name, v, n, alpha, f0)
    assert full.shape == (3, 4, 3)
    same = np.testing.assert_array_equal
    same(store.evaluate_reflection(name, v, n, 0.3, 0.04), store.evaluate_reflection(name, v, n, np.full(4, 0.3),
                                                                                       np.full(4, 0.04)))
    same(store.evaluate_reflection(name, v, n, alpha, [0.04]), store.evaluate_reflection(name, v, n, alpha,
                                                                                          np.full(4, 0.04)))
    same(store.evaluate_reflection(name, v, n, alpha, rgb), store.evaluate_reflection(name, v, n, alpha,
                                                                                       np.repeat(rgb, 4, axis=0)))
    np.testing.assert_allclose(store.evaluate_reflection(name, v[1], n[1], alpha[1], f0[1]), full[:, 1:2],
                               rtol=1e-12, atol=0)  # one row as (3,) vectors (another batch size: BLAS may round)
    # an RGB F0 for one row is (1, 3): one row out, not (P, 3, 3) (a (3,) f0 is refused for one row, above)
    one = store.evaluate_reflection(name, v[:1], n[:1], alpha[:1], rgb)
    assert one.shape == (3, 1, 3)
    # a (3,) f0 with three rows is three scalar F0, documented
    same(store.evaluate_reflection(name, v[:3], n[:3], alpha[:3], rgb[0]),
         store.evaluate_reflection(name, v[:3], n[:3], alpha[:3], rgb[0][:, None] * np.ones(3)))


# ---------------------------------------------------------------------------------------------- unknown encodings (D10)
@pytest.fixture(scope="module")
def future_store(store_path, tmp_path_factory) -> Path:
    """A valid, checksum-verified store that also holds encodings this bakery does not know (a newer minor's)."""
    contents = read_store(store_path)
    for new, like in (("zz_future_irradiance", "sh2"), ("zz_future_reflection", "splitsum")):
        entry = copy.deepcopy(contents.encodings[like])
        entry["attributes"]["encoding_type"] = new
        contents.encodings[new] = entry
    path = tmp_path_factory.mktemp("future") / "future.h5"
    write_store(path, contents)
    return path


@pytest.mark.parametrize("name", ["zz_future_irradiance", "zz_future_reflection"])
def test_an_encoding_unknown_to_this_bakery(future_store, name):
    store = bakery.open_store(future_store)
    assert store.verified and name in store.encodings  # it opens and lists the encoding
    with pytest.raises(KeyError) as error:
        if store.encodings[name].kind == "irradiance":
            store.evaluate_irradiance(name, [0.0, 1.0, 0.0])
        else:
            store.evaluate_reflection(name, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], 0.5, 0.04)
    assert isinstance(error.value, UnknownEncodingError)
    message = str(error.value)
    assert message.startswith(str(future_store)) and f"encoding {name} is not known to this bakery" in message
    assert "newer version" in message and "known: sh2" in message
    assert store.unsupported_reason(name) and store.unsupported_reason("sh2") is None


def test_report_skips_unknown_encodings_with_a_warning(future_store):
    from bakery.report import build_report

    with pytest.warns(UnsupportedEncodingWarning) as recorded:
        data, html = build_report(future_store, previews=True, sphere_size=16)
    skipped = {name for name in ("zz_future_irradiance", "zz_future_reflection")
               if any(name in str(w.message) for w in recorded)}
    assert skipped == {"zz_future_irradiance", "zz_future_reflection"}
    assert sum("zz_future_irradiance" in str(w.message) for w in recorded) == 1  # once per encoding
    assert "sh2" in data["negative_share"] and "zz_future_irradiance" not in data["negative_share"]
    assert "zz_future_irradiance" in data["memory"]["encodings"]  # the memory table still lists it
    assert set(data["not_evaluated"]) == {"zz_future_irradiance", "zz_future_reflection"}  # and the page says why
    assert "Encodings not evaluated" in html and "zz_future_reflection is not known to this bakery" in html


def test_report_cli_on_a_store_with_unknown_encodings(future_store, tmp_path):
    result = run("report", future_store, "-o", tmp_path / "rep", "--no-previews")
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Traceback" not in result.stderr and "zz_future_reflection is not known" in result.stderr
    assert (tmp_path / "rep" / "report.html").is_file()


def test_a_newer_major_encoding_version_is_refused_by_the_api_and_skipped_by_the_report(store_path, tmp_path):
    contents = read_store(store_path)
    contents.encodings["sh2"]["attributes"]["encoding_version"] = "7.0.0"
    path = tmp_path / "newer.h5"
    write_store(path, contents)
    store = bakery.open_store(path)
    with pytest.raises(StoreFormatError, match="upgrade bakery"):
        store.evaluate_irradiance("sh2", [0.0, 1.0, 0.0])
    from bakery.report.quality import negative_shares

    with pytest.warns(UnsupportedEncodingWarning, match="sh2 is version 7.0.0"):
        assert "sh2" not in negative_shares(store)


# ----------------------------------------------------------------------------------------------- malformed stores (D11)
def _replace(f, path, data):
    del f[path]
    f[path] = data


def _legacy_shexp(f):
    f["encodings/shexp"].attrs["encoding_version"] = "1.1.0"
    del f["encodings/shexp/alpha_range"]


MALFORMED = {  # edit of an old (1.1.0, no checksums) copy → (where it fails, the name the message must hold)
    "encodings_is_a_dataset": (lambda f: _replace(f, "encodings", np.arange(3)), "open", "/encodings is a dataset"),
    "encoding_is_a_dataset": (lambda f: _replace(f, "encodings/sh2", np.arange(3)), "open", "/encodings/sh2"),
    "shared_is_a_dataset": (lambda f: _replace(f, "encodings/shexp/shared", np.arange(3)), "open",
                            "/encodings/shexp/shared"),
    "probes_is_a_dataset": (lambda f: _replace(f, "probes", np.arange(3)), "open", "/probes"),
    "history_is_a_dataset": (lambda f: _replace(f, "history", np.arange(3)), "open", "/history"),
    "diagnostics_is_a_dataset": (lambda f: _replace(f, "diagnostics", np.arange(3)), "open", "/diagnostics"),
    "probe_index_missing": (lambda f: f["encodings/sh2"].__delitem__("probe_index"), "open",
                            "/encodings/sh2/probe_index"),
    "probe_index_out_of_range": (lambda f: _replace(f, "encodings/sh2/probe_index", np.array([0, 1, 9], np.int32)),
                                 "open", "/encodings/sh2/probe_index"),
    "probe_index_repeated": (lambda f: _replace(f, "encodings/sh2/probe_index", np.array([0, 1, 1], np.int32)),
                             "open", "/encodings/sh2/probe_index"),
    "field_short_rows": (lambda f: _replace(f, "encodings/sh2/radiance_sh", f["encodings/sh2/radiance_sh"][:2]),
                         "open", "/encodings/sh2/radiance_sh"),
    "bake_id_out_of_range": (lambda f: _replace(f, "probes/bake_id", np.array([0, 0, 5], np.int32)), "open",
                             "/probes/bake_id"),
    "encoding_version_missing": (lambda f: f["encodings/sh2"].attrs.__delitem__("encoding_version"), "open",
                                 "encoding_version"),
    "kind_missing": (lambda f: f["encodings/sh2"].attrs.__delitem__("kind"), "open", "kind"),
    "bytes_per_probe_text": (lambda f: f["encodings/sh2"].attrs.__setitem__("bytes_per_probe", "many"), "open",
                             "bytes_per_probe"),
    "settings_not_json": (lambda f: f["encodings/sh2"].attrs.__setitem__("settings", "{oops"), "open", "settings"),
    "settings_not_an_object": (lambda f: f["encodings/sh2"].attrs.__setitem__("settings", "[1, 2]"), "open",
                               "settings"),
    "skipped_not_json": (lambda f: f.attrs.__setitem__("skipped", "not json"), "open", "skipped"),
    "skipped_wrong_items": (lambda f: f.attrs.__setitem__("skipped", "[1, 2]"), "open", "skipped"),
    "roughness_ranges_not_json": (lambda f: f.attrs.__setitem__("roughness_ranges", "{"), "open",
                                  "roughness_ranges"),
    "roughness_ranges_wrong_items": (lambda f: f.attrs.__setitem__("roughness_ranges", '[{"probe": "/a"}]'),
                                     "open", "roughness_ranges"),
    "conventions_not_json": (lambda f: f.attrs.__setitem__("conventions", "frame: y-up"), "open", "conventions"),
    "light_sampling_not_json": (lambda f: f.attrs.__setitem__("capture_light_sampling", "drawn"), "open",
                                "capture_light_sampling"),
    "warnings_not_a_list": (lambda f: f.attrs.__setitem__("warnings", "7"), "open", "warnings"),
    # found on the encoding's first evaluation
    "field_missing": (lambda f: f["encodings/sh2"].__delitem__("radiance_sh"), "evaluate",
                      "/encodings/sh2/radiance_sh"),
    "field_wrong_shape": (lambda f: _replace(f, "encodings/sh2/radiance_sh", f["encodings/sh2/radiance_sh"][:, :2]),
                          "evaluate", "/encodings/sh2/radiance_sh"),
    "field_wrong_dtype": (lambda f: _replace(f, "encodings/sh2/radiance_sh",
                                             np.zeros((3, 4, 3), dtype=np.int32)), "evaluate",
                          "/encodings/sh2/radiance_sh"),
    "reflection_field_wrong_shape": (lambda f: _replace(f, "encodings/shexp_lights/light_flux",
                                                        f["encodings/shexp_lights/light_flux"][:, :2]),
                                     "evaluate", "/encodings/shexp_lights/light_flux"),
    "hybrid_level_missing": (lambda f: f["encodings/shexp_hybrid"].__delitem__("level1"), "evaluate",
                             "/encodings/shexp_hybrid/level1"),
    "encoding_version_not_a_version": (lambda f: f["encodings/sh2"].attrs.__setitem__("encoding_version", "one"),
                                       "evaluate", "encoding_version"),
    "settings_invalid": (lambda f: f["encodings/shexp"].attrs.__setitem__("settings", '{"p_band": "four"}'),
                         "evaluate", "/encodings/shexp: attribute settings"),
    "kind_disagrees": (lambda f: f["encodings/sh2"].attrs.__setitem__("kind", "reflection"), "evaluate",
                       "/encodings/sh2: attribute kind"),
    "legacy_field_missing": (lambda f: (_legacy_shexp(f), f["encodings/shexp"].__delitem__("p")), "evaluate",
                             "/encodings/shexp/p"),
}


def old_store(source: Path, target: Path, edit) -> Path:
    """A copy of ``source`` as a 1.1.0 store (no checksums: nothing verifies its metadata) with ``edit`` applied."""
    shutil.copy(source, target)
    with h5py.File(target, "r+") as f:
        f.attrs["format_version"] = "1.1.0"
        del f["checksums"]
        edit(f)
    return target


def _evaluate_all(store) -> None:
    v, n = rows(3)
    for name, info in store.encodings.items():
        if info.kind == "irradiance":
            store.evaluate_irradiance(name, n)
        else:
            store.evaluate_reflection(name, v, n, 0.4, 0.04)


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_metadata_is_a_store_format_error_naming_the_store_and_the_node(case, store_path, tmp_path):
    edit, stage, needle = MALFORMED[case]
    path = old_store(store_path, tmp_path / f"{case}.h5", edit)
    with pytest.raises(StoreFormatError) as error:
        _evaluate_all(bakery.open_store(path))
    message = str(error.value)
    assert str(path) in message and needle in message, message
    assert "\n" not in message
    if stage == "evaluate":  # the store opens (inspect works); the encoding fails when evaluated
        bakery.open_store(path)


@pytest.mark.parametrize("case", ["encodings_is_a_dataset", "encoding_is_a_dataset", "probe_index_missing",
                                  "field_short_rows"])
def test_malformed_structure_in_diff(case, store_path, tmp_path):
    edit, _, needle = MALFORMED[case]
    path = old_store(store_path, tmp_path / f"{case}.h5", edit)
    with pytest.raises(StoreFormatError, match=needle):
        diff_stores(store_path, path)


@pytest.mark.parametrize("case", ["encodings_is_a_dataset", "skipped_not_json", "roughness_ranges_wrong_items"])
def test_malformed_metadata_in_the_cli_is_one_line(case, store_path, tmp_path):
    edit, _, needle = MALFORMED[case]
    path = old_store(store_path, tmp_path / f"{case}.h5", edit)
    assert_one_line_failure(run("inspect", path), path.name, needle)


def test_report_cli_on_a_malformed_field_is_one_line(store_path, tmp_path):
    edit, _, needle = MALFORMED["field_wrong_shape"]
    path = old_store(store_path, tmp_path / "bad_field.h5", edit)
    assert_one_line_failure(run("report", path, "-o", tmp_path / "rep"), path.name, needle)  # the previews evaluate


def test_a_checksum_valid_store_with_a_short_field_is_refused(store_path, tmp_path):
    """A 1.2 store whose checksums match (written by a buggy or foreign writer) still gets the layout check."""
    contents = read_store(store_path)
    contents.encodings["sh2"]["fields"]["radiance_sh"] = contents.encodings["sh2"]["fields"]["radiance_sh"][:2]
    path = tmp_path / "short.h5"
    write_store(path, contents)
    with pytest.raises(StoreFormatError, match="/encodings/sh2/radiance_sh"):
        bakery.open_store(path)


def test_an_older_encoding_layout_still_evaluates(store_path, tmp_path):
    """shexp 1.0/1.1 stores lack alpha_range (schemas/store-reflection.md): not a missing field."""
    path = old_store(store_path, tmp_path / "legacy.h5", _legacy_shexp)
    store = bakery.open_store(path)
    v, n = rows(3)
    assert np.all(np.isfinite(store.evaluate_reflection("shexp", v, n, 0.4, 0.04)))
