"""The cost model's pilot capture (``bakery/farm/cost.py``): the rays per camera ray it measures on a handful of
probes predict the rays the whole bake traces, scene by scene — where the modelled count (lights + 2)·(1 + b) is
off by several times (an open scene's rays escape, a closed one's paths are long) — and the chunking of a plan into
farm tasks does not depend on it."""

from pathlib import Path

import pytest
from farm_helpers import INDOOR, cli_json
from usd_scenes import box_mesh, header, material, probe, write

from bakery.farm.cost import CostModel, load_calibration, pilot_capture
from bakery.farm.plan import plan_info
from bakery.pipeline.run import plan_bake
from bakery.pipeline.settings import request_from
from bakery.pipeline.shards import chunk_ranges, format_range, suggest_chunking

REPO = Path(__file__).resolve().parents[2]
DOME = REPO / "examples" / "data" / "StinsonBeach_512.hdr"


def _closed_box(folder: Path) -> Path:
    """A closed grey room (albedo 0.5) lit by a sphere lamp: long paths, ended by Russian roulette."""
    lamp = """
def SphereLight "Lamp"
{
    float inputs:radius = 0.3
    float inputs:intensity = 20
    double3 xformOp:translate = (0, 1.2, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""
    probes = "".join(probe(f"P{i}", (x, 0.0, z)) for i, (x, z) in enumerate([(0, 0), (1, 1), (-1, 0.5), (0.5, -1)]))
    return write(folder / "box.usda", header() + material("Grey", diffuse=(0.5, 0.5, 0.5)) + box_mesh(
        "Room", 2.0, "/Grey") + lamp + probes + probe("Mirror", (0, -1, 0), "BakeryReflectionProbe"))


def _open_dome(folder: Path) -> Path:
    """Probes above a small floor under a sunny dome: most camera rays escape at once."""
    (folder / "sky.hdr").write_bytes(DOME.read_bytes())
    dome = 'def DomeLight "Sky"\n{\n    asset inputs:texture:file = @./sky.hdr@\n}\n'
    probes = "".join(probe(f"P{i}", (i - 1.5, 1.0, 0.0)) for i in range(4))
    return write(folder / "open.usda", header() + material("Grey") + box_mesh("Block", 0.5, "/Grey", (0, -0.5, 0))
                 + dome + probes)


@pytest.mark.parametrize("scene", ["closed_box", "open_dome", "indoor"])
def test_the_pilot_predicts_the_rays_the_bake_traces(tmp_path, scene):
    """Σ over the probes of 6 n² · samples · ρ(kind) against the bake's own count of traced rays (``capture_rays``),
    at a face size and samples different from the pilot's: within 6 % (Monte Carlo path lengths)."""
    path = {"closed_box": lambda: _closed_box(tmp_path), "open_dome": lambda: _open_dome(tmp_path),
            "indoor": lambda: INDOOR}[scene]()
    face, samples = 24, 2  # neither of the pilot's (PILOT_FACES, one sample)
    request = request_from([path], tmp_path / "out.h5", face_size=face, samples=samples)
    source, plan = plan_bake(request)
    pilot = pilot_capture(request, source, plan)
    calibration = load_calibration(None)
    traced = CostModel(request, source, plan, calibration, pilot)
    modelled = CostModel(request, source, plan, calibration)
    predicted = sum(traced.capture_rays(t) for t in plan.tasks)
    summary = cli_json("bake", path, "-o", tmp_path / "out.h5", "--face-size", str(face), "--samples", str(samples),
                       "--no-reference", "--jobs", "1")
    measured = summary["timings"]["capture_rays"]
    assert predicted == pytest.approx(measured, rel=0.06), (pilot, predicted, measured)
    assert modelled.pilot is None and traced.pilot == pilot
    print(f"{scene}: ρ = {pilot.rays_per_camera_ray}, traced {measured:.0f}, pilot {predicted:.0f}, "
          f"modelled {sum(modelled.capture_rays(t) for t in plan.tasks):.0f}")


def test_the_pilot_changes_the_estimate_not_the_chunking(tmp_path):
    """`bakery plan` estimates with the pilot but chunks with the modelled rays, as `--shard i/n` does on every host
    (it never runs a pilot): the ranges are those of the pilot-free model."""
    path = _closed_box(tmp_path)
    request = request_from([path], tmp_path / "out.h5", face_size=8, samples=1, batch_size=1)
    info = plan_info(request, tasks=3)
    source, plan = plan_bake(request)
    calibration = load_calibration(None)
    free = CostModel(request, source, plan, calibration)
    groups = suggest_chunking([free.batch(b) for b in plan.batches], 3)
    assert info["chunking"]["ranges"] == [format_range(r) for r in chunk_ranges(plan, groups)]
    rho = info["estimate"]["capture"]["pilot"]["rays_per_camera_ray"]
    assert rho == pytest.approx(pilot_capture(request, source, plan).rays_per_camera_ray, rel=1e-4)
    assert set(rho) == {"irradiance", "reflection"}



def _shipped() -> dict:
    import json

    from bakery.farm.cost import DEFAULT_CALIBRATION

    return json.loads(Path(DEFAULT_CALIBRATION).read_text())


@pytest.mark.parametrize("case, needle", [
    ("list", "a JSON list, not an object"),
    ("version_only", "'capture_probe_seconds' is a required property"),
    ("encoding_not_an_object", "encodings.sh2"),
    ("pair_of_strings", "irradiance_diagnostics.0"),
    ("negative_seconds", "per_probe_seconds"),
])
def test_a_malformed_calibration_is_a_one_line_config_error(tmp_path, case, needle):
    """`plan` and `farm openjd` read the calibration's numbers: a file of another shape is refused with the key
    (before: AttributeError / KeyError tracebacks, exit 1)."""
    import json
    import subprocess
    import sys

    from bakery.errors import ConfigError

    data = {"list": [1], "version_only": {"version": 1}}.get(case) or _shipped()
    if case == "encoding_not_an_object":
        data["encodings"]["sh2"] = "fast"
    elif case == "pair_of_strings":
        data["irradiance_diagnostics"] = ["a", "b"]
    elif case == "negative_seconds":
        data["per_probe_seconds"] = -1.0
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match=needle):
        load_calibration(path)
    for command in (["plan", INDOOR, "--calibration", path],
                    ["farm", "openjd", INDOOR, "-o", tmp_path / "job.yaml", "--calibration", path]):
        result = subprocess.run([sys.executable, "-m", "bakery.cli", *map(str, command)], capture_output=True,
                                text=True, timeout=300)
        assert result.returncode == 3 and "Traceback" not in result.stderr, result.stderr[-2000:]
        assert str(path) in result.stderr and needle in result.stderr, result.stderr
    assert not (tmp_path / "job.yaml").exists()


def test_the_shipped_calibration_is_valid():
    assert load_calibration(None)["encodings"].keys() == _shipped()["encodings"].keys()
