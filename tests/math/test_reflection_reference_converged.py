"""The converged reflection reference (``bakery.reflection.reference.converged_reflection`` and its image side
``bakery.environment.reflection_reference``, what the report and the reflection bench measure against) checked
against closed forms and quadratures written here, independently of bakery's BRDF code and of its texel geometry:

* white furnace: a uniform sky's E0 is the GGX directional albedo ∫ f_DV⟨n,l⟩ dl and E1 its Fresnel-tail part,
  integrated here over the half vector (u = NDF-inverted polar coordinate, Gauss–Legendre in u and over the visible
  arc of φ, which is closed form) — at α = 0.02 … 1 and n·v down to 0.05 on 64 × 32 and 1024 × 512 images;
* a linear sky L = 1 + y (y the image's polar axis, so every texel holds its exact average, a function of its row
  alone): E0 of the smooth sky by the same half-vector quadrature, which a 1024 × 512 image matches to ~1e-4;
* a one-texel sun on a 32 × 16 image: the exact answer is the background's albedo plus the sun's excess times the
  sun texel's own integral ∫_texel f_DV⟨n,l⟩ dl, done here over 400 × 400 sub-texels of exact solid angle;
* the mirror (α = 0) is the texel containing r, the α → 0 limit of the integral;
* the idealised split-sum's normalised kernel on a face-8 cube with one bright texel, against a 48 × 48 sub-texel
  brute force of every texel.
Texel centres fail every one of these where the lobe is narrow on a texel's scale; each test shows that too.
"""

import numpy as np
import pytest
from scipy.special import roots_legendre

from bakery.environment.layouts import EnvironmentImage
from bakery.environment.reflection_reference import CubeTexels, ImageTexels, cube_prefiltered, environment_reflection
from bakery.reflection.reference import integrate_reflection, reference_method


# ---------------------------------------------------------------------------------------------- independent maths
def smith_lambda(c: np.ndarray, alpha: float) -> np.ndarray:
    c = np.clip(c, 1e-150, 1.0)
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * (1.0 - c * c) / (c * c)) - 1.0)


def ggx_d(cos_h: np.ndarray, alpha: float) -> np.ndarray:
    a2 = alpha * alpha
    return np.where(cos_h > 0, a2 / (np.pi * (cos_h * cos_h * (a2 - 1.0) + 1.0) ** 2), 0.0)


def brdf_cosine(v: np.ndarray, n: np.ndarray, l: np.ndarray,  # noqa: E741
                alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """f_DV⟨n,l⟩₊ = D(h) G2(v, l) / (4 n·v) (height-correlated G2 = 1/(1 + Λ(v) + Λ(l))) and × (1 − v·h)⁵, for
    one (v, n) and directions l (K, 3)."""
    h = v + l
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    nl, nv = l @ n, float(v @ n)
    g2 = 1.0 / (1.0 + smith_lambda(np.array(nv), alpha) + smith_lambda(nl, alpha))
    f = np.where(nl > 0, ggx_d(h @ n, alpha) * g2 / (4.0 * nv), 0.0)
    return f, f * (1.0 - h @ v) ** 5


def lobe_integral(nv: float, alpha: float, sky=None, nu: int = 1000, nphi: int = 96) -> tuple[float, float]:
    """(∫ f_DV⟨n,l⟩ L dl, ∫ f_DV (1 − v·h)⁵⟨n,l⟩ L dl) in the local frame n = z, v = (√(1 − nv²), 0, nv), over the
    half vector: tan²θ_h = α² u/(1 − u) makes D cos θ_h dω_h = du dφ/2π, dω_l = 4 (v·h) dω_h, so the integrand is
    G2 (v·h)/((n·v) cos θ_h) L(l); n·l > 0 ⇔ cos φ > (n·v − 2 n·v cos²θ)/(2 cos θ sin θ_v sin θ), a closed-form arc.
    ``sky``: L of local directions (K, 3) → (K,), 1 when None."""
    x, w = roots_legendre(nu)
    u, wu = 0.5 * (x + 1.0), 0.5 * w
    xp, wp = roots_legendre(nphi)
    sin_v = np.sqrt(1.0 - nv * nv)
    cos_h = 1.0 / np.sqrt(1.0 + alpha * alpha * u / (1.0 - u))
    sin_h = np.sqrt(1.0 - cos_h * cos_h)
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = np.where(sin_v * sin_h > 0, (nv - 2.0 * nv * cos_h**2) / (2.0 * cos_h * sin_v * sin_h),
                         np.where(2.0 * cos_h**2 > 1.0, -np.inf, np.inf))
    arc = np.arccos(np.clip(bound, -1.0, 1.0))  # φ ∈ [−arc, arc]
    phi, wphi = arc[:, None] * xp[None, :], arc[:, None] * wp[None, :]
    h = np.stack([sin_h[:, None] * np.cos(phi), sin_h[:, None] * np.sin(phi),
                  np.broadcast_to(cos_h[:, None], phi.shape)], axis=-1)
    v = np.array([sin_v, 0.0, nv])
    vh = h @ v
    light = 2.0 * vh[..., None] * h - v
    nl = light[..., 2]
    g2 = 1.0 / (1.0 + smith_lambda(np.array(nv), alpha) + smith_lambda(nl, alpha))
    f = np.where(nl > 0, g2 * vh / (nv * cos_h[:, None]), 0.0)
    if sky is not None:
        f = f * sky(light.reshape(-1, 3)).reshape(f.shape)
    weight = wu[:, None] * wphi / (2.0 * np.pi)
    return float(np.sum(weight * f)), float(np.sum(weight * f * (1.0 - vh) ** 5))


def local_frame(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(3, 3) rows x, y, z of the frame with z = n and v in the xz half-plane x ≥ 0."""
    t = v - (v @ n) * n
    if np.linalg.norm(t) < 1e-9:
        t = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    t /= np.linalg.norm(t)
    return np.stack([t, np.cross(n, t), n])


def rows_at(nvs, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(v, n) rows with the given n·v, n and the view's azimuth spread over the sphere."""
    rng = np.random.default_rng(seed)
    vs, ns = [], []
    for nv in nvs:
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        t = np.cross(n, rng.normal(size=3))
        t /= np.linalg.norm(t)
        vs.append(nv * n + np.sqrt(1.0 - nv * nv) * t)
        ns.append(n)
    return np.array(vs), np.array(ns)


def towards(target: np.ndarray, nv: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A row (v, n) whose mirror direction 2(n·v)n − v is ``target``, at n·v = nv: n is the half vector of v and
    the target, v at angle 2 acos(nv) from it."""
    rng = np.random.default_rng(seed)
    t = np.cross(target, rng.normal(size=3))
    t /= np.linalg.norm(t)
    angle = 2.0 * np.arccos(nv)
    v = np.cos(angle) * target + np.sin(angle) * t
    n = v + target
    return v, n / np.linalg.norm(n)


# ---------------------------------------------------------------------------------------------- equirect geometry
def equirect_direction(rows: np.ndarray, cols: np.ndarray, h: int, w: int) -> np.ndarray:
    """Directions at continuous pixel positions: row 0 = +Y, column 0 = longitude +π, centre = +Z
    (schemas/store-v1.md, equirect_orientation)."""
    theta = np.pi * rows / h
    lon = np.pi - 2.0 * np.pi * cols / w
    return np.stack([np.sin(theta) * np.sin(lon), np.cos(theta), np.sin(theta) * np.cos(lon)], axis=-1)


def subtexels(row: int, col: int, h: int, w: int, f: int) -> tuple[np.ndarray, np.ndarray]:
    """Centres (f², 3) and exact solid angles (f²,) of texel (row, col) split into f × f sub-texels."""
    r = row + (np.arange(f) + 0.5) / f
    c = col + (np.arange(f) + 0.5) / f
    rr, cc = np.meshgrid(r, c, indexing="ij")
    edges = np.pi * (row + np.arange(f + 1) / f) / h
    band = (2.0 * np.pi / (w * f)) * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    return equirect_direction(rr, cc, h, w).reshape(-1, 3), np.repeat(band, f)


def uniform_image(h: int, w: int, value: float = 1.0) -> EnvironmentImage:
    return EnvironmentImage(np.full((h, w, 3), value, dtype=np.float32), "equirect")


# ---------------------------------------------------------------------------------------------- white furnace
NVS = (0.05, 0.2, 0.5, 0.8, 1.0)


@pytest.mark.parametrize("h,alphas", [(32, (0.02, 0.05, 0.1, 0.25, 0.5, 1.0)), (512, (0.02, 0.1, 1.0))])
def test_white_furnace_is_the_ggx_albedo(h, alphas):
    """Uniform sky: E0 = the directional albedo and E1 its Fresnel-tail part, to ≤ 1e-3, at every n·v ≥ 0.05; texel
    centres miss by far more where the lobe is narrow on the texel's scale (coarse image, or grazing)."""
    texels = ImageTexels(uniform_image(h, 2 * h))
    v, n = rows_at(NVS)
    for alpha in alphas:
        e0, e1 = environment_reflection(texels, v, n, alpha)
        truth = np.array([lobe_integral(nv, alpha) for nv in NVS])
        np.testing.assert_allclose(e0, np.repeat(truth[:, :1], 3, axis=1), atol=1e-3, err_msg=f"E0 α={alpha}")
        np.testing.assert_allclose(e1, np.repeat(truth[:, 1:], 3, axis=1), atol=1e-3, err_msg=f"E1 α={alpha}")
        centres = integrate_reflection(texels.samples, v, n, np.full(len(v), alpha))[0][:, 0]
        if alpha <= (0.1 if h < 100 else 0.02):  # the centres fail: coarse image, or grazing on the fine one
            assert np.max(np.abs(centres - truth[:, 0])) > (0.03 if h < 100 else 5e-3), alpha


def test_linear_sky_matches_its_smooth_integral():
    """L = 1 + y with each texel its exact average (a function of the row alone): E0 of the 1024 × 512 image within
    1e-3 of the smooth sky's, integrated over the half vector here."""
    h, w = 512, 1024
    lat = np.pi * (0.5 - np.arange(h + 1) / h)
    rows = 1.0 + 0.5 * (np.sin(lat[:-1]) + np.sin(lat[1:]))  # ⟨1 + y⟩ over a latitude band
    image = EnvironmentImage(np.ascontiguousarray(np.broadcast_to(rows[:, None, None], (h, w, 3)), np.float32),
                             "equirect")
    texels = ImageTexels(image)
    nvs = (0.05, 0.3, 0.7, 1.0)
    v, n = rows_at(nvs, seed=5)
    for alpha in (0.02, 0.1, 1.0):
        e0 = environment_reflection(texels, v, n, alpha)[0][:, 0]
        for i, nv in enumerate(nvs):
            up = local_frame(v[i], n[i]) @ np.array([0.0, 1.0, 0.0])  # +y in the local frame
            truth = lobe_integral(nv, alpha, sky=lambda d, up=up: 1.0 + d @ up)[0]
            assert e0[i] == pytest.approx(truth, abs=1e-3), (alpha, nv)


# ---------------------------------------------------------------------------------------------- one-texel sun
def test_a_one_texel_sun_is_integrated_over_its_exact_footprint():
    """32 × 16 sky of radiance 1 with a one-texel sun of 1000 (texels 11° wide): E0 = albedo + 999 ∫_sun f dl, the
    sun texel integrated here over 400² sub-texels. Rows aim r at the sun's centre, near its edge and two texels
    away (the sun in the lobe's tail)."""
    h, w, sun = 16, 32, (5, 11)
    pixels = np.ones((h, w, 3), np.float32)
    pixels[sun] = 1000.0
    texels = ImageTexels(EnvironmentImage(pixels, "equirect"))
    sub_dirs, sub_omega = subtexels(*sun, h, w, 400)
    targets = [equirect_direction(np.array(sun[0] + a), np.array(sun[1] + b), h, w)
               for a, b in ((0.5, 0.5), (0.1, 0.85), (2.5, 0.5), (0.5, -1.5))]
    rows = [towards(t / np.linalg.norm(t), nv, seed) for seed, t in enumerate(targets) for nv in (0.35, 1.0)]
    v, n = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
    for alpha in (0.02, 0.05, 0.2):
        e0, e1 = environment_reflection(texels, v, n, alpha)
        centres = integrate_reflection(texels.samples, v, n, np.full(len(v), alpha))[0][:, 0]
        exact = []
        for i in range(len(v)):
            f, tail = brdf_cosine(v[i], n[i], sub_dirs, alpha)
            base = lobe_integral(float(v[i] @ n[i]), alpha)
            exact.append((base[0] + 999.0 * np.sum(f * sub_omega), base[1] + 999.0 * np.sum(tail * sub_omega)))
        exact = np.array(exact)
        np.testing.assert_allclose(e0[:, 0], exact[:, 0], rtol=1e-3, atol=1e-3, err_msg=f"E0 α={alpha}")
        np.testing.assert_allclose(e1[:, 0], exact[:, 1], rtol=2e-3, atol=1e-3, err_msg=f"E1 α={alpha}")
        assert np.max(np.abs(centres / exact[:, 0] - 1.0)) > 0.1, alpha  # texel centres: far off


# ---------------------------------------------------------------------------------------------- the mirror
def test_the_mirror_is_the_texel_containing_r_and_the_limit_of_small_alpha():
    """α = 0: E0 = L of the texel containing r (this file's own pixel arithmetic), E1 = E0 (1 − n·v)⁵. It is the limit
    of the integral: with r inside a texel, E0 at α = 0.01 is that texel's radiance times the albedo — not a bilinear
    blend with its neighbours."""
    h, w = 16, 32
    pixels = np.random.default_rng(0).uniform(0.1, 4.0, (h, w, 3)).astype(np.float32)
    texels = ImageTexels(EnvironmentImage(pixels, "equirect"))
    v, n = rows_at(np.linspace(0.1, 1.0, 24), seed=7)
    e0, e1 = environment_reflection(texels, v, n, 0.0)
    r = 2.0 * np.sum(n * v, axis=1, keepdims=True) * n - v
    row = np.clip((np.arccos(np.clip(r[:, 1], -1, 1)) / np.pi * h).astype(int), 0, h - 1)
    col = np.floor((np.pi - np.arctan2(r[:, 0], r[:, 2])) / (2 * np.pi) * w).astype(int) % w
    np.testing.assert_array_equal(e0, pixels[row, col].astype(np.float64))
    np.testing.assert_allclose(e1, e0 * (1.0 - np.sum(n * v, axis=1, keepdims=True)) ** 5)
    # r at (0.3, 0.7) inside texel (6, 20): as α → 0, E0/albedo tends to that texel's radiance (GGX's heavy tail
    # still puts ~10 % of the lobe outside the 11° texel at α = 0.01), not to a blend with its neighbours
    target = equirect_direction(np.array(6.3), np.array(20.7), h, w)
    v1, n1 = towards(target, 0.8, 1)
    gaps = [np.max(np.abs(environment_reflection(texels, v1[None], n1[None], alpha)[0][0]
                          / lobe_integral(0.8, alpha)[0] / pixels[6, 20] - 1.0)) for alpha in (0.01, 0.003, 0.001)]
    assert gaps[0] > gaps[1] > gaps[2] and gaps[2] < 5e-3, gaps
    neighbours = pixels[5:8, 19:22].reshape(-1, 3)
    assert np.max(np.abs(neighbours / pixels[6, 20] - 1.0)) > 0.5  # a blend of them would be far off
    assert reference_method(texels, 0.0)["method"] == "mirror"


# ---------------------------------------------------------------------------------------------- idealised split-sum
def cube_subtexels(size: int, f: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directions (T f², 3), solid angles (T f²,) and texel index (T f²,) of every texel of a cube of face ``size``
    split into f × f sub-texels (face order +X, −X, +Y, −Y, +Z, −Z; u along columns, v along rows;
    schemas/store-v1.md cube_face_orientation); solid angles from the exact corner formula."""
    e = 2.0 * np.arange(size * f + 1) / (size * f) - 1.0
    corner = np.arctan2(e[:, None] * e[None, :], np.sqrt(e[:, None] ** 2 + e[None, :] ** 2 + 1.0))
    omega = corner[1:, 1:] - corner[:-1, 1:] - corner[1:, :-1] + corner[:-1, :-1]  # (N f, N f) [v, u]
    c = 0.5 * (e[:-1] + e[1:])
    v, u = np.meshgrid(c, c, indexing="ij")
    one = np.ones_like(u)
    faces = [(one, -v, -u), (-one, -v, u), (u, one, v), (u, -one, -v), (u, -v, one), (-u, -v, -one)]
    directions = np.stack([np.stack(q, axis=-1) for q in faces])
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    rows, cols = np.meshgrid(np.arange(size * f) // f, np.arange(size * f) // f, indexing="ij")
    texel = (np.arange(6)[:, None, None] * size + rows[None]) * size + cols[None]
    return directions.reshape(-1, 3), np.broadcast_to(omega, (6, *omega.shape)).reshape(-1), texel.reshape(-1)


def test_idealised_split_sum_kernel_converges_on_a_coarse_cube():
    """K_α(r, l) ∝ D(h)⟨r, l⟩₊ (v = n = r) normalised over the sphere, on a face-8 cube with one bright texel: within
    1e-3 of a 48 × 48 sub-texel brute force of every texel; a uniform cube stays exactly uniform."""
    size = 8
    cube = np.ones((6, size, size, 3), np.float32)
    cube[4, 3, 5] = 500.0
    texels = CubeTexels(cube)
    directions, omega, index = cube_subtexels(size, 48)
    radiance = cube.reshape(-1, 3)[index, 0].astype(np.float64)
    centre = directions[index == (4 * size + 3) * size + 5].mean(axis=0)
    rng = np.random.default_rng(2)
    r = centre + rng.normal(scale=0.08, size=(6, 3))
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    for alpha in (0.03, 0.2):
        got = cube_prefiltered(texels, r, alpha)
        t = directions @ r.T  # (S, M)
        k = ggx_d(np.sqrt(np.clip(0.5 * (1.0 + t), 0.0, 1.0)), alpha) * np.maximum(t, 0.0) * omega[:, None]
        exact = (radiance @ k) / k.sum(axis=0)
        np.testing.assert_allclose(got[:, 0], exact, rtol=1e-3, err_msg=f"α={alpha}")
        centres = texels.samples
        t = centres.directions @ r.T
        k = ggx_d(np.sqrt(np.clip(0.5 * (1.0 + t), 0.0, 1.0)), alpha) * np.maximum(t, 0.0)
        k *= centres.solid_angles[:, None]
        if alpha < 0.1:  # the texel-centre kernel quadrature (the bench's idealised split-sum before): far off
            assert np.max(np.abs((centres.radiance[:, 0] @ k) / k.sum(axis=0) / exact - 1.0)) > 0.1
        np.testing.assert_allclose(cube_prefiltered(CubeTexels(np.ones_like(cube)), r, alpha), 1.0, rtol=1e-12)
