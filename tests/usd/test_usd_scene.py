"""Reading USD scenes: frames and units, dome orientation, lights (incl. legacy attributes), materials, instancing,
probe volumes and captured images — with real .usda files, checked against closed forms and the OpenEXR
latlong convention written out here."""

from __future__ import annotations

import math

import numpy as np
import OpenImageIO as oiio
import pytest
from usd_scenes import box_mesh, header, material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

DOME = "usd/openusd_DomeLightOrientation"


def _dome_root(tmp_path, shared_data, up_axis):
    """The OpenUSD dome scene (Y-up or Z-up, unedited) with one probe placed by a sublayer, 3 units in front of
    the sphere along bake +Z: stage (0, 0, 3) when Y-up, (0, -3, 0) when Z-up ((x, y, z) ↦ (x, z, −y))."""
    scene = shared_data / DOME / f"domeLight{up_axis}up.usda"
    position = (0, 0, 3) if up_axis == "Y" else (0, -3, 0)
    probes = write(tmp_path / f"probes{up_axis}.usda", f'#usda 1.0\n(\n    upAxis = "{up_axis}"\n)\n'
                   + probe("Probe", position))
    return write(tmp_path / f"root{up_axis}.usda",
                 f'#usda 1.0\n(\n    upAxis = "{up_axis}"\n    subLayers = [@{probes}@, @{scene}@]\n)\n')


def test_dome_y_up_and_z_up_scenes_capture_the_same(tmp_path, shared_data):
    """OpenUSD's domeLightYup/Zup scenes: Z-up adds rotateX 90 on the dome; with the stage's Z-up → bake Y-up
    rotation both bake to the same cube, and misses see the texture per the OpenEXR latlong convention."""
    n = 16
    cubes = {}
    for up in ("Y", "Z"):
        reading = read_scene(_dome_root(tmp_path, shared_data, up))
        assert not reading.errors, reading.errors
        assert reading.up_axis == up
        cube, _ = capture_probes(reading.scene, n, samples=16, bounces=1)
        cubes[up] = cube[0].astype(np.float64)
    # Everything but the -Z face (which sees the sphere) is the dome alone: identical.
    np.testing.assert_allclose(cubes["Y"][:5], cubes["Z"][:5], atol=1e-6)
    # The sphere gprim is tessellated in its local frame (poles on local Y), so its silhouette texels differ
    # slightly between the two stages; the face agrees on average.
    scale = cubes["Y"][5].mean()
    assert np.abs(cubes["Y"][5] - cubes["Z"][5]).mean() < 0.03 * scale

    # Independent reference: the PNG read here, sRGB-decoded, looked up with OpenEXR's convention
    # (row 0 = +Y, column 0 = longitude +π, longitude = atan2(x, z)) at face-centre directions.
    buf = oiio.ImageBuf(str(shared_data / DOME / "testImage.png"))
    image = buf.get_pixels(oiio.FLOAT)[..., :3].astype(np.float64)
    image = np.where(image <= 0.04045, image / 12.92, ((image + 0.055) / 1.055) ** 2.4)
    h, w = image.shape[:2]
    faces = {0: (1, 0, 0), 1: (-1, 0, 0), 2: (0, 1, 0), 3: (0, -1, 0), 4: (0, 0, 1)}  # -Z looks at the sphere
    for face, (x, y, z) in faces.items():
        lon, lat = math.atan2(x, z), math.asin(y)
        row = min(h - 1, int((0.5 - lat / math.pi) * h))
        col = int((0.5 - lon / (2 * math.pi)) * w) % w
        window = image[max(0, row - 8) : row + 9, np.arange(col - 8, col + 9) % w]
        assert np.ptp(window, axis=(0, 1)).max() < 1e-6, f"reference window not constant on face {face}"
        seen = cubes["Y"][face, n // 2 - 1 : n // 2 + 1, n // 2 - 1 : n // 2 + 1].mean(axis=(0, 1))
        # the dome is integrated over each texel and its total flux renormalised exactly: 1e-5-level shifts
        np.testing.assert_allclose(seen, image[row, col], atol=1e-4, err_msg=f"face {face}")


def _lit_scene(unit_scale, up_axis="Y"):
    """Ground, an occluding box, a sphere light and a sun, authored in units of 1/unit_scale metres."""
    s = unit_scale
    text = header(up_axis="Y", meters_per_unit=1.0 / s)
    text += material("Ground", diffuse=(0.5, 0.45, 0.4)) + material("BlockMat", diffuse=(0.2, 0.6, 0.3))
    text += plane_mesh("Plane", 50 * s, "/Ground")
    text += box_mesh("Block", 0.5 * s, "/BlockMat", centre=(1.5 * s, 0.5 * s, 0))
    text += f"""
def SphereLight "Lamp"
{{
    float inputs:radius = {0.25 * s}
    float inputs:intensity = 20
    double3 xformOp:translate = ({-1 * s}, {2.5 * s}, {0.5 * s})
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
def DistantLight "Sun"
{{
    float inputs:intensity = 2
    bool inputs:normalize = 1
    float xformOp:rotateX = -50
    float xformOp:rotateY = 30
    uniform token[] xformOpOrder = ["xformOp:rotateY", "xformOp:rotateX"]
}}
""" + probe("P", (0.3 * s, 1.0 * s, 0.2 * s))
    return text


def test_units_centimetres_and_metres_capture_the_same(tmp_path):
    n = 16
    got = []
    for scale in (1.0, 100.0):
        reading = read_scene(write(tmp_path / f"units{int(scale)}.usda", _lit_scene(scale)))
        assert not reading.errors
        np.testing.assert_allclose(reading.scene.probes[0].position, (0.3, 1.0, 0.2), rtol=1e-12)
        cube, _ = capture_probes(reading.scene, n, samples=2, bounces=1)
        got.append(cube[0].astype(np.float64))
    scale = got[0].mean()
    assert np.abs(got[0] - got[1]).mean() < 1e-3 * scale


def test_z_up_stage_positions_probes_in_the_y_up_bake_frame(tmp_path):
    text = header(up_axis="Z", meters_per_unit=0.01) + probe("P", (100.0, 200.0, 300.0))
    reading = read_scene(write(tmp_path / "zup.usda", text))
    np.testing.assert_allclose(reading.scene.probes[0].position, (1.0, 3.0, -2.0), atol=1e-12)


def test_probe_volume_grid_positions(tmp_path):
    body = "float3 bakery:volume:extent = (2, 1, 3)\n    int3 bakery:volume:counts = (3, 2, 1)"
    text = header() + probe("Vol", (10.0, 0.0, 0.0), type_name="BakeryIrradianceProbeVolume", body=body)
    probes = read_scene(write(tmp_path / "vol.usda", text)).scene.probes
    assert [p.name for p in probes] == [f"/Vol[{i},{j},0]" for j in range(2) for i in range(3)]
    expected = [(10.0 + x, y, 0.0) for y in (-1.0, 1.0) for x in (-2.0, 0.0, 2.0)]  # counts 1 → mid-plane
    np.testing.assert_allclose([p.position for p in probes], expected, atol=1e-12)
    assert all(p.volume == "/Vol" and p.kind == "irradiance" for p in probes)


@pytest.mark.parametrize("metres_per_unit", [1.0, 0.01])
def test_legacy_and_namespaced_light_attributes_and_normalize(tmp_path, metres_per_unit):
    """Legacy un-namespaced inputs are honoured; normalize divides by the world-space emitting area in stage
    units², as OpenUSD's HdEmbree does (so a centimetre stage's normalized light is 10⁴× dimmer per unit intensity
    than the same light in a metre stage)."""
    k = 1.0 / metres_per_unit
    text = header(meters_per_unit=metres_per_unit) + f"""
def SphereLight "Legacy"
{{
    float intensity = 3
    float exposure = 1
    color3f color = (1, 0.5, 0.25)
    float radius = {0.5 * k}
}}
def RectLight "Panel"
{{
    float inputs:intensity = 4
    float inputs:width = {2 * k}
    float inputs:height = {0.5 * k}
    bool inputs:normalize = 1
}}
""" + probe("P")
    lights = {light.name: light for light in read_scene(write(tmp_path / "legacy.usda", text)).scene.lights}
    np.testing.assert_allclose(lights["/Legacy"].radiance, (6.0, 3.0, 1.5))
    assert lights["/Legacy"].size[0] == pytest.approx(0.5)
    np.testing.assert_allclose(lights["/Panel"].radiance, (4.0 / (2 * k * 0.5 * k),) * 3)  # 4 / area in units²


def test_preview_surface_texture_means_are_linear_and_the_fallback_st_is_read_without_texture_coordinates(tmp_path):
    pixels = np.zeros((4, 4, 3), dtype=np.uint8)
    pixels[:2] = 255  # half white, half black, sRGB-encoded 8 bit → linear mean 0.5
    out = oiio.ImageOutput.create(str(tmp_path / "half.png"))
    assert out.open(str(tmp_path / "half.png"), oiio.ImageSpec(4, 4, 3, oiio.UINT8))
    out.write_image(pixels)
    out.close()
    tex = """
    def Shader "Tex"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @./half.png@
        float4 inputs:scale = (0.8, 0.8, 0.8, 1)
        float3 outputs:rgb
    }
"""
    text = header() + material("M", extra=tex).replace(
        "color3f inputs:diffuseColor = (0.18, 0.18, 0.18)",
        "color3f inputs:diffuseColor.connect = </M/Tex.outputs:rgb>",
    ) + box_mesh("Box", 1.0, "/M") + probe("P", (0, 5, 0)) + 'def DomeLight "Sky"\n{\n}\n'
    reading = read_scene(write(tmp_path / "tex.usda", text))
    # the material's constant is the texture's linear mean (reports, constant inputs)
    np.testing.assert_allclose(reading.scene.meshes[0].material.diffuse, (0.4, 0.4, 0.4), rtol=1e-6)
    # the box has no texture coordinates: the texture is read at st (0, 0) — the UsdPrimvarReader_float2 fallback
    # ("fallback value to be returned if geometry fetch failed", UsdPreviewSurface specification; here no reader,
    # UsdUVTexture's st fallback (0, 0)) — everywhere (every st maps to it), and that is reported
    assert [i.message for i in reading.issues] == [
        "textures read primvar 'st', which the mesh does not have; the textures are read at the primvar reader's "
        "fallback st (0, 0)"]
    (entry,) = reading.scene.meshes[0].material.maps
    assert entry["st_transform"] == ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)) and "st_fallback" not in entry
    assert not np.any(reading.scene.meshes[0].uvs)


def test_instances_and_payloads_are_resolved(tmp_path):
    write(tmp_path / "asset.usda", '#usda 1.0\n(\n    defaultPrim = "Asset"\n)\n'
          'def Xform "Asset"\n{\n' + box_mesh("Box", 0.5, "/Asset/NoMat").replace("\n", "\n    ") + "\n}\n")
    text = header() + f"""
def Xform "A" (
    instanceable = true
    references = @./asset.usda@
)
{{
    double3 xformOp:translate = (5, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
def Xform "B" (
    instanceable = true
    payload = @./asset.usda@
)
{{
    double3 xformOp:translate = (-5, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
def PointInstancer "Scatter"
{{
    rel prototypes = </Scatter/Protos/Box>
    int[] protoIndices = [0, 0, 0]
    point3f[] positions = [(0, 0, 10), (0, 0, 20), (0, 0, 30)]
    def Scope "Protos"
    {{
        {box_mesh("Box", 0.5, "/NoMat")}
    }}
}}
""" + probe("P", (0, 5, 0))
    reading = read_scene(write(tmp_path / "inst.usda", text))
    centres = sorted(tuple(np.round(m.triangles.reshape(-1, 3).mean(axis=0), 6)) for m in reading.scene.meshes)
    expected = sorted([(5.0, 0.0, 0.0), (-5.0, 0.0, 0.0), (0.0, 0.0, 10.0), (0.0, 0.0, 20.0), (0.0, 0.0, 30.0)])
    np.testing.assert_allclose(centres, expected, atol=1e-6)


def test_captured_image_probe_is_oriented_by_its_transform(tmp_path):
    """A captured latlong turned by the probe's rotateY 90: bake direction ω reads the image at Rᵀω."""
    h, w = 32, 64
    cols = (np.arange(w) + 0.5) / w
    pixels = np.zeros((h, w, 3), dtype=np.float32)
    pixels[..., 0] = np.cos(2 * np.pi * cols)[None, :] + 1.0  # smooth in longitude
    pixels[..., 1] = np.linspace(0.0, 1.0, h)[:, None]
    pixels[..., 2] = 0.5
    out = oiio.ImageOutput.create(str(tmp_path / "cap.exr"))
    assert out.open(str(tmp_path / "cap.exr"), oiio.ImageSpec(w, h, 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()
    body = 'asset bakery:capture:image = @./cap.exr@\n    float xformOp:rotateY = 90\n'
    text = header() + probe("P", body=body, type_name="BakeryReflectionProbe").replace(
        '["xformOp:translate"]', '["xformOp:translate", "xformOp:rotateY"]')
    reading = read_scene(write(tmp_path / "cap.usda", text))
    n = 16
    cube, report = capture_probes(reading.scene, n)
    assert report.loaded == 1 and report.rendered == 0
    d = cube_texel_directions(n).reshape(-1, 3)
    # rotateY(+90°): local (x, y, z) ↦ world (z, y, −x), so local = (−ω_z, ω_y, ω_x)
    local = np.stack([-d[:, 2], d[:, 1], d[:, 0]], axis=-1)
    lon = np.arctan2(local[:, 0], local[:, 2])
    expected_r = np.cos(2 * np.pi * (0.5 - lon / (2 * np.pi))) + 1.0
    away_from_poles = np.abs(d[:, 1]) < 0.7
    err = np.abs(cube[0].reshape(-1, 3)[away_from_poles, 0] - expected_r[away_from_poles])
    assert err.mean() < 0.03 and err.max() < 0.15


@pytest.mark.parametrize("scene", ["root.usda", "root_with_instances.usda"])
def test_openusd_light_list_scene_legacy_lights_payloads_and_instances(shared_data, scene):
    """OpenUSD's LightListAPI scene: torches arrive by payload (and as instances), their SphereLights use legacy
    attributes (radius 0.1, exposure 5 → radiance 2⁵ = 32)."""
    reading = read_scene(shared_data / "usd" / "openusd_LightListAPI" / scene)
    spheres = [light for light in reading.scene.lights if light.kind == "sphere"]
    assert len(spheres) == 2
    for light in spheres:
        # enableColorTemperature = 1, colorTemperature = 3700: a warm colour of Rec.709 luminance 1 (HdEmbree)
        radiance = np.asarray(light.radiance)
        assert float(radiance @ np.array([0.2126, 0.7152, 0.0722])) == pytest.approx(32.0, rel=1e-5)
        assert radiance[0] > radiance[1] > radiance[2] > 0
        assert light.size[0] == pytest.approx(0.1 * reading.meters_per_unit)
    names = {m.name.split("/")[-1] for m in reading.scene.meshes}
    assert len(reading.scene.meshes) == 3 and "mesh_0" in names  # teapot + two torches (time-sampled points)


@pytest.mark.parametrize(("pole", "up"), [("Y", "Z"), ("Z", "Z"), ("scene", "Z"), ("scene", "Y")])
def test_dome_light_1_pole_axis(tmp_path, pole, up):
    """DomeLight_1: the texture's pole is local +Y for poleAxis "Y", local +Z for "Z" or "scene" on a Z-up stage."""
    text = header(up_axis=up) + f'def DomeLight_1 "Sky"\n{{\n    uniform token poleAxis = "{pole}"\n}}\n' + probe("P")
    dome = read_scene(write(tmp_path / "dome1.usda", text)).scene.dome
    rotation = np.asarray(dome.rotation)  # columns: dome-local axes in the bake frame
    pole_on_z = pole == "Z" or (pole == "scene" and up == "Z")
    pole_stage = np.array([0.0, 0.0, 1.0]) if pole_on_z else np.array([0.0, 1.0, 0.0])
    # stage → bake: identity for Y-up, (x, y, z) ↦ (x, z, −y) for Z-up
    to_bake = np.eye(3) if up == "Y" else np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    # the texture's pole (dome-local +Y before the pole alignment) lands on the pole axis
    np.testing.assert_allclose(rotation @ np.array([0.0, 1.0, 0.0]), to_bake @ pole_stage, atol=1e-12)


def test_usdz_package_textures_are_read(tmp_path):
    """A dome texture inside a .usdz (resolved as pkg.usdz[member]) is read through USD's asset resolver."""
    from pxr import Sdf, UsdUtils

    pixels = np.full((8, 16, 3), 0.25, dtype=np.float32)
    out = oiio.ImageOutput.create(str(tmp_path / "sky.exr"))
    assert out.open(str(tmp_path / "sky.exr"), oiio.ImageSpec(16, 8, 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()
    write(tmp_path / "scene.usda", header() + 'def DomeLight "Sky"\n{\n    asset inputs:texture:file = @./sky.exr@\n}\n'
          + probe("P"))
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(tmp_path / "scene.usda")), str(tmp_path / "scene.usdz"))
    (tmp_path / "sky.exr").unlink()  # only the packaged copy remains
    reading = read_scene(tmp_path / "scene.usdz")
    assert not reading.errors, reading.errors
    np.testing.assert_allclose(reading.scene.dome.pixels, 0.25)


def test_catmull_clark_refinement_of_a_cube():
    """One Catmull-Clark step of the cube [−1, 1]³: 24 quads; corners move to ±5/9, edge points to (±¾, ±¾, 0)…"""
    from bakery.usd.scene import catmull_clark

    points = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
    counts = np.full(6, 4)
    indices = np.array([0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3])
    p, c, i = catmull_clark(points, counts, indices, 1)
    assert len(c) == 24 and (c == 4).all() and len(p) == 8 + 12 + 6
    np.testing.assert_allclose(np.abs(p[:8]), 5.0 / 9.0)
    np.testing.assert_allclose(np.sort(np.abs(p[8:20]), axis=1), np.tile([0.0, 0.75, 0.75], (12, 1)))
    np.testing.assert_allclose(np.sort(np.abs(p[20:]), axis=1), np.tile([0.0, 0.0, 1.0], (6, 1)))


def test_loop_refinement_of_a_tetrahedron_by_hand():
    """One Loop step of a regular tetrahedron: every vertex has valence 3, β = (5/8 − (3/8 + ¼ cos 120°)²)/3 = 3/16,
    so v' = 7/16·v + 3/16·Σ others; every edge point is 3/8·(a + b) + 1/8·(c + d); 4 × 4 triangles, each wound
    as its parent (outward normals stay outward)."""
    from bakery.usd.scene import loop_subdivide

    points = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])
    indices = np.array([0, 1, 2, 0, 3, 1, 0, 2, 3, 1, 3, 2])  # outward winding
    p, c, i, parent = loop_subdivide(points, np.full(4, 3), indices, 1, with_faces=True)
    assert len(c) == 16 and (c == 3).all() and len(p) == 4 + 6 and sorted(np.bincount(parent)) == [4] * 4
    total = points.sum(axis=0)
    np.testing.assert_allclose(p[:4], 7 / 16 * points + 3 / 16 * (total - points))
    for point in p[4:]:  # the edge whose midpoint it is nearest: a, b; c, d the other two corners
        a, b = np.argsort(np.linalg.norm(points - point, axis=1))[:2]
        c_d = total - points[a] - points[b]
        np.testing.assert_allclose(point, 0.375 * (points[a] + points[b]) + 0.125 * c_d)
    tris = p[i.reshape(-1, 3)]
    normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    assert np.all(np.einsum("ij,ij->i", normals, tris.mean(axis=1)) > 0)


def test_loop_refinement_keeps_a_planar_grid_and_its_regular_interior_vertices():
    """Linear precision: a triangulated planar grid stays in its plane, and a regular (valence-6) interior vertex of
    an affine grid stays where it is; boundary vertices follow the ¾, ⅛, ⅛ rule along the boundary."""
    from bakery.usd.scene import loop_subdivide

    n = 5
    xs, ys = np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64), indexing="ij")
    points = np.stack([xs.ravel() + 0.3 * ys.ravel(), ys.ravel(), np.zeros(n * n)], axis=1)  # an affine grid
    quads = [(i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1) for i in range(n - 1) for j in range(n - 1)]
    indices = np.array([[q[0], q[1], q[2], q[0], q[2], q[3]] for q in quads]).ravel()
    p, _c, _i = loop_subdivide(points, np.full(indices.size // 3, 3), indices, 2)
    assert np.all(p[:, 2] == 0)
    refined_once, _, _ = loop_subdivide(points, np.full(indices.size // 3, 3), indices, 1)
    centre = 2 * n + 2  # valence 6 in this triangulation
    np.testing.assert_allclose(refined_once[centre], points[centre], atol=1e-12)
    corner_edge = 2  # a boundary vertex on the edge i = 0: neighbours 1 and 3 along it
    np.testing.assert_allclose(refined_once[corner_edge], 0.75 * points[2] + 0.125 * (points[1] + points[3]))


def test_loop_meshes_are_refined_at_the_recipe_level(tmp_path):
    text = header() + """
def Mesh "Tetra"
{
    int[] faceVertexCounts = [3, 3, 3, 3]
    int[] faceVertexIndices = [0, 1, 2, 0, 3, 1, 0, 2, 3, 1, 3, 2]
    point3f[] points = [(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)]
    uniform token subdivisionScheme = "loop"
}
""" + probe("P", (0.0, 5.0, 0.0))
    path = write(tmp_path / "loop.usda", text)
    assert read_scene(path).scene.meshes[0].triangles.shape[0] == 4
    refined = read_scene(path, subdivision=2)
    assert refined.scene.meshes[0].triangles.shape[0] == 4 * 16
    assert any("loop subdivision refined 2 level(s)" in i.message for i in refined.issues)
    quads = write(tmp_path / "quads.usda", header() + box_mesh("Box", 1.0, "/NoMat").replace(
        "rel material:binding", 'uniform token subdivisionScheme = "loop"\n    rel material:binding') + probe("P"))
    reading = read_scene(quads, subdivision=1)
    assert reading.scene.meshes[0].triangles.shape[0] == 12
    assert any("not triangles" in i.message for i in reading.issues)


def test_subdivision_meshes_are_refined_at_the_recipe_level(tmp_path):
    text = header() + box_mesh("Box", 1.0, "/NoMat").replace(
        "rel material:binding", 'uniform token subdivisionScheme = "catmullClark"\n    rel material:binding') + probe("P")
    path = write(tmp_path / "subd.usda", text)
    cage = read_scene(path)
    assert cage.scene.meshes[0].triangles.shape[0] == 12
    assert any("control cage" in i.message for i in cage.issues)
    refined = read_scene(path, subdivision=2)
    assert refined.scene.meshes[0].triangles.shape[0] == 6 * 16 * 2
    radius = np.linalg.norm(refined.scene.meshes[0].triangles.reshape(-1, 3), axis=1)
    assert radius.max() < 1.0 and radius.min() > 0.5  # shrunk towards the limit surface


def test_time_code_selects_the_time_sample(tmp_path):
    """Default: authored defaults, else each attribute's earliest sample; time=T reads samples at T."""
    text = header() + """
def BakeryIrradianceProbe "P"
{
    double3 xformOp:translate.timeSamples = {0: (0, 0, 0), 10: (5, 0, 0)}
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def SphereLight "Lamp"
{
    float inputs:intensity.timeSamples = {0: 1, 10: 3}
}
"""
    path = write(tmp_path / "anim.usda", text)
    early, late = read_scene(path), read_scene(path, time=10.0)
    np.testing.assert_allclose(early.scene.probes[0].position, (0, 0, 0))
    np.testing.assert_allclose(late.scene.probes[0].position, (5, 0, 0))
    assert early.scene.lights[0].radiance[0] == pytest.approx(1.0) and late.scene.lights[0].radiance[0] == pytest.approx(3.0)
    assert early.scene.time_code is None and late.scene.time_code == 10.0


def test_animated_visibility_is_read_at_the_time_code(tmp_path):
    """A lamp and a box hidden from t = 10 (visibility time samples): present at t = 0, gone at t = 10 (before: the
    default-time visibility was read at every time)."""
    text = header() + """
def Xform "Set"
{
    token visibility.timeSamples = {0: "inherited", 10: "invisible"}
    def SphereLight "Lamp"
    {
        float inputs:intensity = 1
    }
    def Cube "Box"
    {
        double3 xformOp:translate = (3, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
}
def DistantLight "Sun"
{
}
""" + probe("P")
    path = write(tmp_path / "hide.usda", text)
    early, late = read_scene(path, time=0.0), read_scene(path, time=10.0)
    assert [m.name for m in early.scene.meshes] == ["/Set/Box"] and len(early.scene.lights) == 2
    assert not late.scene.meshes and [light.name for light in late.scene.lights] == ["/Sun"]


@pytest.mark.parametrize("kind", ["SphereLight", "DiskLight", "CylinderLight"])
def test_normalize_divides_by_the_world_space_area_in_stage_units(tmp_path, kind):
    """HdEmbree's areas: sphere 4πr² (ellipsoid formula for non-uniform scale), disk πr², cylinder 2πr·length, all
    with the xform scale, in stage units² (a 0.01 m/unit stage here)."""
    scale = 2.0
    text = header(meters_per_unit=0.01) + f"""
def {kind} "L"
{{
    float inputs:radius = 3
    float inputs:length = 5
    float inputs:intensity = 7
    bool inputs:normalize = 1
    float3 xformOp:scale = ({scale}, {scale}, {scale})
    uniform token[] xformOpOrder = ["xformOp:scale"]
}}
""" + probe("P")
    light = read_scene(write(tmp_path / f"{kind}.usda", text)).scene.lights[0]
    r, length = 3 * scale, 5 * scale
    area = {"SphereLight": 4 * math.pi * r * r, "DiskLight": math.pi * r * r,
            "CylinderLight": 2 * math.pi * r * length}[kind]
    assert light.radiance[0] == pytest.approx(7.0 / area, rel=1e-6)


def test_geometry_light_makes_its_meshes_emissive(tmp_path):
    text = header() + box_mesh("Box", 1.0, "/NoMat") + """
def GeometryLight "Glow"
{
    float inputs:intensity = 5
    color3f inputs:color = (1, 0.5, 0.25)
    rel geometry = </Box>
}
""" + probe("P", (0, 3, 0))
    reading = read_scene(write(tmp_path / "geo.usda", text))
    np.testing.assert_allclose(reading.scene.meshes[0].material.emission, (5.0, 2.5, 1.25))
    assert not reading.scene.lights


def test_point_instancer_prototypes_bring_their_lights_points_and_nested_instancers(tmp_path):
    """A street-lamp prototype (a pole, a SphereLight bulb at local (0, 3, 0), an invisible guide box, a proxy box)
    scattered by a PointInstancer whose second prototype is itself an instancer of points: each instance has its
    own bulb at instance position + (0, 3, 0) × scale, its pole, the nested instances multiply, and the invisible
    and proxy prims are skipped."""
    text = header() + f"""
def PointInstancer "Street"
{{
    rel prototypes = [</Street/Protos/Lamp>, </Street/Protos/Cluster>]
    int[] protoIndices = [0, 0, 1, 0]
    point3f[] positions = [(0, 0, 0), (4, 0, 0), (0, 0, 9), (8, 0, 0)]
    float3[] scales = [(1, 1, 1), (1, 2, 1), (1, 1, 1), (1, 1, 1)]
    def Scope "Protos"
    {{
        def Xform "Lamp"
        {{
            {box_mesh("Pole", 0.1, "/NoMat")}
            def SphereLight "Bulb"
            {{
                float inputs:radius = 0.1
                float inputs:intensity = 7
                double3 xformOp:translate = (0, 3, 0)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }}
            def Xform "Hidden" (
            )
            {{
                token visibility = "invisible"
                {box_mesh("HiddenBox", 0.5, "/NoMat")}
            }}
            def Xform "Proxy"
            {{
                uniform token purpose = "proxy"
                {box_mesh("ProxyBox", 0.5, "/NoMat")}
            }}
        }}
        def PointInstancer "Cluster"
        {{
            rel prototypes = </Street/Protos/Cluster/Protos/Dots>
            int[] protoIndices = [0, 0]
            point3f[] positions = [(0, 1, 0), (0, 2, 0)]
            def Scope "Protos"
            {{
                def Points "Dots"
                {{
                    point3f[] points = [(0, 0, 0), (1, 0, 0)]
                    float[] widths = [0.2, 0.2]
                }}
            }}
        }}
    }}
}}
""" + probe("P", (0, 5, 0))
    reading = read_scene(write(tmp_path / "street.usda", text))
    assert not reading.errors, reading.errors
    scene = reading.scene
    bulbs = sorted((light.name, tuple(np.round(light.position, 6))) for light in scene.lights)
    assert bulbs == [("/Street/Protos/Lamp/Bulb#0", (0.0, 3.0, 0.0)), ("/Street/Protos/Lamp/Bulb#1", (4.0, 6.0, 0.0)),
                     ("/Street/Protos/Lamp/Bulb#3", (8.0, 3.0, 0.0))]
    names = sorted(m.name for m in scene.meshes)
    assert [n for n in names if "Pole" in n] == [f"/Street/Protos/Lamp/Pole#{i}" for i in (0, 1, 3)]
    assert not [n for n in names if "Hidden" in n or "Proxy" in n]
    dots = [m for m in scene.meshes if "Dots" in m.name]
    assert sorted(m.name for m in dots) == ["/Street/Protos/Cluster/Protos/Dots#2#0", "/Street/Protos/Cluster/Protos/Dots#2#1"]
    centres = sorted(tuple(np.round(m.triangles.reshape(-1, 3).mean(axis=0), 3)) for m in dots)
    np.testing.assert_allclose(centres, [(0.5, 1.0, 9.0), (0.5, 2.0, 9.0)], atol=1e-3)
