"""UsdGeom as the specification and Hydra read it: the reader's meshes (``read_scene``) checked against the rules of
OpenUSD's ``pxr/usd/usdGeom`` schemas (mesh.h, gprim.h, pointInstancer.h, overview.dox) and of UsdImaging/Hydra
(``HdMeshUtil::ComputeTriangleIndices``, ``UsdImagingPointInstancerAdapter``, hdPrman's fallback material). Every
expectation is a closed form written from the rule: which faces, which corners, which normals, which material."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Usd, UsdGeom
from usd_scenes import header, material, probe, write

from bakery.usd.scene import read_scene

POINTS = [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1), (2, 0, 0), (2, 0, 1)]


def _read(tmp_path, body: str, **kwargs):
    reading = read_scene(write(tmp_path / "scene.usda", header() + probe("Probe", (0.0, 5.0, 0.0)) + body),
                         load_textures=False, **kwargs)
    return reading, {m.name: m for m in reading.scene.meshes}


def _mesh(name: str, counts, indices, extra: str = "", points=POINTS, scheme: str = "none") -> str:
    pts = ", ".join(f"({x}, {y}, {z})" for x, y, z in points)
    return f"""
def Mesh "{name}" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{{
    int[] faceVertexCounts = {list(counts)}
    int[] faceVertexIndices = {list(indices)}
    point3f[] points = [{pts}]
    uniform token subdivisionScheme = "{scheme}"
    {extra}
}}
"""


def _fan(counts, indices, skip=()) -> list[tuple[int, int, int]]:
    """HdMeshUtil's triangulation written out: face f with corners c0..c(n−1) → (c0, cj+1, cj+2), faces of fewer
    than 3 vertices and ``skip`` (holes) left out, in face order."""
    out, start = [], 0
    for face, n in enumerate(counts):
        corners = list(indices[start:start + n])
        if n >= 3 and face not in skip:
            out += [(corners[0], corners[j + 1], corners[j + 2]) for j in range(n - 2)]
        start += n
    return out


def _positions(triangles) -> np.ndarray:
    return np.array([[POINTS[i] for i in tri] for tri in triangles], dtype=np.float64)


# --------------------------------------------------------------------------------------------- faces and winding
def test_faces_of_fewer_than_three_vertices_are_skipped_as_hydra_skips_them(tmp_path):
    """HdMeshUtil::ComputeTriangleIndices: "skip degenerated face" (nv < 3) and draw the rest; UsdGeomMesh's
    ValidateTopology only requires the counts to sum to the indices and the indices to be points. Before, the
    whole mesh was an error."""
    counts, indices = [4, 2, 0, 3, 1], [0, 1, 2, 3, 0, 1, 1, 4, 5, 2]
    reading, meshes = _read(tmp_path, _mesh("M", counts, indices))
    assert not reading.errors
    assert any("fewer than 3 vertices" in i.message for i in reading.issues if i.prim == "/M")
    np.testing.assert_array_equal(meshes["/M"].triangles, _positions(_fan(counts, indices)))


def test_polygons_are_fanned_from_their_first_corner_as_hydra_does_also_when_concave(tmp_path):
    """A concave hexagon-free pentagon (an arrow) and a hole: HdMeshUtil fans every face from its first corner
    (_FanTriangulate), hole faces left out."""
    points = [(0, 0, 0), (2, 0, 0), (1, 0, 0.5), (2, 0, 1), (0, 0, 1), (3, 0, 0), (3, 0, 1)]
    counts, indices = [5, 4], [0, 1, 2, 3, 4, 1, 5, 6, 3]
    reading, meshes = _read(tmp_path, _mesh("A", counts, indices, points=points)
                            + _mesh("H", counts, indices, "int[] holeIndices = [0]", points=points))
    assert not reading.errors
    expected = np.array([[points[i] for i in t] for t in _fan(counts, indices)], dtype=np.float64)
    np.testing.assert_array_equal(meshes["/A"].triangles, expected)
    np.testing.assert_array_equal(meshes["/H"].triangles, expected[3:])  # face 1 only


@pytest.mark.parametrize(("orientation", "scale", "front"), [
    ("rightHanded", "(1, 1, 1)", 1), ("leftHanded", "(1, 1, 1)", -1),
    ("rightHanded", "(-1, 1, 1)", -1), ("leftHanded", "(1, -1, -1)", -1), ("leftHanded", "(-1, 2, 1)", 1)])
def test_mesh_front_follows_orientation_and_the_determinant(tmp_path, orientation, scale, front):
    """gprim.h/overview.dox: rightHanded (the fallback) fronts are the right-hand-rule side, leftHanded the other,
    and an odd number of negative scales (det < 0) flips it again."""
    reading, meshes = _read(tmp_path, _mesh("M", [3], [0, 1, 2], f'uniform token orientation = "{orientation}"\n'
                                            f"    float3 xformOp:scale = {scale}\n"
                                            '    uniform token[] xformOpOrder = ["xformOp:scale"]'))
    assert not reading.errors
    assert meshes["/M"].front == front


@pytest.mark.parametrize("kind", ["Cube", "Sphere", "Cylinder", "Cone", "Capsule"])
def test_implicit_surfaces_face_outward_whatever_their_orientation(tmp_path, kind):
    """overview.dox applies the winding rule "for all non-implicit surface and solid types"; Hydra meshes the
    implicit surfaces rightHanded (geomUtil's generators) whatever their ``orientation``. Only doubleSided and a
    mirroring transform change the front (the winding is outward: test_gprims.py)."""
    body = "\n".join(f"""
def {kind} "{name}"
{{
    uniform token orientation = "leftHanded"
    {extra}
    float3 xformOp:scale = {scale}
    uniform token[] xformOpOrder = ["xformOp:scale"]
}}""" for name, extra, scale in [("L", "", "(1, 1, 1)"), ("Mirrored", "", "(1, 1, -1)"),
                                  ("Both", "uniform bool doubleSided = 1", "(1, 1, 1)")])
    reading, meshes = _read(tmp_path, body)
    assert not reading.errors
    assert (meshes["/L"].front, meshes["/Mirrored"].front, meshes["/Both"].front) == (1, -1, 0)


def test_planes_are_double_sided_by_fallback(tmp_path):
    reading, meshes = _read(tmp_path, 'def Plane "P"\n{\n}\n'
                            'def Plane "One"\n{\n    uniform bool doubleSided = 0\n}\n')
    assert (meshes["/P"].front, meshes["/One"].front) == (0, 1)


# ------------------------------------------------------------------------------------------------------- normals
Q = [4, 3]
QI = [0, 1, 2, 3, 1, 4, 2]
TRI_FACES = [0, 0, 1]  # the face of each fan triangle of Q/QI
TRI_CORNERS = [(0, 1, 2), (0, 2, 3), (4, 5, 6)]  # face-vertex (faceVarying) positions of each triangle


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("interpolation", ["constant", "uniform", "vertex", "varying", "faceVarying"])
def test_primvars_normals_in_every_interpolation_and_indexed(tmp_path, interpolation):
    """mesh.h "A Note About Normals": ``primvars:normals`` has precedence over ``normals``; primvar interpolation
    (UsdGeom_Mesh_Primvars): constant one value, uniform one per face, vertex/varying one per point, faceVarying one
    per face-vertex; indexed primvars are flattened through their ``:indices``."""
    table = [_unit((k + 1, 1, 0.5 * k)) for k in range(3)]  # the indexed values
    count = {"constant": 1, "uniform": len(Q), "vertex": len(POINTS), "varying": len(POINTS),
             "faceVarying": len(QI)}[interpolation]
    idx = [(3 * k + 1) % 3 for k in range(count)]
    values = ", ".join(f"({v[0]}, {v[1]}, {v[2]})" for v in table)
    extra = (f'normal3f[] normals = [(0, -1, 0)] (interpolation = "constant")\n'
             f'    normal3f[] primvars:normals = [{values}] (interpolation = "{interpolation}")\n'
             f"    int[] primvars:normals:indices = {idx}")
    reading, meshes = _read(tmp_path, _mesh("M", Q, QI, extra))
    assert not reading.errors
    flat = [table[i] for i in idx]
    tris = _fan(Q, QI)
    expected = []
    for t, (face, corners) in enumerate(zip(TRI_FACES, TRI_CORNERS)):
        if interpolation == "constant":
            expected.append([flat[0]] * 3)
        elif interpolation == "uniform":
            expected.append([flat[face]] * 3)
        elif interpolation in ("vertex", "varying"):
            expected.append([flat[p] for p in tris[t]])
        else:
            expected.append([flat[c] for c in corners])
    np.testing.assert_allclose(meshes["/M"].normals, np.array(expected), atol=1e-6)


def test_normals_attribute_when_no_primvar_and_the_inverse_transpose(tmp_path):
    """``normals`` (with its own interpolation metadata) when ``primvars:normals`` is absent; normals transform by
    the inverse transpose of the world matrix: under scale (2, 1, 1), n = (1, 1, 0) becomes ∝ (1/2, 1, 0)."""
    extra = ('normal3f[] normals = [(1, 1, 0)] (interpolation = "constant")\n'
             "    float3 xformOp:scale = (2, 1, 1)\n    uniform token[] xformOpOrder = [\"xformOp:scale\"]")
    reading, meshes = _read(tmp_path, _mesh("M", Q, QI, extra))
    assert not reading.errors
    np.testing.assert_allclose(meshes["/M"].normals.reshape(-1, 3), np.tile(_unit((0.5, 1, 0)), (9, 1)), atol=1e-6)


def test_subdivision_meshes_ignore_authored_normals(tmp_path):
    """mesh.h: normals "should only be authored for polygonal meshes"; UsdImagingMeshAdapter populates them only
    when subdivisionScheme is "none"."""
    extra = 'normal3f[] primvars:normals = [(0, 1, 0)] (interpolation = "constant")'
    reading, meshes = _read(tmp_path, _mesh("M", Q, QI, extra, scheme="catmullClark"))
    assert meshes["/M"].normals is None


# ------------------------------------------------------------------------------- displayColor / displayOpacity
@pytest.mark.parametrize("interpolation", ["uniform", "vertex", "faceVarying"])
def test_display_color_of_the_fallback_surface_per_corner_and_indexed(tmp_path, interpolation):
    """Without a bound material Hydra's fallback surface shows ``displayColor`` (interpolated like any primvar;
    indexed primvars flattened): the mesh's corner colours are the primvar's values at the corners."""
    table = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)]
    count = {"uniform": len(Q), "vertex": len(POINTS), "faceVarying": len(QI)}[interpolation]
    idx = [(k * 2 + 1) % 3 for k in range(count)]
    extra = (f"color3f[] primvars:displayColor = {[tuple(c) for c in table]} (interpolation = \"{interpolation}\")\n"
             f"    int[] primvars:displayColor:indices = {idx}")
    reading, meshes = _read(tmp_path, _mesh("M", Q, QI, extra))
    assert not reading.errors
    flat = [table[i] for i in idx]
    tris = _fan(Q, QI)
    expected = [[flat[face]] * 3 if interpolation == "uniform" else
                [flat[p] for p in tris[t]] if interpolation == "vertex" else [flat[c] for c in corners]
                for t, (face, corners) in enumerate(zip(TRI_FACES, TRI_CORNERS))]
    np.testing.assert_allclose(meshes["/M"].colors, np.array(expected), atol=0)
    assert meshes["/M"].material.diffuse == pytest.approx(tuple(np.mean(flat, axis=0)))


def test_display_opacity_is_the_fallback_surfaces_presence_and_a_bound_material_ignores_both(tmp_path):
    """hdPrman's fallback material wires ``displayOpacity`` to ``presence`` and ``displayColor`` to the diffuse
    colour (rileyFallbackMaterialSceneIndexPlugin.cpp); a bound UsdPreviewSurface uses its own inputs."""
    extra = "color3f[] primvars:displayColor = [(1, 0, 0)]\n    float[] primvars:displayOpacity = [0.25]"
    body = material("Blue", diffuse=(0.0, 0.0, 1.0)) + _mesh("Bare", [3], [0, 1, 2], extra)
    body += _mesh("Bound", [3], [0, 1, 2], extra + "\n    rel material:binding = </Blue>")
    reading, meshes = _read(tmp_path, body)
    assert not reading.errors
    assert (meshes["/Bare"].material.diffuse, meshes["/Bare"].material.opacity) == ((1.0, 0.0, 0.0), 0.25)
    assert (meshes["/Bound"].material.diffuse, meshes["/Bound"].material.opacity) == ((0.0, 0.0, 1.0), 1.0)


def test_a_geom_subset_without_a_usable_material_shows_the_meshs_display_color(tmp_path):
    """UsdImagingMeshAdapter binds each materialBind subset's ComputeBoundMaterial (inherited from the mesh when
    the subset has none); the fallback surface reads the mesh's primvars — the subset has none of its own."""
    subset = """
    color3f[] primvars:displayColor = [(1, 0, 0)]
    def GeomSubset "S"
    {
        uniform token elementType = "face"
        uniform token familyName = "materialBind"
        int[] indices = [1]
    }"""
    reading, meshes = _read(tmp_path, _mesh("M", Q, QI, subset))
    assert not reading.errors
    assert meshes["/M"].material.diffuse == (1.0, 0.0, 0.0)
    assert meshes["/M#S"].material.diffuse == (1.0, 0.0, 0.0)
    np.testing.assert_array_equal(meshes["/M#S"].triangles, _positions(_fan(Q, QI))[2:])


# ------------------------------------------------------------------------------------- visibility, purpose, binding
def _tri(name: str, extra: str = "") -> str:
    return _mesh(name, [3], [0, 1, 2], extra)


def test_visibility_is_inherited_and_read_at_the_bakes_time(tmp_path):
    """imageable.h: ``invisible`` hides the prim and its descendants (ComputeVisibility); ``visibility`` is
    animatable: read at the bake's time (without one, the earliest sample)."""
    body = 'def Xform "Hidden"\n{\n    token visibility = "invisible"\n' + _tri("Kid") + "}\n"
    body += 'def Xform "Anim"\n{\n    token visibility.timeSamples = {1: "inherited", 2: "invisible"}\n'
    body += _tri("Kid") + "}\n"
    _, early = _read(tmp_path, body)
    _, late = _read(tmp_path, body, time=2.0)
    assert set(early) == {"/Anim/Kid"} and set(late) == set()


def test_render_and_default_purposes_are_drawn_proxy_and_guide_are_not(tmp_path):
    """imageable.h: a final-frame render draws "default" and "render" purposes; "proxy" stands in for render
    geometry in previews, "guide" is never rendered; purpose inherits to descendants."""
    body = "".join(_tri(name, f'uniform token purpose = "{purpose}"')
                   for name, purpose in [("D", "default"), ("R", "render"), ("P", "proxy"), ("G", "guide")])
    body += 'def Xform "GuideGroup"\n{\n    uniform token purpose = "guide"\n' + _tri("Kid") + "}\n"
    _, meshes = _read(tmp_path, body)
    assert set(meshes) == {"/D", "/R"}


def test_material_binding_purposes_strength_and_collections(tmp_path):
    """UsdShade: a full render resolves ``material:binding:full``, falling back to the all-purpose binding, never
    ``preview``; an ancestor's ``strongerThanDescendants`` binding wins over the prim's own; a collection binding
    applies to its members only; bindings inside an instanceable prototype hold on every instance."""
    mats = "".join(material(n, diffuse=c) for n, c in [("R", (1, 0, 0)), ("G", (0, 1, 0)), ("B", (0, 0, 1))])
    body = mats + _tri("Full", "rel material:binding = </R>\n    rel material:binding:full = </G>\n"
                               "    rel material:binding:preview = </B>")
    body += _tri("All", "rel material:binding = </R>\n    rel material:binding:preview = </B>")
    body += """
def Xform "Strong" (
    prepend apiSchemas = ["MaterialBindingAPI"]
)
{
    rel material:binding = </G> (bindMaterialAs = "strongerThanDescendants")
""" + _tri("Kid", "rel material:binding = </R>") + """}
def Xform "Coll" (
    prepend apiSchemas = ["MaterialBindingAPI", "CollectionAPI:set"]
)
{
    rel collection:set:includes = </Coll/In>
    rel material:binding:collection:set = [</Coll.collection:set>, </B>]
""" + _tri("In") + _tri("Out") + """}
def Xform "Proto"
{
""" + _tri("M", "rel material:binding = </G>") + """}
def Xform "Inst" (
    instanceable = true
    prepend references = </Proto>
)
{
}
"""
    reading, meshes = _read(tmp_path, body)
    assert not reading.errors
    names = {name: mesh.material.name for name, mesh in meshes.items()}
    assert names == {"/Full": "/G", "/All": "/R", "/Strong/Kid": "/G", "/Coll/In": "/B", "/Coll/Out": "<default>",
                     "/Proto/M": "/G", "/Inst/M": "/G"}


# ------------------------------------------------------------------------------------------------ point instancers
def _instancer(body: str, prototypes: str = "</PI/Protos/A>", protos: str = "", scope: str = "") -> str:
    return f"""
def PointInstancer "PI"
{{
    rel prototypes = [{prototypes}]
    {body}
    def Scope "Protos"
    {{
        {scope}
        def Mesh "A"
        {{
            double3 xformOp:translate = (0, 100, 0)
            uniform token[] xformOpOrder = ["xformOp:translate"]
            int[] faceVertexCounts = [3]
            int[] faceVertexIndices = [0, 1, 2]
            point3f[] points = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
            uniform token subdivisionScheme = "none"
        }}
        {protos}
    }}
}}
"""


PROTO = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def _quat_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The rotation of unit quaternion (w, x, y, z) acting on column vectors."""
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_instance_transforms_apply_the_prototype_transform_once_then_scale_orient_translate(tmp_path):
    """pointInstancer.h, instance transform: 1. the prototype root's local transform, 2. scales[i], 3. the
    rotation of orientations[i] (quath), 4. positions[i], 5. the instancer's own transform. Before, the
    prototype's transform was applied twice (IncludeProtoXform and again with the prototype's world)."""
    s = math.sqrt(0.5)
    body = """int[] protoIndices = [0, 0]
    point3f[] positions = [(0, 0, 0), (10, 0, 0)]
    quath[] orientations = [(1, 0, 0, 0), (%r, 0, %r, 0)]
    float3[] scales = [(1, 1, 1), (2, 1, 3)]
    double3 xformOp:translate = (0, 0, -5)
    uniform token[] xformOpOrder = ["xformOp:translate"]""" % (s, s)
    reading, meshes = _read(tmp_path, _instancer(body))
    assert not reading.errors
    rotation = _quat_matrix(float(np.float16(s)), 0, float(np.float16(s)), 0)
    for n, scale, rot, position in [(0, (1, 1, 1), np.eye(3), (0, 0, 0)), (1, (2, 1, 3), rotation, (10, 0, 0))]:
        local = PROTO + (0, 100, 0)
        expected = (rot @ (local * scale).T).T + position + (0, 0, -5)
        np.testing.assert_allclose(meshes[f"/PI/Protos/A#{n}"].triangles[0], expected, atol=2e-3)
    assert meshes["/PI/Protos/A#0"].front == 1


def test_a_mirroring_instance_scale_flips_the_front(tmp_path):
    reading, meshes = _read(tmp_path, _instancer("int[] protoIndices = [0]\n    point3f[] positions = [(0, 0, 0)]\n"
                                                 "    float3[] scales = [(-1, 1, 1)]"))
    assert meshes["/PI/Protos/A#0"].front == -1


def test_invisible_and_inactive_ids_mask_their_instances(tmp_path):
    """pointInstancer.h "Masking Instances": ``invisibleIds`` (animatable) and the ``inactiveIds`` list-op hide
    instances by id (``ids`` when authored, else the instance's index). Before, any mask made the whole instancer
    an error and its prototypes were drawn in place."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "scene.usda"))
    stage.GetRootLayer().ImportFromString(header() + probe("Probe", (0.0, 5.0, 0.0)) + _instancer(
        "int[] protoIndices = [0, 0, 0, 0]\n    point3f[] positions = [(0, 0, 0), (10, 0, 0), (20, 0, 0), (30, 0, 0)]\n"
        "    int64[] ids = [7, 8, 9, 10]\n    int64[] invisibleIds = [8]"))
    assert UsdGeom.PointInstancer(stage.GetPrimAtPath("/PI")).DeactivateId(10)
    stage.GetRootLayer().Save()
    reading = read_scene(tmp_path / "scene.usda", load_textures=False)
    assert not reading.errors
    assert sorted(m.name for m in reading.scene.meshes) == ["/PI/Protos/A#0", "/PI/Protos/A#2"]


def test_velocities_do_not_move_instances_at_a_sample_and_extrapolate_off_it(tmp_path):
    """overview.dox "Applying Timesampled Velocities": off a sample, p = p(t0) + v(t0)·(t − t0)/timeCodesPerSecond;
    at a sample, p(t0). Without a bake time the earliest sample is read (before: USD extrapolated to
    EarliestTime, −∞, an error)."""
    body = """int[] protoIndices = [0]
    point3f[] positions.timeSamples = {5: [(0, 0, 0)], 10: [(0, 50, 0)]}
    vector3f[] velocities.timeSamples = {5: [(0, 24, 0)], 10: [(0, 24, 0)]}"""
    for time, lift in [(None, 0.0), (5.0, 0.0), (7.0, 24.0 * 2 / 24.0)]:
        reading, meshes = _read(tmp_path, _instancer(body), time=time)
        assert not reading.errors, (time, reading.errors)
        np.testing.assert_allclose(meshes["/PI/Protos/A#0"].triangles[0], PROTO + (0, 100 + lift, 0), atol=1e-4)


def test_prototype_visibility_counts_from_the_prototype_root_down(tmp_path):
    """UsdImagingPointInstancerAdapter::_ComputeProtoVisibility: the prototype root's and its descendants'
    visibility, not that of the scope holding the prototypes; an invisible prototype root hides its instances."""
    hidden_scope = _instancer("int[] protoIndices = [0]\n    point3f[] positions = [(0, 0, 0)]",
                              scope='token visibility = "invisible"')
    _, meshes = _read(tmp_path, hidden_scope)
    assert set(meshes) == {"/PI/Protos/A#0"}
    hidden_root = _instancer("int[] protoIndices = [0, 1]\n    point3f[] positions = [(0, 0, 0), (5, 0, 0)]",
                             prototypes="</PI/Protos/A>, </PI/Protos/B>",
                             protos='def Xform "B"\n        {\n            token visibility = "invisible"\n'
                                    + _tri("M") + "        }")
    _, meshes = _read(tmp_path, hidden_root)
    assert set(meshes) == {"/PI/Protos/A#0"}


def test_constant_primvars_are_inherited_from_ancestors(tmp_path):
    """primvarsAPI.h (FindPrimvarWithInheritance): a constant primvar authored on an ancestor applies to the
    gprims below it that do not author their own, as Hydra's inherited primvars do — displayColor on a group."""
    body = 'def Xform "Group"\n{\n    color3f[] primvars:displayColor = [(0, 1, 0)]\n'
    body += _tri("Plain") + _tri("Own", "color3f[] primvars:displayColor = [(0, 0, 1)]") + "}\n"
    reading, meshes = _read(tmp_path, body)
    assert not reading.errors
    assert meshes["/Group/Plain"].material.diffuse == (0.0, 1.0, 0.0)
    assert meshes["/Group/Own"].material.diffuse == (0.0, 0.0, 1.0)


def test_extent_only_prims_and_zero_area_faces_are_read_without_errors(tmp_path):
    """A Mesh with only an ``extent`` has no faces (nothing drawn, no error); a zero-area face is a valid face
    (ValidateTopology) kept as a degenerate triangle, which no ray hits."""
    body = 'def Mesh "Empty"\n{\n    float3[] extent = [(-1, -1, -1), (1, 1, 1)]\n}\n'
    body += _mesh("Flat", [3, 3], [0, 1, 2, 0, 1, 4])  # the second face's corners are collinear
    reading, meshes = _read(tmp_path, body)
    assert not reading.errors
    assert "/Empty" not in meshes
    np.testing.assert_array_equal(meshes["/Flat"].triangles, _positions(_fan([3, 3], [0, 1, 2, 0, 1, 4])))


def test_a_probe_inside_a_prototype_is_reported_not_baked(tmp_path):
    """A probe is one placed prim; inside a PointInstancer prototype it would be one per instance, which nothing in
    the schema describes. It was skipped silently; now it is a warning naming it, and the instances still draw."""
    body = _instancer("point3f[] positions = [(0, 0, 0), (5, 0, 0), (9, 0, 0)]\n    int[] protoIndices = [0, 0, 1]",
                      prototypes="</PI/Protos/A>, </PI/Protos/Inner>", protos=probe("Inner"))
    reading, meshes = _read(tmp_path, body)
    assert not reading.errors and len(meshes) == 2
    assert [p.name for p in reading.scene.probes] == ["/Probe"]
    warned = [i for i in reading.issues if i.prim == "/PI/Protos/Inner"]
    assert warned and "PointInstancer prototype" in warned[0].message
