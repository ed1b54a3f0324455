"""UsdSkel: skinned prims are baked where UsdSkel (and Hydra) puts them at the bake's time — before, their bind-pose
points were placed by their own transform, which UsdSkel ignores.

References: closed forms of linear-blend skinning for a translated and a rotated joint (p' = Σ_j w_j · p ·
inverse(bind_j) · world_j, the SkelRoot's transform after), a rigidly bound gprim, and pxr's ``UsdSkel.BakeSkinning``
— which writes the skinned points into the layer — read back as a plain mesh."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Usd, UsdSkel
from usd_scenes import header, write

from bakery.usd.scene import read_scene

#: SkelRoot at x = 10; a joint "Lift" bound at y = 1 and animated to y = 1 (t = 1), 3 (t = 10); a joint "Turn" at the
#: origin, turned 90° about +Y at t = 10; the Quad's own transform (z + 5) is ignored by UsdSkel.
SCENE = header(extra="    startTimeCode = 1\n    endTimeCode = 10\n") + """
def SkelRoot "Model"
{
    double3 xformOp:translate = (10, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Skeleton "Skel" (
        prepend apiSchemas = ["SkelBindingAPI"]
    )
    {
        uniform token[] joints = ["Root", "Root/Lift", "Root/Turn"]
        uniform matrix4d[] bindTransforms = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1)),
            ((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,1,0,1)), ((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1))]
        uniform matrix4d[] restTransforms = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1)),
            ((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,1,0,1)), ((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1))]
        rel skel:animationSource = </Model/Skel/Anim>
        def SkelAnimation "Anim"
        {
            uniform token[] joints = ["Root/Lift", "Root/Turn"]
            float3[] translations.timeSamples = { 1: [(0, 1, 0), (0, 0, 0)], 10: [(0, 3, 0), (0, 0, 0)] }
            quatf[] rotations.timeSamples = { 1: [(1, 0, 0, 0), (1, 0, 0, 0)],
                                              10: [(1, 0, 0, 0), (0.70710678, 0, 0.70710678, 0)] }
            half3[] scales = [(1, 1, 1), (1, 1, 1)]
        }
    }
    def Mesh "Quad" (
        prepend apiSchemas = ["SkelBindingAPI"]
    )
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, 1, 1), (1, 1, 1), (1, 1, -1), (-1, 1, -1)]
        normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)] (
            interpolation = "vertex"
        )
        int[] primvars:skel:jointIndices = [1, 1, 2, 2] (
            elementSize = 1
            interpolation = "vertex"
        )
        float[] primvars:skel:jointWeights = [1, 1, 1, 1] (
            elementSize = 1
            interpolation = "vertex"
        )
        rel skel:skeleton = </Model/Skel>
        double3 xformOp:translate = (0, 0, 5)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def Cube "Block" (
        prepend apiSchemas = ["SkelBindingAPI"]
    )
    {
        double size = 1
        int[] primvars:skel:jointIndices = [1] (
            elementSize = 1
            interpolation = "constant"
        )
        float[] primvars:skel:jointWeights = [1] (
            elementSize = 1
            interpolation = "constant"
        )
        rel skel:skeleton = </Model/Skel>
    }
}
"""


def _quad_points(t: float) -> np.ndarray:
    """The Quad's corners by hand: corners 0, 1 follow Lift (y + 2 at t = 10), corners 2, 3 follow Turn (90° about
    +Y at t = 10: (x, y, z) → (z, y, −x)); then the SkelRoot's x + 10."""
    points = np.array([(-1, 1, 1), (1, 1, 1), (1, 1, -1), (-1, 1, -1)], dtype=np.float64)
    if t == 10:
        points[:2, 1] += 2.0
        points[2:] = np.stack([points[2:, 2], points[2:, 1], -points[2:, 0]], axis=-1)
    return points + np.array([10.0, 0.0, 0.0])


def _mesh(reading, name: str):  # noqa: ANN001, ANN202
    (mesh,) = [m for m in reading.scene.meshes if m.name == name]
    return np.asarray(mesh.triangles, dtype=np.float64).reshape(-1, 3, 3)


@pytest.mark.parametrize("t", [1, 10])
def test_skinned_points_are_where_usdskel_puts_them(tmp_path, t):
    reading = read_scene(write(tmp_path / "skel.usda", SCENE), time=t)
    quad = _quad_points(t)
    np.testing.assert_allclose(_mesh(reading, "/Model/Quad"), quad[[[0, 1, 2], [0, 2, 3]]], atol=1e-6)
    lift = 1.0 if t == 1 else 3.0  # the rigidly bound Block rides Lift: its centre at (10, lift − 1, 0)
    block = _mesh(reading, "/Model/Block").reshape(-1, 3)
    np.testing.assert_allclose(0.5 * (block.min(axis=0) + block.max(axis=0)), [10.0, lift - 1.0, 0.0], atol=1e-6)
    assert [i for i in reading.issues if "authored normals are not skinned" in i.message]


def test_the_bake_agrees_with_pxr_bake_skinning(tmp_path):
    """UsdSkel.BakeSkinning writes the skinned points (and the rigid transform) into the layer; read back without
    the skeleton, the same triangles at both times."""
    path = write(tmp_path / "skel.usda", SCENE)
    baked = tmp_path / "baked.usda"
    stage = Usd.Stage.Open(str(path))
    assert UsdSkel.BakeSkinning(stage.Traverse())
    stage.GetRootLayer().Export(str(baked))
    for t in (1, 10):
        ours, theirs = read_scene(path, time=t), read_scene(baked, time=t)
        for name in ("/Model/Quad", "/Model/Block"):
            np.testing.assert_allclose(_mesh(ours, name), _mesh(theirs, name), atol=1e-5)


def test_a_skeleton_without_a_bind_pose_is_reported_and_its_prims_stay_in_their_bind_pose(tmp_path):
    """bindTransforms that do not match the joints: pxr would skin with identity bind transforms (the quad would
    jump by the joints' whole rest offsets); the prims stay where their points are, placed by their own transform."""
    broken = SCENE.replace("""        uniform matrix4d[] bindTransforms = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1)),
            ((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,1,0,1)), ((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1))]""",
                           "        uniform matrix4d[] bindTransforms = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1))]")
    assert broken != SCENE
    reading = read_scene(write(tmp_path / "broken.usda", broken), time=10)
    assert [i for i in reading.issues if "bindTransforms are missing or do not match" in i.message]
    rest = np.array([(-1, 1, 1), (1, 1, 1), (1, 1, -1), (-1, 1, -1)], dtype=np.float64) + np.array([10.0, 0.0, 5.0])
    np.testing.assert_allclose(_mesh(reading, "/Model/Quad"), rest[[[0, 1, 2], [0, 2, 3]]], atol=1e-6)
