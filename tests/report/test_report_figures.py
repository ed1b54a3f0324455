"""Every figure of ``bakery report`` recomputed independently of ``bakery/report``: from the store file with h5py and
the layouts of ``schemas/store-v1.md`` / ``schemas/store-reflection.md`` (memory), and from closed forms or this
file's own quadratures of environments it writes itself (quality). Nothing here compares the report with numbers the
report code produced; bakery is used to bake, to read the store (``bakery.open_store``: the engine-side
reconstruction the report measures) and for the (v, n) rows of the per-α curves (geometry only; their documented
properties are checked).

Environments (equirect, written with this file's own pixel directions, ``equirect_orientation`` convention):
  * polynomial sky L(ω) = (a + b t + c t²)·rgb, t = d·ω: E(n) = π(a + c/3) + (2π/3) b (d·n) + (π c/6) P2(d·n)
    (Funk–Hecke: π, 2π/3, π/4 for bands 0–2; t² = 1/3 + (2/3) P2(t)), so linear SH misses exactly the P2 term and
    its irradiance π(a + c/3) + (2π/3) b (d·n) is negative exactly where d·n < −3(a + c/3)/(2b);
  * constant sky L = c: E0 = c·(A + B), E1 = c·B (the GGX albedo split, schemas/store-reflection.md "dfg");
  * black sky: every relative figure not measurable.
"""

import json
import re
import shutil
from html import unescape
from pathlib import Path

import h5py
import numpy as np
import pytest

import bakery
from bakery.environment.io import write_exr
from bakery.probe import Probe
from bakery.report import build_report, write_report
from harness import bake_cubes, bake_image

# ---------------------------------------------------------------------------------------------- independent maths
A_L = np.array([np.pi] + [2 * np.pi / 3] * 3 + [np.pi / 4] * 5)  # clamped-cosine factors per SH index k ≤ 8


def equirect_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre directions (h, w, 3) and exact solid angles (h, w): row 0 = +Y, column 0 = longitude +π,
    longitude = atan2(x, z), centre = +Z (schemas/store-v1.md, equirect_orientation)."""
    theta = np.pi * (np.arange(h) + 0.5) / h
    lon = np.pi - 2 * np.pi * (np.arange(w) + 0.5) / w
    t, p = np.meshgrid(theta, lon, indexing="ij")
    directions = np.stack([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)], axis=-1)
    edges = np.pi * np.arange(h + 1) / h
    omega = (2 * np.pi / w) * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    return directions, np.broadcast_to(omega[:, None], (h, w))


def equirect_lookup(pixels: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Radiance of the pixel containing each direction (the capture: texels constant over their footprint)."""
    h, w = pixels.shape[:2]
    d = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    i = np.clip((np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi * h).astype(int), 0, h - 1)
    j = np.floor((np.pi - np.arctan2(d[..., 0], d[..., 2])) / (2 * np.pi) * w).astype(int) % w
    return pixels[i, j].astype(np.float64)


def fibonacci(count: int) -> np.ndarray:
    """The quality directions of schemas/store-v1.md: z_k = 1 − (2k + 1)/N, φ_k = k·π(3 − √5)."""
    k = np.arange(count, dtype=np.float64)
    z = 1 - (2 * k + 1) / count
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(k * np.pi * (3 - np.sqrt(5))), r * np.sin(k * np.pi * (3 - np.sqrt(5))), z], -1)


def sh9(d: np.ndarray) -> np.ndarray:
    """Real SH bands 0–2 of schemas/store-v1.md ("SH basis, exactly"), index k = l(l+1) + m."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    c1, c2 = np.sqrt(3 / (4 * np.pi)), np.sqrt(15 / (4 * np.pi))
    return np.stack([np.full_like(x, 0.5 / np.sqrt(np.pi)), -c1 * y, c1 * z, -c1 * x, c2 * x * y, -c2 * y * z,
                     np.sqrt(5 / (16 * np.pi)) * (3 * z * z - 1), -c2 * x * z,
                     np.sqrt(15 / (16 * np.pi)) * (x * x - y * y)], axis=-1)


def sh_irradiance(coefficients: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """E(n) = Σ_k A_l f_k Y_k(n) of radiance SH (P, K, 3) → (P, N, 3)."""
    k = coefficients.shape[-2]
    return np.einsum("nk,pkc->pnc", sh9(normals)[:, :k] * A_L[:k], coefficients.astype(np.float64))


def cube_grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Texel-centre directions (6, N, N, 3) and exact solid angles (6, N, N) of a cube map (schemas/store-v1.md
    cube_face_order / cube_face_orientation: s = (j+½)/N, t = (i+½)/N, u = 2s−1, v = 2t−1)."""
    c = 2 * (np.arange(size) + 0.5) / size - 1
    v, u = np.meshgrid(c, c, indexing="ij")
    one = np.ones_like(u)
    faces = [(one, -v, -u), (-one, -v, u), (u, one, v), (u, -one, -v), (u, -v, one), (-u, -v, -one)]
    directions = np.stack([np.stack(f, axis=-1) for f in faces])
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    e = 2 * np.arange(size + 1) / size - 1
    corner = np.arctan2(e[:, None] * e[None, :], np.sqrt(e[:, None] ** 2 + e[None, :] ** 2 + 1))
    omega = corner[1:, 1:] - corner[:-1, 1:] - corner[1:, :-1] + corner[:-1, :-1]
    return directions, np.broadcast_to(omega, (6, size, size))


def relative_rmse(values: np.ndarray, reference: np.ndarray) -> float:
    return float(np.sqrt(np.sum((values - reference) ** 2)) / np.sqrt(np.sum(reference**2)))


def decode_sh3_quantized(packed: np.ndarray, sqrt_companding: bool) -> np.ndarray:
    """schemas/store-v1.md "Quantized layouts": R11G11B10F DC, then SNORM8 ratios of f0 for k = 1..8."""
    packed = np.asarray(packed, dtype=np.uint8)
    word = packed[:, :4].copy().view("<u4")[:, 0].astype(np.uint32)
    r, g, b = word & 0x7FF, (word >> 11) & 0x7FF, (word >> 22) & 0x3FF
    f0 = np.stack([(r << 4), (g << 4), (b << 5)], axis=-1).astype(np.uint16).view(np.float16).astype(np.float64)
    s = np.maximum(packed[:, 4:].view(np.int8).astype(np.float64) / 127.0, -1.0).reshape(-1, 8, 3)
    t = np.sign(s) * s * s if sqrt_companding else s
    hi = np.array([np.sqrt(3)] * 3 + [np.sqrt(15) / 2] * 2 + [np.sqrt(5)] + [np.sqrt(15) / 2] * 2)
    lo = np.array([np.sqrt(3)] * 3 + [np.sqrt(15) / 2] * 2 + [np.sqrt(5) / 2] + [np.sqrt(15) / 2] * 2)
    ratio = np.where(t >= 0, t * hi[None, :, None], t * lo[None, :, None])
    return np.concatenate([f0[:, None, :], ratio * f0[:, None, :]], axis=1)


def ggx_lambda(c: np.ndarray, alpha: float) -> np.ndarray:
    c = np.clip(c, 1e-12, 1.0)
    return 0.5 * (np.sqrt(1 + alpha * alpha * (1 - c * c) / (c * c)) - 1)


def ggx_reflection(lookup, v: np.ndarray, n: np.ndarray, alpha: float, nu: int = 160, nphi: int = 80):
    """(E0, E1) (M, 3) of ∫ L f_DV ⟨n,l⟩ dl (and × (1 − v·h)⁵): GGX half-vector (NDF) sampling on a midpoint
    product grid, tan²θ_h = α² u/(1 − u), weight f_DV⟨n,l⟩/pdf(l) = G2 (v·h)/((n·v)(n·h)), height-correlated
    G2 = 1/(1 + Λ(v) + Λ(l)); α = 0: the mirror L(r)."""
    if alpha == 0:
        radiance = lookup(2 * np.sum(n * v, 1, keepdims=True) * n - v)
        nv = np.clip(np.sum(n * v, 1), 0, 1)[:, None]
        return radiance, radiance * (1 - nv) ** 5
    u = np.repeat((np.arange(nu) + 0.5) / nu, nphi)
    phi = np.tile(2 * np.pi * (np.arange(nphi) + 0.5) / nphi, nu)
    cos_h = 1 / np.sqrt(1 + alpha * alpha * u / (1 - u))
    sin_h = np.sqrt(1 - cos_h**2)
    e0, e1 = np.zeros((len(v), 3)), np.zeros((len(v), 3))
    for m in range(len(v)):
        t = np.cross(n[m], [1.0, 0, 0] if abs(n[m][0]) < 0.9 else [0, 1.0, 0])
        t /= np.linalg.norm(t)
        b = np.cross(n[m], t)
        h = sin_h[:, None] * (np.cos(phi)[:, None] * t + np.sin(phi)[:, None] * b) + cos_h[:, None] * n[m]
        vh = h @ v[m]
        light = 2 * vh[:, None] * h - v[m]
        nl, nv = light @ n[m], float(v[m] @ n[m])
        g2 = 1 / (1 + ggx_lambda(nv, alpha) + ggx_lambda(nl, alpha))
        w = np.where((nl > 0) & (vh > 0), g2 * vh / (nv * cos_h), 0.0)
        radiance = lookup(light)
        e0[m] = np.mean(w[:, None] * radiance, axis=0)
        e1[m] = np.mean((w * (1 - vh) ** 5)[:, None] * radiance, axis=0)
    return e0, e1


# ---------------------------------------------------------------------------------------------- environments
D = np.array([0.3, 0.8, -0.52]) / np.linalg.norm([0.3, 0.8, -0.52])
POLY = (1.4, 4.0, 3.0)  # a, b, c: L ≥ 0 (a ≥ b²/4c), and 3a + c < 2b so that linear SH rings negative
RGB = np.array([1.0, 0.8, 0.6])


def polynomial_sky(h: int, w: int) -> np.ndarray:
    a, b, c = POLY
    t = equirect_grid(h, w)[0] @ D
    return ((a + b * t + c * t * t)[..., None] * RGB).astype(np.float32)


def polynomial_irradiance(normals: np.ndarray) -> np.ndarray:
    a, b, c = POLY
    t = normals @ D
    return ((np.pi * (a + c / 3) + 2 * np.pi / 3 * b * t + np.pi * c / 6 * 0.5 * (3 * t * t - 1))[:, None] * RGB)


SMALL = {"splitsum": {"face_size": 8, "min_face_size": 4}, "shexp": {"fit_face_size": 8},
         "shexp_hybrid": {"face_size": 8, "fit_face_size": 8, "alpha_min": 0.3}}
REFLECTION = ("splitsum", "shexp", "shexp_hybrid")


@pytest.fixture(scope="module")
def poly(tmp_path_factory):
    """One probe of the polynomial sky (32 × 64) with irradiance and reflection encodings, and its report."""
    d = tmp_path_factory.mktemp("figures_poly")
    pixels = polynomial_sky(32, 64)
    write_exr(d / "poly.exr", pixels, half=False)
    bake_image(d / "poly.exr", d / "poly.h5", face_size=8, encodings=("sh2", "sh3", "zh3", "sh3_quantized",
                                                                       *REFLECTION), encoding_settings=SMALL)
    result = write_report(d / "poly.h5", d / "rep", previews=False)
    return {"dir": d, "store": d / "poly.h5", "pixels": pixels, "data": json.loads(result["json"].read_text()),
            "html": result["html"].read_text()}


@pytest.fixture(scope="module")
def constant(tmp_path_factory):
    """A constant sky on a coarse 16 × 32 image (texels 11° wide: far wider than the GGX lobe at α = 0.02)."""
    d = tmp_path_factory.mktemp("figures_constant")
    pixels = np.broadcast_to(np.array([0.5, 1.0, 2.0], np.float32), (16, 32, 3)).copy()
    write_exr(d / "c.exr", pixels, half=False)
    bake_image(d / "c.exr", d / "c.h5", face_size=8, encodings=("sh2", *REFLECTION), encoding_settings=SMALL)
    data, html = build_report(d / "c.h5", previews=False)
    return {"store": d / "c.h5", "pixels": pixels, "data": data, "html": html}


def curve_geometry(data):
    """The report's (v, n) rows (geometry only), checked against their documented properties."""
    from bakery.report.quality import curve_rows

    v, n = curve_rows(data["reflection_alpha_curves"]["rows_per_alpha"])
    assert v.shape == n.shape == (128, 3)
    assert np.allclose(np.linalg.norm(v, axis=1), 1) and np.allclose(np.linalg.norm(n, axis=1), 1)
    assert np.all(np.sum(v * n, axis=1) >= 0.05 - 1e-9)
    assert np.allclose(n, fibonacci(128))
    return v, n


def mine_vs_store(store, name, v, n, alpha, f0, e0, e1):
    """(relative MSE, bias) of the store's reconstruction against this file's reference (E = F0 E0 + (1 − F0) E1)."""
    reference = f0 * e0 + (1 - f0) * e1
    estimate = store.evaluate_reflection(name, v, n, np.full(len(v), alpha), np.full(len(v), f0))[0]
    return (float(np.sum((estimate - reference) ** 2) / np.sum(reference**2)),
            float(np.sum(estimate) / np.sum(reference) - 1))


# ---------------------------------------------------------------------------------------------- memory
def h5_layout(path: Path) -> dict[str, dict]:
    """Per encoding: per-probe row bytes of every field (shape[1:] × dtype size, probe_index excluded), probe count,
    level shapes and shared tables, from the file itself."""
    out = {}
    with h5py.File(path, "r") as f:
        for name, group in f["encodings"].items():
            fields = {k: int(np.prod(ds.shape[1:], dtype=np.int64)) * ds.dtype.itemsize
                      for k, ds in group.items() if isinstance(ds, h5py.Dataset) and k != "probe_index"}
            shared = {k: (ds.dtype.itemsize * ds.size, ds[()].tobytes()) for k, ds in group.get("shared", {}).items()}
            out[name] = {"fields": fields, "probes": int(group["probe_index"].shape[0]),
                         "attr": int(group.attrs["bytes_per_probe"]), "shared": shared,
                         "levels": [group[f"level{i}"].shape[2] for i in range(16) if f"level{i}" in group],
                         "first_level": group["first_level"][()].reshape(-1) if "first_level" in group else None}
    return out


def test_memory_figures_from_the_file_and_the_schema_layouts(poly):
    data, layout = poly["data"]["memory"], h5_layout(poly["store"])
    # schema sizes: sh2 48, sh3 108, zh3 60, sh3_quantized 28, shexp 404 (store-v1.md, store-reflection.md)
    schema = {"sh2": 48, "sh3": 108, "zh3": 60, "sh3_quantized": 28, "shexp": 404,
              "splitsum": sum(6 * s * s * 3 * 2 for s in [8, 4, 4, 4, 4, 4])}
    per_kind = {"irradiance": 0, "reflection": 0}
    for name, entry in data["encodings"].items():
        row = sum(layout[name]["fields"].values())
        assert entry["bytes_per_probe"] == row == layout[name]["attr"], name
        assert entry["probes"] == layout[name]["probes"] == 1 and entry["total_bytes"] == row
        if name in schema:
            assert row == schema[name], name
        per_kind[entry["kind"]] += row
        assert entry["shared_bytes"] == sum(b for b, _ in layout[name]["shared"].values())
    assert data["total_bytes_per_kind"] == per_kind and data["total_bytes"] == sum(per_kind.values())
    # shared tables: the DFG (64 × 64 × 2 float32 = 32 768 B) of every reflection encoding, identical: counted once
    contents = {content for e in layout.values() for _, content in e["shared"].values()}
    once = sum(len(c) for c in contents)
    assert len(contents) == 1 and once == 64 * 64 * 2 * 4
    assert data["shared_bytes"] == once and data["total_bytes_with_shared"] == sum(per_kind.values()) + once
    assert sorted(t for s in data["shared_tables"] for t in s["tables"]) == sorted(
        f"{n}/shared/{k}" for n, e in layout.items() for k in e["shared"])


def test_split_sum_comparisons_are_the_stored_chain_in_gpu_formats(poly):
    data, layout = poly["data"]["memory"], h5_layout(poly["store"])
    cube = layout["splitsum"]["levels"]  # the stored chain: N_i = max(N >> i, min(m, N)) = 8, 4, 4, 4, 4, 4
    assert cube == [8, 4, 4, 4, 4, 4]
    texels = sum(6 * s * s for s in cube)
    octahedral = [16, 8, 4, 4, 4, 4]  # M_i = max(2N >> i, min(m, 2N)), m = 4 (memory.py, docs/report.md)
    expected = {"cube_rgba16f": 8 * texels, "cube_bc6h": sum(6 * 16 * (-(-s // 4)) ** 2 for s in cube),
                "octahedral_rgba16f": 8 * sum(s * s for s in octahedral),
                "octahedral_bc6h": sum(16 * (-(-s // 4)) ** 2 for s in octahedral)}
    # RGBA16F (8 B/texel) of the stored chain is 8/6 of its stored RGB float16 bytes
    assert expected["cube_rgba16f"] * 6 == layout["splitsum"]["attr"] * 8
    assert data["split_sum_chain"]["cube_sizes"] == cube and data["split_sum_chain"]["octahedral_sizes"] == octahedral
    for key, value in expected.items():
        assert data["comparisons"][f"split_sum_{key}"]["bytes_per_probe"] == value
        assert data["comparisons"][f"split_sum_{key}"]["total_bytes_reflection_probes"] == value  # 1 probe
        for name, entry in data["encodings"].items():
            assert data["ratios"][name][f"vs_split_sum_{key}"] == pytest.approx(entry["bytes_per_probe"] / value)
    assert data["comparisons"]["sh3_float"]["bytes_per_probe"] == 9 * 3 * 4
    for name, entry in data["encodings"].items():
        assert data["ratios"][name]["vs_sh3_float"] == pytest.approx(entry["bytes_per_probe"] / 108)


def test_hybrid_upload_leaves_out_the_levels_below_first_level(poly):
    """alpha_min = 0.3 ≥ α_1 = 0.273 (face 8): k0 = 1, so level 0 (the kept capture) is stored but not uploaded."""
    layout = h5_layout(poly["store"])["shexp_hybrid"]
    k0 = int(layout["first_level"][0])
    assert 0 < k0 < len(layout["levels"])
    levels = {f"level{k}": 6 * s * s * 3 * 2 for k, s in enumerate(layout["levels"])}
    assert all(layout["fields"][k] == b for k, b in levels.items())
    upload = sum(b for k, b in layout["fields"].items() if not k.startswith("level")) + sum(
        levels[f"level{k}"] for k in range(k0, len(levels)))
    entry = poly["data"]["memory"]["encodings"]["shexp_hybrid"]
    assert entry["upload_bytes_per_probe"] == {"mean": upload, "min": upload, "max": upload}
    assert entry["upload_total_bytes"] == upload < entry["bytes_per_probe"]


def test_inspect_and_the_report_agree_on_sizes(poly):
    from click.testing import CliRunner

    from bakery.cli import main

    shown = json.loads(CliRunner().invoke(main, ["inspect", str(poly["store"]), "--json"]).stdout)
    for name, entry in poly["data"]["memory"]["encodings"].items():
        assert shown["encodings"][name]["bytes_per_probe"] == entry["bytes_per_probe"]
        assert shown["encodings"][name]["probes"] == entry["probes"]


# ---------------------------------------------------------------------------------------------- irradiance
def test_irradiance_errors_against_the_closed_form_and_a_brute_force_of_the_image(poly):
    store = bakery.open_store(poly["store"])
    data = poly["data"]
    normals = fibonacci(1024)
    assert data["quality_directions"] == 1024
    # brute force of the image itself (this file's pixel directions and solid angles), float64
    directions, omega = equirect_grid(32, 64)
    radiance = poly["pixels"].reshape(-1, 3).astype(np.float64) * omega.reshape(-1, 1)
    exact = np.maximum(normals @ directions.reshape(-1, 3).T, 0) @ radiance  # (N, 3)
    closed = polynomial_irradiance(normals)
    assert relative_rmse(exact, closed) < 2e-3  # the image is the sky up to its pixels
    for name in ("sh2", "sh3"):
        coefficients = store.fields(name)["radiance_sh"]
        mine = sh_irradiance(coefficients, normals)[0]
        np.testing.assert_allclose(store.evaluate_irradiance(name, normals)[0], mine, rtol=1e-5, atol=1e-5)
        reported = data["errors"][name]
        assert reported["summary"]["count"] == 1 and reported["metric"].startswith("relative RMSE")
        assert reported["per_probe"][0] == pytest.approx(relative_rmse(mine, exact), rel=1e-3)
    # linear SH misses exactly the P2 term: its error is the closed form's ‖(πc/6) P2‖ / ‖E‖
    a, b, c = POLY
    t = normals @ D
    sh2_closed = relative_rmse(((np.pi * (a + c / 3) + 2 * np.pi / 3 * b * t)[:, None] * RGB), closed)
    assert data["errors"]["sh2"]["per_probe"][0] == pytest.approx(sh2_closed, rel=0.02)
    assert data["errors"]["sh3"]["per_probe"][0] < 0.01 and data["errors"]["zh3"]["per_probe"][0] < 0.01


def test_negative_share_and_quantization_error_recomputed_from_the_stored_bytes(poly):
    store = bakery.open_store(poly["store"])
    data = poly["data"]
    normals = fibonacci(1024)
    sh2 = sh_irradiance(store.fields("sh2")["radiance_sh"], normals)[0]
    share = float(np.mean(np.any(sh2 < 0, axis=-1)))
    assert data["negative_share"]["sh2"]["per_probe"][0] == pytest.approx(share, abs=1.5 / 1024)
    # closed form: negative where d·n < −3(a + c/3)/(2b) = −0.9, 5 % of uniform directions
    a, b, c = POLY
    assert share == pytest.approx((1 - 3 * (a + c / 3) / (2 * b)) / 2, abs=0.01)
    assert data["negative_share"]["sh3"]["per_probe"][0] == 0.0 == float(np.mean(np.any(
        sh_irradiance(store.fields("sh3")["radiance_sh"], normals)[0] < 0, axis=-1)))
    # sh3_quantized decoded from its 28 bytes (store-v1.md) against its float source sh3
    settings = store.encodings["sh3_quantized"].settings
    decoded = decode_sh3_quantized(store.fields("sh3_quantized")["packed"], settings["sqrt_companding"])
    quantized = sh_irradiance(decoded, normals)[0]
    np.testing.assert_allclose(store.evaluate_irradiance("sh3_quantized", normals)[0], quantized, rtol=1e-4,
                               atol=1e-4)
    source = sh_irradiance(store.fields("sh3")["radiance_sh"], normals)[0]
    q = data["quantization"]["sh3_quantized"]
    assert q["source"] == "sh3" and q["per_probe"][0] == pytest.approx(relative_rmse(quantized, source), rel=1e-3)
    assert 0 < q["per_probe"][0] < 0.05


def test_figures_use_the_quality_directions_the_store_was_measured_at(poly, tmp_path):
    """An irradiance-only store measured at 2048 directions (the reference recipe's): the page and the figures say
    2048 (they said 1024 whatever the store), and equal this file's recomputation at 2048 Fibonacci normals."""
    bake_image(poly["dir"] / "poly.exr", tmp_path / "q.h5", face_size=4, encodings=("sh2",), quality_directions=2048)
    data, html = build_report(tmp_path / "q.h5", previews=False)
    store = bakery.open_store(tmp_path / "q.h5")
    normals = fibonacci(2048)
    sh2 = sh_irradiance(store.fields("sh2")["radiance_sh"], normals)[0]
    directions, omega = equirect_grid(32, 64)
    exact = np.maximum(normals @ directions.reshape(-1, 3).T, 0) @ (
        poly["pixels"].reshape(-1, 3).astype(np.float64) * omega.reshape(-1, 1))
    assert data["quality_directions"] == 2048
    assert data["errors"]["sh2"]["per_probe"][0] == pytest.approx(relative_rmse(sh2, exact), rel=1e-3)
    assert data["negative_share"]["sh2"]["per_probe"][0] == pytest.approx(
        float(np.mean(np.any(sh2 < 0, axis=-1))), abs=1.5 / 2048)
    assert "over 2048 Fibonacci normals" in html and "1024" not in data["errors"]["sh2"]["metric"]
    assert data["reflection_alpha_curves"] == {} and "No reflection encodings in this store" in html


# ---------------------------------------------------------------------------------------------- reflection
def test_per_alpha_reflection_error_of_a_constant_sky_is_measured_against_the_exact_albedo(constant):
    """L = c: E_ref = c·(F0·A + B). The texel-centre quadrature of a 16 × 32 image gave a white furnace between
    0.02 and 22 at α = 0.02 (relative MSE ~1 for a perfect encoding); the report must measure against the exact
    albedo at every α of its grid."""
    data = constant["data"]
    store = bakery.open_store(constant["store"])
    curves = data["reflection_alpha_curves"]
    v, n = curve_geometry(data)
    c = constant["pixels"][0, 0].astype(np.float64)
    lookup = lambda d: np.broadcast_to(c, (*d.shape[:-1], 3))  # noqa: E731
    for j, alpha in enumerate(curves["alphas"]):
        e0, e1 = ggx_reflection(lookup, v, n, alpha)
        if alpha > 0:  # the furnace itself: A + B ≤ 1, A + B → 1 as α → 0 (mirror), B ≥ 0
            albedo = e0[:, 0] / c[0]
            assert np.all(albedo <= 1 + 1e-3) and np.all(e1 >= 0)
        for name in REFLECTION:
            for material, f0 in (("chrome", 1.0), ("glass", 0.04)):
                mse, bias = mine_vs_store(store, name, v, n, alpha, f0, e0, e1)
                reported = curves["encodings"][name][material][0][j]
                assert reported == pytest.approx(mse, rel=0.05, abs=2e-4), (name, material, alpha)
                assert curves["bias"][name][material][0][j] == pytest.approx(bias, rel=0.05, abs=2e-3)
    # the headline per encoding: the plain mean over the α grid and both materials, of these cells
    for name in REFLECTION:
        cells = [curves["encodings"][name][m][0] for m in ("chrome", "glass")]
        assert data["errors"][name]["per_probe"][0] == pytest.approx(float(np.mean(cells)), rel=1e-9)
        assert "mean over the 12 α of the grid" in data["errors"][name]["metric"]


def test_per_alpha_reflection_error_against_an_independent_reference_of_the_capture(poly):
    """Polynomial sky: this file's NDF-sampled integral of the image's texels (pixel lookup) at α from the mirror to
    1, for every stored reflection encoding and both materials."""
    store = bakery.open_store(poly["store"])
    curves = poly["data"]["reflection_alpha_curves"]
    v, n = curve_geometry(poly["data"])
    lookup = lambda d: equirect_lookup(poly["pixels"], d)  # noqa: E731
    for alpha in (0.0, 0.02, 0.0625, 0.25, 1.0):
        j = curves["alphas"].index(alpha)
        e0, e1 = ggx_reflection(lookup, v, n, alpha)
        for name in REFLECTION:
            for material, f0 in (("chrome", 1.0), ("glass", 0.04)):
                mse, bias = mine_vs_store(store, name, v, n, alpha, f0, e0, e1)
                assert curves["encodings"][name][material][0][j] == pytest.approx(mse, rel=0.05, abs=2e-4), (
                    name, material, alpha)
                assert curves["bias"][name][material][0][j] == pytest.approx(bias, rel=0.05, abs=2e-3)


# ---------------------------------------------------------------------------------------------- not measurable
def test_a_black_capture_has_no_relative_error_anywhere(tmp_path):
    """schemas/store-v1.md: against a black reference the store writes reference_error 0 (encoding black too) or
    +inf; a relative error of a black probe is not measurable, never "0"."""
    write_exr(tmp_path / "black.exr", np.zeros((16, 32, 3), np.float32), half=False)
    with pytest.warns(UserWarning, match="black"):
        bake_image(tmp_path / "black.exr", tmp_path / "b.h5", face_size=8, encodings=("sh2", "zh3", "shexp"),
                   encoding_settings={"shexp": {"fit_face_size": 8}})
    with h5py.File(tmp_path / "b.h5", "r") as f:
        assert float(f["diagnostics/reference_error/sh2"][0]) == 0.0  # what the store says: 0 / 0 written as 0
    result = write_report(tmp_path / "b.h5", tmp_path / "rep", previews=False)
    data = json.loads(result["json"].read_text())
    for name in ("sh2", "zh3", "shexp"):
        assert data["errors"][name]["per_probe"] == [None] and data["errors"][name]["summary"] == {"count": 0}
        assert data["errors"][name]["probes"] == 1 and data["worst_probes"][name] == []
    rows = re.findall(r"<tr><td[^>]*>(sh2|zh3|shexp)</td><td[^>]*>relative[^<]*</td>((?:<td[^>]*>[^<]*</td>)*)</tr>",
                      result["html"].read_text())
    assert len(rows) == 3
    for _, cells in rows:  # bytes/probe, probes, measured = 0, then mean, median, p90, max: "not measured"
        values = [unescape(c) for c in re.findall(r"<td[^>]*>([^<]*)</td>", cells)]
        assert values[1:3] == ["1", "0"] and values[3:] == ["not measured"] * 4


def test_a_store_without_captures_names_no_worst_probe(tmp_path):
    """Cube captures (scene-like: no capture kept), probes of one kind each: reflection errors are not measured, so
    the preview probe is not called "worst" or "median"; irradiance is ranked by the stored diagnostics."""
    rng = np.random.default_rng(5)
    cubes = rng.uniform(0.05, 1.0, size=(4, 6, 8, 8, 3)).astype(np.float32)
    cubes[1, 0, 2, 2] = 400.0
    probes = [Probe(f"/W/p{i}", kinds=("irradiance",) if i < 2 else ("reflection",), position=(i, 0.0, 0.0))
              for i in range(4)]
    bake_cubes(tmp_path / "s.h5", probes, cubes, encodings=("sh2", "shexp"),
               encoding_settings={"shexp": {"fit_face_size": 8}})
    data, html = build_report(tmp_path / "s.h5", sphere_size=16)
    assert data["reference_available"] is False and "shexp" not in data["errors"]
    assert data["previews"]["reflection"] == {"first (no error measured)": {"probe": "/W/p2"}}
    # irradiance: the reference of a cube bake is its capture (store-v1.md "Quality directions"): brute force of
    # each cube's texels against linear SH evaluated from the stored coefficients
    store = bakery.open_store(tmp_path / "s.h5")
    directions, omega = cube_grid(8)
    normals = fibonacci(1024)
    rows = store.fields("sh2")["probe_index"].tolist()
    assert rows == [0, 1]
    mine = []
    for r, i in enumerate(rows):
        exact = np.maximum(normals @ directions.reshape(-1, 3).T, 0) @ (
            cubes[i].reshape(-1, 3).astype(np.float64) * omega.reshape(-1, 1))
        mine.append(relative_rmse(sh_irradiance(store.fields("sh2")["radiance_sh"][r:r + 1], normals)[0], exact))
    assert data["errors"]["sh2"]["per_probe"] == pytest.approx(mine, rel=1e-3)
    worst = f"/W/p{rows[int(np.argmax(mine))]}"
    assert worst == "/W/p1" and data["previews"]["irradiance"]["worst"]["probe"] == worst
    # two probes: the median role is the lower middle, the other probe
    assert data["previews"]["irradiance"]["median"]["probe"] == f"/W/p{rows[int(np.argmin(mine))]}"
    assert data["worst_probes"]["sh2"][0]["probe"] == worst
    assert data["memory"]["probes_of_kind"] == {"irradiance": 2, "reflection": 2}
    assert data["memory"]["comparisons"]["sh3_float"]["total_bytes_irradiance_probes"] == 2 * 108
    assert "Per-α reflection curves need the probe capture" in html


# ---------------------------------------------------------------------------------------------- the capture used
def test_the_reference_is_the_image_the_store_was_baked_from(poly, tmp_path, monkeypatch):
    """A relative ``source`` is found beside a moved store; a different image at that path is refused (its flux is
    not the store's input/flux_source) instead of silently becoming the reference."""
    moved = tmp_path / "elsewhere"
    moved.mkdir()
    monkeypatch.chdir(poly["dir"])
    bake_image(Path("poly.exr"), moved / "rel.h5", face_size=4, encodings=("sh2",), reference_errors=False)
    with h5py.File(moved / "rel.h5", "r") as f:
        assert f.attrs["source"] == "poly.exr"
    shutil.copy(poly["dir"] / "poly.exr", moved / "poly.exr")
    monkeypatch.chdir(tmp_path)  # no poly.exr here: the one beside the store is used
    data, _ = build_report(moved / "rel.h5", previews=False)
    assert data["reference_available"] is True and data["errors"]["sh2"]["summary"]["count"] == 1
    assert data["reference"] == {"path": str(moved / "poly.exr"), "flux_matches_store": True}
    write_exr(moved / "poly.exr", 1.01 * polynomial_sky(32, 64), half=False)  # another sky, same name
    with pytest.warns(UserWarning, match="not the image"):
        data, _ = build_report(moved / "rel.h5", previews=False)
    assert data["reference_available"] is False and data["errors"] == {} and data["reference"] is None
    # asked for explicitly: measured against it, and the page says it is not the baked image
    with pytest.warns(UserWarning, match="as asked"):
        data, html = build_report(moved / "rel.h5", environment=moved / "poly.exr", previews=False)
    assert data["reference"]["flux_matches_store"] is False and "not the image this store was baked from" in html


# ---------------------------------------------------------------------------------------------- page = JSON
def _cells(html: str, first_header: str) -> list[list[str]]:
    """Body cells of every table whose first column header is ``first_header``."""
    tables = re.findall(rf"<table><thead><tr><th[^>]*>{re.escape(first_header)}</th>.*?</table>", html, re.S)
    return [[unescape(c) for c in re.findall(r"<td[^>]*>([^<]*)</td>", row)]
            for table in tables for row in re.findall(r"<tr>(<td.*?)</tr>", table)]


def _g(value) -> str:
    return "not measured" if value is None else (f"{value:,}" if isinstance(value, int) else f"{value:.4g}")


def test_the_page_shows_the_json_numbers(poly):
    data, html = poly["data"], poly["html"]
    memory = {row[0]: row for row in _cells(html, "encoding") if row[1] in ("irradiance", "reflection")}
    for name, entry in data["memory"]["encodings"].items():
        assert memory[name][2] == _g(entry["bytes_per_probe"]) and memory[name][5] == _g(entry["total_bytes"])
    quality = {row[0]: row for row in _cells(html, "encoding") if row[1].startswith("relative")}
    for name, entry in data["errors"].items():
        s = entry["summary"]
        assert quality[name][3:] == [_g(entry["probes"]), _g(s["count"]), _g(s.get("mean")), _g(s.get("median")),
                                     _g(s.get("p90")), _g(s.get("max"))]
    kinds = {row[0]: row for row in _cells(html, "probe kind")}
    assert kinds["shared tables (once)"][2] == _g(data["memory"]["shared_bytes"])
    assert kinds["all"][2] == _g(data["memory"]["total_bytes_with_shared"])
    assert "over 1024 Fibonacci normals" in html
    alpha = {(row[0], row[1]): row[2:] for row in _cells(html, "encoding") if row[1] in ("chrome", "glass")}
    curves = data["reflection_alpha_curves"]
    for name in REFLECTION:
        for material in ("chrome", "glass"):
            shown = [cell.split(" ")[0] for cell in alpha[(name, material)]]
            assert shown == [f"{x:.3g}" for x in curves["encodings"][name][material][0]]
