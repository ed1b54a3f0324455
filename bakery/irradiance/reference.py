"""Exact reference irradiance: brute-force cosine convolution of a full-resolution quadrature, and the two fast
formulations the bake's per-probe diagnostics use.

Brute force (:func:`reference_irradiance`, the ground truth every irradiance encoding is measured against)
    E(n) = Σ_s L(ω_s) max(0, n·ω_s) Ω_s, evaluated as chunked matrix products (D × S cosine kernel times S × C
    radiance·Ω). Independent of SH.

Cube captures (:func:`reference_irradiance_cubes`; probes whose reference is their capture, e.g. scene probes)
    The cube's texels are the quadrature, so the brute force at D directions is one fixed linear operator
        K[d, t] = max(0, n_d·c_t) Ω_t        (D × 6N², float32; environment-independent, cached per face size)
    applied as one GEMM to the whole batch, E = K · L (6N² × 3P). Same sum as the brute force; only the float32
    summation order differs (relative ~1e-6). K is cached up to 128 MB (64² faces at D = 1024), streamed above.

Full-resolution quadratures (:func:`reference_irradiance_binned`; distant probes: the source image)
    Brute force costs D × S per probe (S = 0.5 M texels for a 1k equirect: 2.2 s). Instead (quadratures of at
    most ``EXACT_BRIGHTEST`` samples stay entirely brute force; steps 1–2 do not depend on the normals, and a bake
    holds their result, :class:`BinnedQuadrature`, built band by band, instead of the samples):
    1. the ``EXACT_BRIGHTEST`` = 1024 samples of largest luminance flux (the sun) are integrated by brute force;
    2. every other sample is binned into the texel t of a reference cube of face ``REFERENCE_FACE_SIZE`` = 48 that
       contains it, keeping per texel its flux Φ_t = Σ Ω_s L_s and first moment m_t = Σ Ω_s L_s ω_s (per channel);
       48 is the measured compromise: the error falls as ~1/N² (ρ on city 1.6e-4, 7e-5, 4e-5 at N = 32, 48, 64)
       while the straddling texels, the only ones evaluated per texel, grow as N;
    3. texels entirely on the positive side of n (all four corners n·corner ≥ 0: a texel is a convex spherical
       quadrilateral) contribute n·m_t — *exactly*, the cosine being linear there; texels entirely on the negative
       side contribute 0, exactly; only the texels straddling the terminator of n are approximated, by
       max(0, n·c_t) Φ_t at the texel centre c_t. On a face, n·direction has the sign of a linear function of
       (u, v), so in each texel row the positive texels are one run of columns and the straddling ones another
       (:func:`_row_intervals`): Σ_{t positive} m_t is a difference of the rows' prefix sums M, and with the fixed
       sparse operators Q (±1 at each row's run ends, D × 6N(N+1)) and S[d, t] = [t straddles n_d] max(0, n_d·c_t)
       (D × 6N², about 12N entries per row; both O(D·N) to build, cached) the batch is two sparse products:
           E_c(n_d) = Σ_j n_dj (Q · M_{·cj})_d + (S · Φ_{·c})_d + E_c^bright(n_d).
    Error bound (a straddling texel has |n·ω| ≤ δ over it, δ = the largest texel chord, ``texel_chord(48)`` =
    0.059, and both the truth and the approximation lie in [0, δ Φ_t]):
        |E_c(n) − E_c^ref(n)| ≤ δ · Σ_{t straddles n} Φ_{t,c}     (Φ without the brightest samples),
    computed a posteriori by :func:`binned_error_bound`; the relative RMSE an encoding reports then moves by at
    most ρ(1 + err)/(1 − ρ), ρ = ‖E − E^ref‖ / ‖E^ref‖ (triangle inequality). Measured (D = 1024) against the
    brute force: ρ = 3.1e-5 (StinsonBeach 512), 7.3e-5 (city 512), 2.3e-5 (park 1k), 7.0e-5 (lobby 1k); the
    reported errors of sh2, sh3, zh3, zh3_hallucinated moved by ≤ 4.7e-4 relative (city, whose errors are small),
    ≤ 6e-5 absolute (tests/math/test_irradiance_reference_fast.py). Cost: 0.1–0.2 s per 1k image instead of
    2.5–3.1 s (most of it binning the 0.5 M samples; the GEMMs are ~10 ms).

Notation
    D directions n_d, S quadrature samples ω_s (Ω_s, L_s), T = 6N² cube texels (centres c_t), C = 3 channels.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.sphere.cubemap import (
    _FACE_FRAMES,
    cube_face_uv_to_direction,
    cube_texel_directions,
    cube_texel_solid_angles,
    direction_to_cube_texel,
)
from bakery.sphere.grid import SphericalSamples

#: Face size of the reference cube that full-resolution quadratures are binned into (module doc).
REFERENCE_FACE_SIZE = 48
#: Samples of largest luminance flux integrated by brute force before binning (module doc).
EXACT_BRIGHTEST = 1024
#: Cube face sizes whose operators are cached (the capture operator D × 6N² float32, 57 MB at N = 48, D = 1024;
#: the binned reference's sparse ones, about 12N entries per direction).
_CACHE_FACES = 4
#: Largest capture operator cached (elements; 128 MB float32: 64² faces at D = 1024); larger ones are streamed.
_MAX_CACHED_ELEMENTS = 1 << 25


def reference_irradiance(
    samples: SphericalSamples, normals: np.ndarray, chunk_elements: int = 1 << 24, dtype: type = np.float64
) -> np.ndarray:
    """Irradiance (N, C) at unit normals (N, 3) by brute-force integration over ``samples``.

    ``dtype=np.float32`` halves the time (relative rounding ~√T·2⁻²⁴); tests use float64.
    """
    weighted = (samples.radiance * samples.solid_angles[:, None]).astype(dtype)  # (T, C) = L·Ω
    directions = samples.directions.T.astype(dtype)  # (3, T)
    normals = np.asarray(normals, dtype=dtype)
    out = np.zeros((normals.shape[0], weighted.shape[1]), dtype=np.float64)
    rows = max(1, chunk_elements // max(1, directions.shape[1]))
    for start in range(0, normals.shape[0], rows):
        cosine = normals[start : start + rows] @ directions
        np.maximum(cosine, 0.0, out=cosine)
        out[start : start + rows] = cosine @ weighted
    return out


def relative_rmse(estimate: np.ndarray, reference: np.ndarray) -> float:
    """√(Σ (E − E_ref)²) / √(Σ E_ref²) over all directions and channels (uniformly weighted directions)."""
    denominator = np.sqrt(np.sum(reference**2))
    return float(np.sqrt(np.sum((estimate - reference) ** 2)) / denominator) if denominator > 0 else 0.0


# ------------------------------------------------------------------------------------------- fixed operators
def _key(normals: np.ndarray) -> tuple[int, bytes]:
    """Cache key of a direction set: its count and float64 bytes (24 kB at D = 1024)."""
    normals = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    return normals.shape[0], normals.tobytes()


_NORMALS: dict[tuple[int, bytes], np.ndarray] = {}


def _remember(normals: np.ndarray) -> tuple[int, bytes]:
    key = _key(normals)
    _NORMALS.setdefault(key, np.array(normals, dtype=np.float64).reshape(-1, 3))
    return key


@lru_cache(maxsize=_CACHE_FACES)
def _cube_operator(face_size: int, key: tuple[int, bytes]) -> np.ndarray:
    """K[d, t] = max(0, n_d·c_t) Ω_t (D, 6N²) float32 (module doc "Cube captures")."""
    normals = _NORMALS[key]
    centres = cube_texel_directions(face_size).reshape(-1, 3)
    k = np.maximum(normals @ centres.T, 0.0) * cube_texel_solid_angles(face_size).reshape(1, -1)
    k = k.astype(np.float32)
    k.setflags(write=False)
    return k


def _corner_grid(face_size: int) -> np.ndarray:
    """Texel corner directions (6, N+1, N+1, 3) (shared by neighbouring texels)."""
    c = np.linspace(-1.0, 1.0, face_size + 1)
    v, u = np.meshgrid(c, c, indexing="ij")
    faces = np.broadcast_to(np.arange(6)[:, None, None], (6, face_size + 1, face_size + 1))
    return cube_face_uv_to_direction(faces, u[None], v[None])


def _texel_corners(face_size: int) -> np.ndarray:
    """Corner directions (4, 6N², 3) of every texel."""
    grid = _corner_grid(face_size)
    parts = (grid[:, :-1, :-1], grid[:, 1:, :-1], grid[:, :-1, 1:], grid[:, 1:, 1:])
    return np.stack([q.reshape(-1, 3) for q in parts])


def texel_chord(face_size: int) -> float:
    """δ: the largest chord |ω − ω'| between two points of one cube texel (its longest diagonal; centre texels of
    a face are the largest)."""
    corners = _texel_corners(face_size)
    return float(max(np.linalg.norm(corners[0] - corners[3], axis=-1).max(),
                     np.linalg.norm(corners[1] - corners[2], axis=-1).max()))


def _row_intervals(normals: np.ndarray, face_size: int) -> tuple[np.ndarray, ...]:
    """Per normal d, face f and texel row r (arrays (D, 6, N) int64): the columns [p0, p1) of the texels entirely on
    the positive side of n_d and [s0, s1) of those straddling it (module doc "Full-resolution quadratures").

    On face f a direction is ∝ F0 + u·F1 + v·F2 (``_FACE_FRAMES``), so n·direction has the sign of the linear
    γ + α u + β v (γ, α, β = n·F0, n·F1, n·F2). A texel (corners u_c, u_{c+1} × v_r, v_{r+1}) is positive when the
    least of it over the corners is ≥ 0, negative when the largest is ≤ 0; in a row both are monotone in c, so the
    positive texels are one run of columns, the negative ones another at the other end, and the straddling ones the
    run between: thresholds, not D × 6N² corner signs."""
    n = face_size
    g, a, b = (normals @ _FACE_FRAMES[:, k, :].T for k in range(3))  # (D, 6) each: γ, α, β
    v = np.linspace(-1.0, 1.0, n + 1)
    bv_lo, bv_hi = b[..., None] * v[None, None, :-1], b[..., None] * v[None, None, 1:]  # β v_r, β v_{r+1}
    b_min, b_max = np.minimum(bv_lo, bv_hi), np.maximum(bv_lo, bv_hi)  # (D, 6, N)
    alpha = np.broadcast_to(a[..., None], b_min.shape)
    gamma = g[..., None]
    with np.errstate(divide="ignore", invalid="ignore"):
        # column c's corners u_c = −1 + 2c/N: α·u ≥ T holds for c ≥ (T/α + 1)·N/2 (α > 0) or c + 1 ≤ … (α < 0)
        pos_t = (-gamma - b_min) / alpha  # positive: min_c(α u) ≥ −γ − β_min
        neg_t = (-gamma - b_max) / alpha  # negative: max_c(α u) ≤ −γ − β_max
        pos_edge = (pos_t + 1.0) * (0.5 * n)
        neg_edge = (neg_t + 1.0) * (0.5 * n)
    rising = alpha > 0
    flat = alpha == 0

    def clip(x: np.ndarray) -> np.ndarray:  # α = 0 gives ±inf or NaN here; those entries are replaced below (flat)
        with np.errstate(invalid="ignore"):
            return np.clip(x, 0, n, out=x).astype(np.int64)

    # α > 0: positive [ceil(pos_edge), N), negative [0, floor(neg_edge)); α < 0: positive [0, floor(pos_edge)),
    # negative [ceil(neg_edge), N)
    p0 = np.where(rising, clip(np.ceil(pos_edge)), 0)
    p1 = np.where(rising, n, clip(np.floor(pos_edge)))
    q0 = np.where(rising, 0, clip(np.ceil(neg_edge)))
    q1 = np.where(rising, clip(np.floor(neg_edge)), n)
    all_positive, all_negative = gamma + b_min >= 0, gamma + b_max <= 0  # α = 0: the row is one kind
    p0, p1 = np.where(flat, 0, p0), np.where(flat, np.where(all_positive, n, 0), p1)
    q0, q1 = np.where(flat, 0, q0), np.where(flat, np.where(all_negative & ~all_positive, n, 0), q1)
    p1 = np.maximum(p1, p0)
    q1 = np.maximum(q1, q0)
    # the straddling run lies between the negative and the positive runs
    s0 = np.where(flat, 0, np.where(rising, q1, p1))
    s1 = np.where(flat, np.where(~all_positive & ~all_negative, n, 0), np.where(rising, p0, q0))
    return p0, p1, np.minimum(s0, s1), s1


@lru_cache(maxsize=_CACHE_FACES)
def _binned_operators(face_size: int, key: tuple[int, bytes]):  # noqa: ANN202 - (csr, csr)
    """Sparse Q (D, 6N(N+1)) and S (D, 6N²) float32 (module doc "Full-resolution quadratures"): Q · M, with M the
    moments' prefix sums along each texel row, is Σ_{t positive for n_d} m_t (+1 at the end of a row's positive
    run, −1 at its start); S[d, t] = max(0, n_d·c_t) over the texels t straddling n_d. O(D·N) to build."""
    from scipy.sparse import csr_matrix

    normals = _NORMALS[key]
    d, n = normals.shape[0], face_size
    p0, p1, s0, s1 = _row_intervals(normals, n)
    rows = (np.arange(6)[:, None] * n + np.arange(n)[None, :]).reshape(1, 6, n) * (n + 1)  # prefix row offsets
    columns = np.stack([rows + p1, rows + p0], axis=-1).reshape(d, -1)  # (D, 12N)
    signs = np.tile(np.array([1.0, -1.0], dtype=np.float32), 6 * n)
    keep = (p1 > p0).reshape(d, -1).repeat(2, axis=1)
    q = csr_matrix((np.broadcast_to(signs, columns.shape)[keep], columns[keep],
                    np.concatenate([[0], np.cumsum(keep.sum(axis=1))])), shape=(d, 6 * n * (n + 1)))
    counts = (s1 - s0).reshape(d, -1)  # straddling texels per (face, row)
    run = np.repeat(np.arange(counts.size), counts.reshape(-1))
    offset = np.arange(run.size) - np.repeat(np.cumsum(counts.reshape(-1)) - counts.reshape(-1), counts.reshape(-1))
    texel = ((run % (6 * n)) * n + s0.reshape(-1)[run] + offset).astype(np.int64)  # (f·N + r)·N + c
    normal = run // (6 * n)
    centres = cube_texel_directions(n).reshape(-1, 3)
    weight = np.maximum(np.einsum("ij,ij->i", normals[normal], centres[texel]), 0.0).astype(np.float32)
    straddle = csr_matrix((weight, texel, np.concatenate([[0], np.cumsum(counts.sum(axis=1))])), shape=(d, 6 * n * n))
    return q, straddle


def _texel_sides(normals: np.ndarray, face_size: int) -> tuple[np.ndarray, np.ndarray]:
    """(D, 6N²) bool: texel entirely on the positive side of n (all corners n·corner ≥ 0), texel straddling n.
    The signs are taken once per corner of the (N+1)² corner grid, then combined over each texel's four."""
    n = face_size
    # float32 signs: a corner within 1e-7 of the terminator may flip, erring by ≤ 1e-7 Φ_t
    dots = normals.astype(np.float32) @ _corner_grid(n).reshape(-1, 3).T.astype(np.float32)  # (D, 6(N+1)²)
    sign_pos = (dots >= 0.0).reshape(-1, 6, n + 1, n + 1)
    sign_neg = (dots <= 0.0).reshape(-1, 6, n + 1, n + 1)
    del dots

    def all_four(g: np.ndarray) -> np.ndarray:
        return (g[..., :-1, :-1] & g[..., 1:, :-1] & g[..., :-1, 1:] & g[..., 1:, 1:]).reshape(g.shape[0], -1)

    positive = all_four(sign_pos)
    return positive, ~positive & ~all_four(sign_neg)


# ------------------------------------------------------------------------------------------- fast references
def reference_irradiance_cubes(cubes: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Irradiance (P, D, 3) float32 of cube captures (P, 6, N, N, 3) at unit normals (D, 3): the brute force over
    the cube texels as one GEMM with the cached operator (module doc "Cube captures"). Operators above
    ``_MAX_CACHED_ELEMENTS`` (large faces or direction sets) are not cached but built per call in texel chunks."""
    cubes = np.asarray(cubes, dtype=np.float32)
    p, n = cubes.shape[0], cubes.shape[2]
    t = 6 * n * n
    radiance = cubes.reshape(p, t, 3).transpose(1, 0, 2).reshape(t, 3 * p)  # (T, 3P)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    if normals.shape[0] * t <= _MAX_CACHED_ELEMENTS:
        e = _cube_operator(n, _remember(normals)) @ radiance
    else:
        centres = cube_texel_directions(n).reshape(-1, 3).astype(np.float32)
        omega = cube_texel_solid_angles(n).reshape(-1).astype(np.float32)
        n32 = normals.astype(np.float32)
        e = np.zeros((normals.shape[0], 3 * p), dtype=np.float32)
        step = max(1, _MAX_CACHED_ELEMENTS // (8 * normals.shape[0]))
        for start in range(0, t, step):
            k = n32 @ centres[start : start + step].T
            np.maximum(k, 0.0, out=k)
            k *= omega[start : start + step]
            e += k @ radiance[start : start + step]
    return np.ascontiguousarray(e.reshape(-1, p, 3).transpose(1, 0, 2))


def _split_brightest(samples: SphericalSamples, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the ``count`` samples of largest luminance flux (brute force) and a mask of the rest."""
    flux = (np.asarray(samples.radiance, dtype=np.float64) @ LUMINANCE_WEIGHTS) * samples.solid_angles
    rest = np.ones(flux.shape[0], dtype=bool)
    if count <= 0:
        return np.zeros(0, dtype=np.int64), rest
    if count >= flux.shape[0]:
        return np.arange(flux.shape[0]), ~rest
    bright = np.argpartition(-np.abs(flux), count - 1)[:count]
    rest[bright] = False
    return bright, rest


def bin_samples(samples: SphericalSamples, face_size: int, mask: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Flux Φ (6N², C) and first moment m (6N², C, 3) of the samples (those where ``mask`` (S,) bool is True) per
    reference-cube texel containing them (module doc step 2), float64."""
    directions = np.asarray(samples.directions, dtype=np.float64)
    flux = np.asarray(samples.radiance, dtype=np.float64).T * np.asarray(samples.solid_angles)  # (C, S) rows
    if mask is not None:
        flux[:, ~np.asarray(mask)] = 0.0  # the same sums as dropping them (+0 is exact), without copying the rest
    face, row, col = direction_to_cube_texel(directions, face_size)
    texel = (face * face_size + row) * face_size + col
    t = 6 * face_size * face_size
    c = flux.shape[0]
    phi = np.empty((t, c))
    moment = np.empty((t, c, 3))
    weighted = np.empty(flux.shape[1])
    for ch in range(c):
        phi[:, ch] = np.bincount(texel, flux[ch], minlength=t)
        for j in range(3):
            moment[:, ch, j] = np.bincount(texel, np.multiply(flux[ch], directions[:, j], out=weighted), minlength=t)
    return phi, moment


@dataclass(frozen=True)
class BinnedQuadrature:
    """A full-resolution quadrature reduced to what :func:`reference_irradiance_binned` reads (module doc, steps 1
    and 2), whatever the normals: its ``EXACT_BRIGHTEST`` samples of largest luminance flux as they are, and every
    other sample's flux and first moment binned into the texels of a reference cube. A few MB at any image size
    (the samples of an 8192 × 4096 latlong are 1.9 GB), so a worker can hold a batch of them.

    Attributes:
        bright: the brightest samples (≤ ``EXACT_BRIGHTEST``), integrated by brute force.
        phi: (6N², C) flux Φ_t of the other samples per reference-cube texel.
        moment: (6N², C, 3) first moment m_t per texel.
        face_size: N, the reference cube's face size.
    """

    bright: SphericalSamples
    phi: np.ndarray
    moment: np.ndarray
    face_size: int

    def flux(self) -> np.ndarray:
        """∫ L dω per channel (C,) of the whole quadrature."""
        return self.bright.flux() + self.phi.sum(axis=0)


def binned_quadrature(samples: SphericalSamples, face_size: int = REFERENCE_FACE_SIZE,
                      exact: int = EXACT_BRIGHTEST) -> BinnedQuadrature:
    """``samples`` reduced to a :class:`BinnedQuadrature` (module doc, steps 1 and 2)."""
    index, rest = _split_brightest(samples, exact)
    bright = SphericalSamples(samples.directions[index], samples.solid_angles[index], samples.radiance[index])
    phi, moment = bin_samples(samples, face_size, rest)
    return BinnedQuadrature(bright, phi, moment, face_size)


def binned_quadrature_of_bands(bands: Iterable[SphericalSamples], luminance_flux: np.ndarray,
                               face_size: int = REFERENCE_FACE_SIZE, exact: int = EXACT_BRIGHTEST) -> BinnedQuadrature:
    """:func:`binned_quadrature` of a quadrature given as consecutive ``bands`` of its samples (never all at once),
    with ``luminance_flux`` (S,) = (L_s · luminance weights) Ω_s of all S samples, which picks the brightest as
    :func:`_split_brightest` does. The bins are summed band by band (the same sums in another order)."""
    luminance_flux = np.asarray(luminance_flux, dtype=np.float64)
    total = luminance_flux.shape[0]
    rest = np.ones(total, dtype=bool)
    if exact >= total:
        chosen = np.arange(total)
    elif exact <= 0:
        chosen = np.zeros(0, dtype=np.int64)
    else:
        chosen = np.argpartition(-np.abs(luminance_flux), exact - 1)[:exact]
    rest[chosen] = False
    chosen.sort()  # the bright samples are met band by band, in index order
    t = 6 * face_size * face_size
    phi, moment, start = None, None, 0
    parts: list[SphericalSamples] = []
    for band in bands:
        end = start + band.count
        mask = rest[start:end]
        picked = np.flatnonzero(~mask)
        parts.append(SphericalSamples(band.directions[picked], band.solid_angles[picked], band.radiance[picked]))
        band_phi, band_moment = bin_samples(band, face_size, mask)
        phi = band_phi if phi is None else phi + band_phi
        moment = band_moment if moment is None else moment + band_moment
        start = end
    if start != total or not parts:
        raise ValueError(f"the bands hold {start} samples, the luminance flux {total}")
    bright = SphericalSamples(np.concatenate([q.directions for q in parts]),
                              np.concatenate([q.solid_angles for q in parts]),
                              np.concatenate([q.radiance for q in parts]))
    return BinnedQuadrature(bright, phi, moment, face_size)


def reference_irradiance_binned(samples: list[SphericalSamples | BinnedQuadrature], normals: np.ndarray,
                                face_size: int = REFERENCE_FACE_SIZE, exact: int = EXACT_BRIGHTEST) -> np.ndarray:
    """Irradiance (P, D, C) float32 of full-resolution quadratures (or their :class:`BinnedQuadrature`, which fix
    their own face size and brightest samples) at unit normals (D, 3): the brightest ``exact`` samples by brute
    force, the rest binned with exact positive/negative texels (module doc, error bound there)."""
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    quadratures = [s if isinstance(s, BinnedQuadrature) else binned_quadrature(s, face_size, exact) for s in samples]
    bright = np.stack([reference_irradiance(q.bright, normals) if q.bright.solid_angles.size
                       else np.zeros((normals.shape[0], q.phi.shape[1])) for q in quadratures])  # (P, D, C)
    if not any(q.phi.any() or q.moment.any() for q in quadratures):  # nothing binned: all by brute force
        return bright.astype(np.float32)
    sizes = {q.face_size for q in quadratures}
    if len(sizes) != 1:
        raise ValueError(f"binned quadratures of different reference face sizes {sorted(sizes)}")
    n = sizes.pop()
    prefix, straddle = _binned_operators(n, _remember(normals))
    p, c = len(quadratures), bright.shape[2]
    phi = np.stack([q.phi for q in quadratures], axis=1).reshape(6 * n * n, -1)  # (T, P·C)
    moment = np.stack([q.moment for q in quadratures], axis=1).reshape(6 * n, n, -1)  # (6N rows, N cols, P·C·3)
    cumulative = np.zeros((6 * n, n + 1, moment.shape[2]))  # prefix sums of each texel row's moments
    np.cumsum(moment, axis=1, out=cumulative[:, 1:])
    linear = (prefix @ cumulative.reshape(6 * n * (n + 1), -1)).reshape(-1, p, c, 3)  # Σ_{t positive} m_t
    e = np.einsum("dpcj,dj->pdc", linear, normals) + (straddle @ phi).reshape(-1, p, c).transpose(1, 0, 2)
    return (e + bright).astype(np.float32)


def binned_error_bound(samples: SphericalSamples, normals: np.ndarray, face_size: int = REFERENCE_FACE_SIZE,
                       exact: int = EXACT_BRIGHTEST) -> np.ndarray:
    """A posteriori bound (D, C) on |E − E^ref| of :func:`reference_irradiance_binned`: δ · Σ_{t straddles n} |Φ_t|
    (module doc)."""
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    straddles = _texel_sides(normals, face_size)[1]
    _, rest = _split_brightest(samples, exact)
    directions = np.asarray(samples.directions, dtype=np.float64)[rest]
    flux = np.abs(np.asarray(samples.radiance, dtype=np.float64)[rest] * np.asarray(samples.solid_angles)[rest, None])
    face, row, col = direction_to_cube_texel(directions, face_size)
    texel = (face * face_size + row) * face_size + col
    phi = np.stack([np.bincount(texel, flux[:, c], minlength=straddles.shape[1]) for c in range(flux.shape[1])], 1)
    return texel_chord(face_size) * (straddles.astype(np.float64) @ phi)
