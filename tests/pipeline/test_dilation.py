"""Dilation of probes inside geometry (``bakery:volume:dilate``, :mod:`bakery.pipeline.dilate`).

Closed forms: radiance SH linear in position is reproduced exactly at a grid probe whose neighbours are valid (the
inverse-square weights are symmetric), a constant field anywhere; passes fill a row one spacing per pass.
Properties (hypothesis): valid probes are untouched bit for bit, a dilated probe is a convex combination of its
sources. End to end through a USD bake: the probe inside a cube stores Eq. 1 of its neighbours' stored SH in every
irradiance encoding, no validity warning names it, the exports and the layer carry it, and changing the radius or
the passes re-bakes nothing."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from usd_scenes import header, material, write

import bakery
from bakery.encodings import get_encoding
from bakery.errors import SceneWarning
from bakery.pipeline.dilate import DilationSettings, dilate_radiance_sh, hashed_settings
from bakery.probe import RadianceSHBatch


def _grid(n: int = 3, spacing: float = 1.0) -> np.ndarray:
    k, j, i = np.meshgrid(*(np.arange(n),) * 3, indexing="ij")
    return spacing * np.stack([i.ravel(), j.ravel(), k.ravel()], axis=-1).astype(np.float64)


def test_a_linear_field_is_reproduced_at_an_interior_probe():
    rng = np.random.default_rng(1)
    positions = _grid(3, 0.7)
    offset, slope = rng.normal(size=(27, 1)), rng.normal(size=(27, 3))  # each of the 27 SH values: a + b·x
    field = (offset + slope @ positions.T).T.reshape(27, 9, 3)
    valid = np.ones(27, dtype=bool)
    valid[13] = False  # the centre
    captured = field.copy()
    captured[13] = 0.0  # what it saw inside the wall
    result = dilate_radiance_sh(captured, positions, valid, radius=0.7 * np.sqrt(3) * (1 + 1e-9))
    np.testing.assert_allclose(result.radiance_sh[13], field[13], rtol=0, atol=1e-12)
    assert result.neighbours[13] == 26 and np.count_nonzero(result.neighbours) == 1
    # a corner is not surrounded: the linear field is not reproduced there, a constant one is
    corner = valid.copy()
    corner[0] = False
    constant = np.broadcast_to(rng.normal(size=(9, 3)), (27, 9, 3))
    dilated = dilate_radiance_sh(constant, positions, corner, radius=1.0).radiance_sh
    np.testing.assert_allclose(dilated[0], constant[0], rtol=1e-14)
    linear = dilate_radiance_sh(field, positions, corner, radius=1.0).radiance_sh
    assert not np.allclose(linear[0], field[0])


def test_inverse_square_weights_of_unequal_distances():
    """Probe 1 of a row at x = 0, 1, 2, 4 with radius 3: sources at distances 1, 1 and 3 weigh 1, 1 and 1/9."""
    positions = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [4, 0, 0]])
    sh = np.arange(4 * 27, dtype=np.float64).reshape(4, 9, 3) ** 1.5
    result = dilate_radiance_sh(sh, positions, np.array([True, False, True, True]), radius=3.0)
    expected = (sh[0] + sh[2] + sh[3] / 9.0) / (2.0 + 1.0 / 9.0)
    np.testing.assert_allclose(result.radiance_sh[1], expected, rtol=1e-14)
    assert result.neighbours.tolist() == [0, 3, 0, 0]


def test_each_pass_reaches_one_spacing_further():
    positions = np.arange(5, dtype=np.float64)[:, None] * np.array([[1.0, 0, 0]])
    sh = np.zeros((5, 9, 3))
    sh[4] = 1.0
    valid = np.array([False, False, False, False, True])
    two = dilate_radiance_sh(sh, positions, valid, radius=1.0, passes=2)
    assert two.neighbours.tolist() == [0, 0, 1, 1, 0]
    assert np.all(two.radiance_sh[2:] == 1.0) and np.all(two.radiance_sh[:2] == 0.0)
    four = dilate_radiance_sh(sh, positions, valid, radius=1.0, passes=4)
    assert np.all(four.radiance_sh == 1.0) and four.neighbours.tolist() == [1, 1, 1, 1, 0]


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 40), st.integers(0, 2**31 - 1), st.floats(0.2, 2.0), st.integers(1, 3))
def test_valid_probes_are_untouched_and_dilated_ones_are_convex_combinations(count, seed, radius, passes):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(0, 3, size=(count, 3))
    sh = rng.normal(size=(count, 9, 3))
    valid = rng.random(count) < 0.6
    result = dilate_radiance_sh(sh, positions, valid, radius, passes)
    assert result.radiance_sh[valid].tobytes() == sh[valid].tobytes()
    assert np.all(result.neighbours[valid] == 0)
    done = result.neighbours > 0
    assert np.all(result.radiance_sh[~valid & ~done] == sh[~valid & ~done])
    if valid.any() and done.any():  # every source descends from the valid probes: within their range
        low, high = sh[valid].min(axis=0), sh[valid].max(axis=0)
        assert np.all(result.radiance_sh[done] >= low - 1e-12) and np.all(result.radiance_sh[done] <= high + 1e-12)
    more = dilate_radiance_sh(sh, positions, valid, radius, passes + 1)
    assert np.all((more.neighbours > 0) | ~done)  # another pass never empties a probe


def test_the_content_hash_sees_only_that_dilation_is_on():
    a = DilationSettings("/Volume", 1.0, 1).as_setting()
    b = DilationSettings("/Volume", 3.0, 4).as_setting()
    assert hashed_settings({"dilation": a}) == hashed_settings({"dilation": b}) != hashed_settings({})
    with pytest.raises(ValueError, match="radius > 0"):
        DilationSettings("/Volume", 0.0)


# ------------------------------------------------------------------------------------------------ through a bake
GREY = material("Grey", diffuse=(0.5, 0.5, 0.5), diffuse_only=True)
SKY = 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1\n    color3f inputs:color = (0.4, 0.6, 1.0)\n}\n'
SUN = 'def SphereLight "Lamp"\n{\n    float inputs:intensity = 300\n    float inputs:radius = 0.2\n' \
      '    double3 xformOp:translate = (3, 2.5, 1)\n    uniform token[] xformOpOrder = ["xformOp:translate"]\n}\n'
IRRADIANCE = ("sh2", "sh3", "zh3", "zh3_solved", "zh3_deringed", "zh3_hallucinated", "zh3_hallucinated_solved",
              "zh3_quantized", "sh3_quantized")


def _row(volume: str) -> str:
    """Four probes 1 m apart along X (x = −1.5 … 1.5), the second inside a closed 0.6 m cube, under a sky and a
    lamp (the probes see different light: a field that is not constant)."""
    return header() + SKY + SUN + GREY + f"""
def Cube "Wall" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    double size = 0.6
    rel material:binding = </Grey>
    double3 xformOp:translate = (-0.5, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
def BakeryIrradianceProbeVolume "Row"
{{
    float3 bakery:volume:extent = (1.5, 0, 0)
    int3 bakery:volume:counts = (4, 1, 1)
    {volume}
}}
"""


def _bake(tmp_path, name: str, volume: str, output: str = "row.h5", **kwargs):
    scene = write(tmp_path / f"{name}.usda", _row(volume))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = bakery.bake(scene, tmp_path / output, encodings=IRRADIANCE, face_size=8, samples=2, **kwargs)
    return result, bakery.open_store(tmp_path / output), [str(w.message) for w in caught
                                                         if issubclass(w.category, SceneWarning)]


@pytest.fixture(scope="module")
def dilated_row(tmp_path_factory):
    folder = tmp_path_factory.mktemp("dilation")
    return folder, *_bake(folder, "row", "bool bakery:volume:dilate = 1\n    float bakery:volume:dilationDistance = 2.5")


def test_the_probe_inside_stores_eq_1_of_its_neighbours_in_every_irradiance_encoding(dilated_row):
    _folder, _result, store, messages = dilated_row
    assert np.asarray(store.diagnostics["capture/backface_fraction"]).tolist() == [0.0, 1.0, 0.0, 0.0]
    assert np.asarray(store.diagnostics["dilation/neighbours"]).tolist() == [0.0, 3.0, 0.0, 0.0]
    assert not any("inside geometry" in m for m in messages), messages
    captured = np.asarray(store.diagnostics["dilation/radiance_sh"], dtype=np.float64)
    stored = np.asarray(store.fields("sh3")["radiance_sh"], dtype=np.float64)
    np.testing.assert_array_equal(stored[[0, 2, 3]], captured[[0, 2, 3]])  # the valid ones store their capture
    # Eq. 1 by hand: sources at 1, 1 and 2 m weigh 1, 1 and 1/4; the inside probe's own capture is the dark inside
    expected = (captured[0] + captured[2] + captured[3] / 4.0) / 2.25
    np.testing.assert_allclose(stored[1], expected, rtol=2e-7)
    assert captured[1, 0].max() < 0.2 * expected[0].min()
    for name in IRRADIANCE:
        encoding = get_encoding(name).from_settings(store.encodings[name].settings)
        again = encoding.encode(RadianceSHBatch(expected[None]))
        for key, value in store.fields(name).items():
            if key == "probe_index":
                continue
            np.testing.assert_allclose(np.asarray(value[1], dtype=np.float64), again[key][0], rtol=1e-5, atol=1e-6,
                                       err_msg=f"{name}.{key}")
        error = np.asarray(store.diagnostics[f"reference_error/{name}"])
        assert np.isnan(error[1]) and np.all(np.isfinite(error[[0, 2, 3]])), name


def test_exports_layer_and_inspect_say_which_probe_was_dilated(dilated_row):
    from pxr import Usd

    from bakery.export import export_store

    folder, _result, store, _messages = dilated_row
    export_store(folder / "row.h5", folder / "three", "three", layer=False)
    grids = json.loads((folder / "three" / "lightprobegrids.json").read_text())["grids"]
    validity = {probe: record for grid in grids for probe, record in grid.get("validity", {}).items()}
    assert validity["/Row[1,0,0]"]["dilated_from"] == 3 and validity["/Row[1,0,0]"]["inside_geometry"]
    assert "dilated_from" not in validity["/Row[0,0,0]"]
    layer = Usd.Stage.Open(str(folder / "row.bake.usda"))
    values = np.asarray(layer.GetPrimAtPath("/Row").GetAttribute("bakery:irradiance:sh3:radiance_sh").Get())
    np.testing.assert_allclose(values.reshape(4, 9, 3)[1], store.fields("sh3")["radiance_sh"][1], rtol=1e-6)
    assert list(layer.GetPrimAtPath("/Row").GetAttribute("bakery:baked:dilatedFrom").Get()) == [0, 3, 0, 0]
    from click.testing import CliRunner

    from bakery.cli import main

    out = CliRunner().invoke(main, ["inspect", str(folder / "row.h5")])
    assert out.exit_code == 0 and "dilated: 1 probe inside geometry" in out.output
    from bakery.report.build import build_report

    data, html = build_report(folder / "row.h5", previews=False)
    assert data["capture_validity"]["dilated_count"] == 1 and "bakery:volume:dilate" in html
    assert data["capture_validity"]["inside"] == [{"probe": "/Row[1,0,0]", "backface_fraction": 1.0,
                                                   "dilated_from": 3}]


def test_changing_the_radius_or_passes_re_bakes_nothing(tmp_path):
    result, store, _ = _bake(tmp_path, "a", "bool bakery:volume:dilate = 1")
    assert result.baked == 4
    default = np.asarray(store.fields("zh3")["radiance_sh"]).copy()
    assert np.asarray(store.diagnostics["dilation/neighbours"]).tolist() == [0.0, 2.0, 0.0, 0.0]  # cell: 1 m
    result, store, messages = _bake(tmp_path, "b", "bool bakery:volume:dilate = 1\n"
                                    "    float bakery:volume:dilationDistance = 0.5")
    assert (result.baked, result.reused) == (0, 4)
    captured = np.asarray(store.diagnostics["dilation/radiance_sh"])
    np.testing.assert_array_equal(store.fields("sh3")["radiance_sh"][1], captured[1])  # no source in reach
    assert any("no valid probe within 0.5 m" in m and "/Row[1,0,0]" in m for m in messages), messages
    assert any("likely inside geometry" in m for m in messages)
    result, store, _ = _bake(tmp_path, "c", "bool bakery:volume:dilate = 1")
    assert result.reused == 4
    np.testing.assert_array_equal(store.fields("zh3")["radiance_sh"], default)


def test_bad_dilation_attributes_are_errors_naming_the_volume(tmp_path):
    from bakery.usd.scene import read_scene

    for attrs, fragment in (("int bakery:volume:dilationIterations = 0", "dilationIterations must be >= 1"),
                            ("float bakery:volume:dilationDistance = -1", "dilationDistance must be a finite")):
        reading = read_scene(write(tmp_path / "bad.usda", _row(f"bool bakery:volume:dilate = 1\n    {attrs}")))
        assert any("/Row" in str(e) and fragment in str(e) for e in reading.errors), reading.errors


def test_worker_count_does_not_change_a_dilated_store(tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    _bake(tmp_path, "row", "bool bakery:volume:dilate = 1", output="one.h5", jobs=1)
    _bake(tmp_path, "row", "bool bakery:volume:dilate = 1", output="two.h5", jobs=2, batch_size=1)
    assert (tmp_path / "one.h5").read_bytes() == (tmp_path / "two.h5").read_bytes()
    assert json.loads(bakery.open_store(tmp_path / "two.h5").attributes["failed_probes"]) == {}


def test_check_says_the_bake_dilates_the_probes_inside(tmp_path):
    from bakery.usd.check import check_scene

    (plain,) = [i for i in check_scene(write(tmp_path / "plain.usda", _row(""))) if "inside geometry" in i.message]
    assert "set bakery:volume:relocate or bakery:volume:dilate" in plain.message
    scene = write(tmp_path / "dilating.usda", _row("bool bakery:volume:dilate = 1"))
    (row,) = [i for i in check_scene(scene) if "inside geometry" in i.message]
    assert row.prim == "/Row" and "the bake dilates them (bakery:volume:dilate)" in row.message
