"""Capture scene snapshots (bakery.capture.snapshot): exact round trip, stable hash, corruption, no pxr in workers."""

import dataclasses
import json
import math
import mmap
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bakery.capture import capture_probes
from bakery.capture.render import ProbeRenderer
from bakery.capture.scene import LIGHT_TYPES, CaptureScene, Dome, Light, Material, Mesh, ProbeSpec, Texture
from bakery.capture.snapshot import read_capture_scene, scene_content_hash, write_capture_scene
from bakery.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = {"indoor": ROOT / "examples/indoor/indoor.usda", "outdoor": ROOT / "examples/outdoor/outdoor.usda"}


# ----------------------------------------------------------------------------------------------------------------
def assert_same(a, b, where="scene"):
    """Field-for-field equality with types: dataclasses by fields, arrays by dtype/shape/values, containers by
    type, floats by repr (so -0.0 and the last bit count); numpy scalars compare as their Python values."""
    if isinstance(a, np.generic):
        a = a.item()
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray), where
        assert a.dtype == b.dtype and a.shape == b.shape, where
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), where
    elif isinstance(a, (tuple, list)):
        assert type(a) is type(b) and len(a) == len(b), f"{where}: {type(a).__name__} vs {type(b).__name__}"
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, dict):
        assert type(b) is dict and set(a) == set(b), where
        for k in a:
            assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, float):
        assert type(b) is float and repr(a) == repr(b), f"{where}: {a!r} vs {b!r}"
    else:
        assert type(a) is type(b) and a == b, f"{where}: {a!r} vs {b!r}"


def _box(lo, hi) -> np.ndarray:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]
    return corners[np.array(tris)].astype(np.float32)


def hand_scene() -> CaptureScene:
    rng = np.random.default_rng(7)
    rot = tuple(map(tuple, np.eye(3)[[0, 2, 1]] * np.array([1.0, 1.0, -1.0])))  # np.float64 entries, as USD gives
    floor_uvs = rng.uniform(-1.0, 2.0, (12, 3, 2)).astype(np.float32)
    lamp_normals = rng.normal(size=(12, 3, 3))
    lamp_normals = (lamp_normals / np.linalg.norm(lamp_normals, axis=-1, keepdims=True)).astype(np.float32)
    textured = Material("/Looks/Floor", diffuse=(0.5, 0.4, 0.3), roughness=0.7, metallic=0.1, ior=1.45,
                        opacity_threshold=0.5, maps=(
                            {"input": "diffuseColor", "texture": 0, "channels": "rgb", "scale": (1.0, 1.0, 1.0, 1.0),
                             "bias": (0.0, 0.0, 0.0, 0.0), "fallback": (0.0, 0.0, 0.0, 1.0),
                             "wrap": ("repeat", "mirror")},
                            {"input": "opacity", "texture": 0, "channels": "a", "scale": (1.0, 1.0, 1.0, 1.0),
                             "bias": (0.0, 0.0, 0.0, 0.0), "fallback": (0.0, 0.0, 0.0, 1.0),
                             "wrap": ("clamp", "black")}))
    meshes = (
        Mesh("/World/Floor", _box((-3, -0.1, -3), (3, 0.0, 3)), textured, uvs=floor_uvs),
        Mesh("/World/Lamp", _box((0.5, 0.5, 0.5), (0.7, 0.7, 0.7)),
             Material("/Looks/Emitter", diffuse=(0.1 + 0.2, 0.0, 1e-300), emission=(4.0, 3.5, -0.0)),
             normals=lamp_normals),
        Mesh("/World/Empty", np.zeros((0, 3, 3), np.float32)),
    )
    lights = (
        Light("distant", "/Lights/Sun", illuminance=(np.float64(3.0), 2.5, 2.0), axes=rot, angle=0.53),
        Light("sphere", "/Lights/Bulb", radiance=(50.0, 40.0, 30.0), position=(0.0, 1.5, 0.0), size=(0.1, 0.0)),
        Light("rect", "/Lights/Panel", radiance=(5.0, 5.0, 5.0), position=(1.0, 2.0, 0.0), size=(0.5, 0.25)),
        Light("disk", "/Lights/Spot", radiance=(8.0, 8.0, 9.0), position=(-1.0, 2.0, 0.5), size=(0.2, 0.0),
              visible=False, shaping=(30.0, 0.2, 1.5, 0.5, 0.25, 0.0)),
        Light("cylinder", "/Lights/Tube", radiance=(3.0, 3.0, 3.0), position=(0.0, 2.5, 1.0), size=(0.05, 1.2)),
        Light("rect", "/Lights/Window", radiance=(2.0, 2.0, 2.0), position=(0.0, 1.0, -2.0), size=(1.0, 1.0),
              texture=1),
    )
    textures = (
        Texture("/tmp/floor.png", rng.uniform(0.0, 1.0, (8, 16, 4)).astype(np.float32), "srgb_texture"),
        Texture("/tmp/window.exr", rng.uniform(0.0, 4.0, (4, 4, 4)).astype(np.float32), "ACEScg"),
    )
    portals = (Light("rect", "/Lights/Portal", position=(0.0, 1.0, -2.9), size=(1.0, 2.0)),)
    assert {light.kind for light in lights} == set(LIGHT_TYPES)
    dome = Dome("/Lights/Dome", scale=(0.5, 0.5, 0.5), rotation=rot,
                pixels=rng.uniform(0.0, 2.0, (8, 16, 3)).astype(np.float32), source="/tmp/sky.hdr")
    probes = (
        ProbeSpec("/Probes/A", "irradiance", (0.0, 0.5, 0.0), resolution=8, encodings=("sh2", "zh3"),
                  influence={"radius_m": 0.25}),
        ProbeSpec("/Probes/R", "reflection", (0.3, 1.0, -0.2), rotation=rot,
                  influence={"radius_m": 1.5, "shape": "box", "extent_m": [1.0, 2.0, 0.5], "blend_distance_m": 0.1,
                             "nested": {"pair": (1, 2.5), "flag": True, "none": None, "inf": math.inf}}),
        ProbeSpec("/Probes/Image", "reflection", (0.0, 1.0, 1.0), rotation=rot,
                  image=str(ROOT / "examples/data/StinsonBeach_512.hdr"),
                  influence={"radius_m": 2.0, "shape": "sphere", "extent_m": [1.0, 1.0, 1.0],
                             "blend_distance_m": 0.0}),
    ) + tuple(
        ProbeSpec(f"/Probes/Vol[{i},{j},0]", "irradiance", (i * 0.5, 0.3, j * 0.5), volume="/Probes/Vol",
                  volume_index=(i, j, 0), encodings=("zh3",))
        for i in range(2) for j in range(2)
    )
    return CaptureScene(meshes=meshes, lights=lights, dome=dome, probes=probes, meters_per_unit=0.01, up_axis="Z",
                        textures=textures, portals=portals, time_code=12.5)


@pytest.fixture(scope="module")
def usd_scenes():
    from bakery.usd.scene import read_scene

    return {name: read_scene(path).scene for name, path in EXAMPLES.items()}


def scenes(usd_scenes):
    return {"hand": hand_scene(), **usd_scenes}


# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["hand", "indoor", "outdoor", "empty"])
def test_round_trip_is_field_for_field_equal(name, usd_scenes, tmp_path):
    scene = CaptureScene() if name == "empty" else scenes(usd_scenes)[name]
    digest = write_capture_scene(scene, tmp_path / "snap")
    assert digest == scene_content_hash(scene)
    assert json.loads((tmp_path / "snap/scene.json").read_text())["content_hash"] == digest
    for use_mmap in (True, False):
        back = read_capture_scene(tmp_path / "snap", mmap=use_mmap, verify=True)
        assert_same(scene, back)
        assert scene_content_hash(back) == digest
    assert sorted(os.listdir(tmp_path)) == ["snap"]  # no temporaries left


def test_mesh_triangles_are_views_into_one_mapped_array(tmp_path, usd_scenes):
    write_capture_scene(usd_scenes["outdoor"], tmp_path / "snap")
    back = read_capture_scene(tmp_path / "snap")

    def root(array):
        while isinstance(array.base, np.ndarray):
            array = array.base
        return array.base

    roots = {id(root(m.triangles)) for m in back.meshes}
    assert len(roots) == 1 and isinstance(root(back.meshes[0].triangles), mmap.mmap)
    assert not back.meshes[0].triangles.flags.writeable
    assert isinstance(root(back.dome.pixels), mmap.mmap)
    in_memory = read_capture_scene(tmp_path / "snap", mmap=False)
    assert not isinstance(root(in_memory.meshes[0].triangles), mmap.mmap)


def test_hash_and_bytes_are_stable(tmp_path):
    scene = hand_scene()
    first = write_capture_scene(scene, tmp_path / "a")
    second = write_capture_scene(hand_scene(), tmp_path / "b")
    assert first == second == scene_content_hash(scene)
    for file in ("scene.json", "triangles.npy", "dome.npy"):
        assert (tmp_path / "a" / file).read_bytes() == (tmp_path / "b" / file).read_bytes()
    # same content again: the existing directory is left untouched
    inode = (tmp_path / "a/scene.json").stat().st_ino
    assert write_capture_scene(scene, tmp_path / "a") == first
    assert (tmp_path / "a/scene.json").stat().st_ino == inode
    # different content: replaced atomically, no temporaries left
    moved = dataclasses.replace(scene, probes=scene.probes[:1])
    third = write_capture_scene(moved, tmp_path / "a")
    assert third != first and third == scene_content_hash(moved)
    assert_same(moved, read_capture_scene(tmp_path / "a"))
    assert sorted(os.listdir(tmp_path)) == ["a", "b"]
    # a changed float bit changes the hash
    nudged = dataclasses.replace(scene, meters_per_unit=float(np.nextafter(0.01, 1.0)))
    assert scene_content_hash(nudged) != first


def _assert_input_error(directory: Path, **kwargs):
    with pytest.raises(InputError) as info:
        read_capture_scene(directory, **kwargs)
    message = str(info.value)
    assert str(directory) in message and "\n" not in message
    return message


def test_missing_truncated_or_corrupt_snapshots_raise_input_error(tmp_path):
    scene = hand_scene()
    _assert_input_error(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    _assert_input_error(tmp_path / "empty")

    def fresh(name):
        write_capture_scene(scene, tmp_path / name)
        return tmp_path / name

    d = fresh("trunc_npy")
    data = (d / "triangles.npy").read_bytes()
    (d / "triangles.npy").write_bytes(data[:-7])
    assert "truncated" in _assert_input_error(d)

    d = fresh("trunc_json")
    text = (d / "scene.json").read_bytes()
    (d / "scene.json").write_bytes(text[: len(text) // 2])
    _assert_input_error(d)

    d = fresh("edited_json")
    document = json.loads((d / "scene.json").read_text())
    document["scene"]["meters_per_unit"] = 1.0
    (d / "scene.json").write_text(json.dumps(document))
    assert "hash" in _assert_input_error(d)

    d = fresh("missing_dome")
    (d / "dome.npy").unlink()
    _assert_input_error(d)

    d = fresh("flipped")  # same size, one byte changed: only the full verification sees it
    raw = bytearray((d / "dome.npy").read_bytes())
    raw[-5] ^= 0xFF
    (d / "dome.npy").write_bytes(bytes(raw))
    read_capture_scene(d)
    assert "hash" in _assert_input_error(d, verify=True)

    d = fresh("bad_header")  # same size, header made inconsistent with the manifest
    raw = bytearray((d / "triangles.npy").read_bytes())
    header_end = raw.index(b"\n") + 1
    raw[:header_end] = raw[:header_end].replace(b"'<f4'", b"'<i4'")
    (d / "triangles.npy").write_bytes(bytes(raw))
    _assert_input_error(d)


def _render_all(scene: CaptureScene, face_size: int = 4) -> np.ndarray:
    renderer = ProbeRenderer(scene, samples=1, bounces=1)
    return np.stack([renderer.render(np.asarray(p.position), face_size, p.name)[0] for p in scene.probes])


@pytest.mark.parametrize("name", ["hand", "indoor", "outdoor"])
def test_rendering_the_read_back_scene_is_bit_identical(name, usd_scenes, tmp_path):
    scene = scenes(usd_scenes)[name]
    write_capture_scene(scene, tmp_path / "snap")
    back = read_capture_scene(tmp_path / "snap")
    original, again = _render_all(scene), _render_all(back)
    assert original.tobytes() == again.tobytes()
    assert np.isfinite(original).all() and original.max() > 0


def test_capture_probes_with_image_probes_is_bit_identical(usd_scenes, tmp_path):
    scene = usd_scenes["outdoor"]
    assert any(p.image for p in scene.probes)
    write_capture_scene(scene, tmp_path / "snap")
    back = read_capture_scene(tmp_path / "snap")
    cubes, _ = capture_probes(scene, 4, samples=1)
    cubes_back, _ = capture_probes(back, 4, samples=1)
    assert cubes.tobytes() == cubes_back.tobytes()


def test_worker_reads_the_snapshot_without_pxr(usd_scenes, tmp_path):
    scene = usd_scenes["indoor"]
    write_capture_scene(scene, tmp_path / "snap")
    probe = scene.probes[0]
    expected, _ = ProbeRenderer(scene, samples=1).render(np.asarray(probe.position), 4, probe.name)
    code = (
        "import sys, numpy as np\n"
        "from bakery.capture.snapshot import read_capture_scene\n"
        "from bakery.capture.render import ProbeRenderer\n"
        f"scene = read_capture_scene({str(tmp_path / 'snap')!r})\n"
        "p = scene.probes[0]\n"
        "cube, _ = ProbeRenderer(scene, samples=1).render(np.asarray(p.position), 4, p.name)\n"
        f"np.save({str(tmp_path / 'cube.npy')!r}, cube)\n"
        "print('pxr' in sys.modules, 'h5py' in sys.modules)\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                            env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["False", "False"]
    assert np.load(tmp_path / "cube.npy").tobytes() == expected.tobytes()


@pytest.mark.parametrize("name", ["indoor", "outdoor"])
def test_a_probe_does_not_depend_on_what_its_renderer_rendered_before(name, usd_scenes):
    """Per-probe seeds and per-probe arrays: a probe's cube is bit-identical whether it is rendered first by a fresh
    renderer or after other probes at other face sizes (any batch composition or worker count sees the same)."""
    scene = scenes(usd_scenes)[name]
    rendered = [p for p in scene.probes if not p.image]
    last = rendered[-1]
    fresh, _ = ProbeRenderer(scene, samples=2).render(np.asarray(last.position), 8, last.name)
    busy = ProbeRenderer(scene, samples=2)
    for p in rendered[:3]:
        busy.render(np.asarray(p.position), 6, p.name)
        busy.render(np.asarray(p.position), 8, p.name)
    again, _ = busy.render(np.asarray(last.position), 8, last.name)
    assert fresh.tobytes() == again.tobytes()
