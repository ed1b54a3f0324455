"""The geometry of the UsdLux dome layouts, against their definitions: the mirrored ball is the view ray reflected by
a mirrored sphere, and the vertical cross is a cube unfolded without a tear, whose centre face continues the latlong.

Every expected value here comes from geometry written out in the test (a reflection, an axis, a neighbouring
pixel), never from the functions under test."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bakery.environment.io import detect_layout
from bakery.environment.layouts import (
    VERTICAL_CROSS_CELLS,
    EnvironmentImage,
    direction_to_disc,
    equirect_directions,
    layout_directions_and_density,
    layout_inside,
)
from bakery.environment.resample import source_texel_solid_angles

N = 16  # vertical cross face size
AXES = {"+X": (1, 0, 0), "-X": (-1, 0, 0), "+Y": (0, 1, 0), "-Y": (0, -1, 0), "+Z": (0, 0, 1), "-Z": (0, 0, -1)}


def _disc_pixel(u, v, size=512):
    return np.array([(1.0 - v) * 0.5 * size]), np.array([(u + 1.0) * 0.5 * size])


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.999, 0.999), st.floats(-0.999, 0.999))
def test_a_mirrored_ball_pixel_sees_the_view_ray_reflected_about_the_ball_normal(u, v):
    """An orthographic camera looking down −Z at a unit mirrored sphere: the pixel (u, v) sees the ray (0, 0, −1)
    reflected about the normal (u, v, √(1−u²−v²)), r = d − 2(d·n)n."""
    if u * u + v * v >= 0.998:
        return
    normal = np.array([u, v, np.sqrt(1.0 - u * u - v * v)])
    view = np.array([0.0, 0.0, -1.0])
    reflected = view - 2.0 * (view @ normal) * normal
    rows, cols = _disc_pixel(u, v)
    direction, _ = layout_directions_and_density("mirrored_ball", rows, cols, 512, 512)
    np.testing.assert_allclose(direction[0], reflected, atol=1e-9)
    back_rows, back_cols = direction_to_disc("mirrored_ball", direction, 512, 512)
    np.testing.assert_allclose([back_rows[0], back_cols[0]], [rows[0], cols[0]], atol=1e-6)


@settings(max_examples=100, deadline=None)
@given(st.floats(-0.999, 0.999), st.floats(-0.999, 0.999))
def test_an_angular_map_pixel_is_at_the_angle_its_radius_says(u, v):
    """Debevec's angular map: the angle from +Z is π·r and the azimuth is the pixel's (u right, v up)."""
    r = np.hypot(u, v)
    if r >= 0.999 or r < 1e-6:
        return
    rows, cols = _disc_pixel(u, v)
    direction, _ = layout_directions_and_density("angular", rows, cols, 512, 512)
    assert np.arccos(np.clip(direction[0, 2], -1, 1)) == pytest.approx(np.pi * r, abs=1e-9)
    np.testing.assert_allclose(direction[0, :2] / np.hypot(*direction[0, :2]), [u / r, v / r], atol=1e-9)
    back_rows, back_cols = direction_to_disc("angular", direction, 512, 512)
    np.testing.assert_allclose([back_rows[0], back_cols[0]], [rows[0], cols[0]], atol=1e-6)


@pytest.mark.parametrize("layout,height,width", [("angular", 1024, 1024), ("mirrored_ball", 1024, 1024),
                                                 ("vertical_cross", 4 * 64, 3 * 64)])
def test_texel_solid_angles_cover_the_sphere(layout, height, width):
    """Σ Ω over the valid texels = 4π (the disc maps to within their rim texels' partial coverage)."""
    image = EnvironmentImage(np.zeros((height, width, 3), np.float32), layout)
    omega = source_texel_solid_angles(image)
    tolerance = 1e-9 if layout == "vertical_cross" else 2e-2
    assert omega.sum() == pytest.approx(4.0 * np.pi, rel=tolerance)


def test_mirrored_ball_solid_angle_is_uniform_over_the_disc():
    """dΩ = sin θ dθ dφ with θ = 2 asin r: sin θ·dθ/dr = 4r, so dΩ = 4 r dr dφ = 4 dA — 16/(W·H) per pixel."""
    rows, cols = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5, indexing="ij")
    _, density = layout_directions_and_density("mirrored_ball", rows, cols, 64, 64)
    inside = layout_inside("mirrored_ball", rows, cols, 64, 64)
    np.testing.assert_allclose(density[inside], 16.0 / (64 * 64))
    assert np.all(density[~inside] == 0)


def _cross_direction(rows, cols):
    directions, _ = layout_directions_and_density("vertical_cross", np.asarray(rows, float), np.asarray(cols, float),
                                                  4 * N, 3 * N)
    return directions


def test_vertical_cross_face_centres_are_the_axes_of_their_cells():
    for face, (cell_row, cell_col) in VERTICAL_CROSS_CELLS.items():
        centre = _cross_direction([(cell_row + 0.5) * N], [(cell_col + 0.5) * N])[0]
        np.testing.assert_allclose(centre, AXES[face], atol=1e-12)


def test_vertical_cross_centre_face_continues_the_latlong_centre():
    """Right of the centre looks the same way in the cross and in the latlong (towards −X), above looks up (+Y):
    the cross is the latlong's view from inside, not its mirror image."""
    step = 0.25
    right = _cross_direction([1.5 * N], [1.5 * N + step * N / 2])[0]
    up = _cross_direction([1.5 * N - step * N / 2], [1.5 * N])[0]
    latlong_right = equirect_directions(np.array(64.0), np.array(128.0 + 4.0), 128, 256)
    assert right[0] < 0 and latlong_right[0] < 0 and abs(right[1]) < 1e-12
    assert up[1] > 0 and abs(up[0]) < 1e-12


@pytest.mark.parametrize("upper,lower", [((0, 1), (1, 1)), ((1, 1), (2, 1)), ((2, 1), (3, 1))])
def test_vertical_cross_is_continuous_across_its_vertical_seams(upper, lower):
    """Pixels just above and just below a shared edge of the image look in the same direction (to the pixel)."""
    cols = upper[1] * N + np.arange(N) + 0.5
    eps = 1e-6
    above = _cross_direction(np.full(N, lower[0] * N - eps), cols)
    below = _cross_direction(np.full(N, lower[0] * N + eps), cols)
    np.testing.assert_allclose(above, below, atol=1e-5)


@pytest.mark.parametrize("left,right", [((1, 0), (1, 1)), ((1, 1), (1, 2))])
def test_vertical_cross_is_continuous_across_its_horizontal_seams(left, right):
    rows = left[0] * N + np.arange(N) + 0.5
    eps = 1e-6
    a = _cross_direction(rows, np.full(N, right[1] * N - eps))
    b = _cross_direction(rows, np.full(N, right[1] * N + eps))
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_vertical_cross_folds_into_a_closed_cube():
    """Every point on a face's border is also on the border of exactly one other face: the six faces close up
    (the cube's twelve edges, the seven folded ones included), and the valid texels' directions are distinct."""
    t = np.arange(N) + 0.5
    borders = []
    for face, (r, c) in VERTICAL_CROSS_CELLS.items():
        eps = 1e-9
        top = np.stack([np.full(N, r * N + eps), c * N + t], -1)
        bottom = np.stack([np.full(N, (r + 1) * N - eps), c * N + t], -1)
        left = np.stack([r * N + t, np.full(N, c * N + eps)], -1)
        right = np.stack([r * N + t, np.full(N, (c + 1) * N - eps)], -1)
        points = np.concatenate([top, bottom, left, right])
        borders.append((face, _cross_direction(points[:, 0], points[:, 1])))
    for face, directions in borders:
        others = np.concatenate([d for f, d in borders if f != face])
        nearest = np.min(np.linalg.norm(directions[:, None, :] - others[None, :, :], axis=-1), axis=1)
        assert nearest.max() < 1e-6, face
    rows, cols = np.meshgrid(np.arange(4 * N) + 0.5, np.arange(3 * N) + 0.5, indexing="ij")
    inside = layout_inside("vertical_cross", rows, cols, 4 * N, 3 * N)
    assert inside.sum() == 6 * N * N
    directions = np.round(_cross_direction(rows[inside], cols[inside]), 9)
    assert len(np.unique(directions, axis=0)) == 6 * N * N


def test_aspect_ratios_name_their_layouts():
    assert detect_layout(3 * 128, 4 * 128) == "vertical_cross"
    assert detect_layout(512, 512) == "angular"  # a mirrored ball has the same shape: it is always named
