"""A decoder written from ``schemas/store-v1.md`` alone (h5py + numpy, nothing from bakery) reads stores that the
one bake path wrote, and reconstructs every irradiance encoding as the public API does. The spec is also checked
for completeness: every attribute and dataset an image bake writes is named in it.

Nothing below imports bakery's math: the basis, the cosine factors, the luminance axis, Listing 1, R11G11B10F and
SNORM8 decoding and the Fibonacci quality directions are transcribed from the spec."""

import json
import re
from math import pi, sqrt
from pathlib import Path

import h5py
import numpy as np
import pytest

import bakery
from bakery.encodings import ENCODINGS
from bakery.environment.io import write_exr

SPEC = Path(__file__).resolve().parents[2] / "schemas"
SPEC_TEXT = "\n".join(p.read_text() for p in sorted(SPEC.glob("store*.md")))

# ---------------------------------------------------------------------------------------- the spec, transcribed
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # colour convention
A = np.array([pi] + [2 * pi / 3] * 3 + [pi / 4] * 5)  # A_l per index k
SQRT3, SQRT15_2, SQRT5 = sqrt(3), sqrt(15) / 2, sqrt(5)
BOUNDS = [(-SQRT3, SQRT3)] * 3 + [(-SQRT15_2, SQRT15_2)] * 2 + [(-SQRT5 / 2, SQRT5)] + [(-SQRT15_2, SQRT15_2)] * 2
ZONAL_BOUNDS = (-SQRT5 / 2, SQRT5)


def basis(n):
    """"SH basis (bands 0–2), exactly": (N, 3) → (N, 9)."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    c1, c2 = sqrt(3 / (4 * pi)), sqrt(15 / (4 * pi))
    return np.stack([np.full_like(x, 1 / (2 * sqrt(pi))), -c1 * y, c1 * z, -c1 * x, c2 * x * y, -c2 * y * z,
                     sqrt(5 / (16 * pi)) * (3 * z * z - 1), -c2 * x * z, sqrt(15 / (16 * pi)) * (x * x - y * y)], 1)


def luminance_axis(linear):
    """a = normalize(Σ_c w_c v_c), v = (−f1,1, −f1,−1, f1,0); (0, 0, 1) if |·| ≤ 1e−30. linear: (4, 3)."""
    v = np.stack([-linear[3], -linear[1], linear[2]])  # (3 xyz, 3 rgb)
    u = v @ LUMINANCE
    norm = np.linalg.norm(u)
    return np.array([0.0, 0.0, 1.0]) if norm <= 1e-30 else u / norm


def sh_irradiance(sh, n):
    k = sh.shape[0]
    return basis(n)[:, :k] @ (A[:k, None] * sh)


def zh3_irradiance(linear, zonal, n):
    t = n @ luminance_axis(linear)
    return sh_irradiance(linear, n) + (pi / 4) * np.outer(sqrt(5 / (16 * pi)) * (3 * t * t - 1), zonal)


def hallucinated_zonal(linear, curve):
    """zonal_l2 = (c2 p² + c1 p)·f0, p = abs(v_c·a)/f0 (0 if f0 ≤ 0)."""
    c2, c1 = curve
    v = np.stack([-linear[3], -linear[1], linear[2]])
    f0 = linear[0]
    p = np.where(f0 > 0, np.abs(luminance_axis(linear) @ v) / np.where(f0 > 0, f0, 1), 0.0)
    return (c2 * p * p + c1 * p) * f0


def parse_curve(settings):
    curve = settings["curve"]
    if curve == "paper":
        return 0.6, 0.08
    if isinstance(curve, str):
        raise TypeError(f"a stored curve must be 'paper' or [c2, c1], got {curve!r}")
    return float(curve[0]), float(curve[1])


def decode_r11g11b10(word):
    """uint32 → RGB: R bits 0–10, G 11–21, B 22–31; 5-bit exponent (bias 15), 6/6/5 mantissa bits; exponent 31
    refused."""
    out = []
    for shift, mantissa_bits in ((0, 6), (11, 6), (22, 5)):
        field = (int(word) >> shift) & ((1 << (5 + mantissa_bits)) - 1)
        exponent, mantissa = field >> mantissa_bits, field & ((1 << mantissa_bits) - 1)
        if exponent == 31:
            raise ValueError("R11G11B10F exponent 31: corrupt store")
        if exponent == 0:
            out.append(2.0**-14 * mantissa / 2**mantissa_bits)
        else:
            out.append(2.0 ** (exponent - 15) * (1 + mantissa / 2**mantissa_bits))
    return np.array(out)


def decode_ratio(q, bounds, companding):
    s = max(int(q) / 127, -1.0)  # q = −128 decodes as −127
    t = np.sign(s) * s * s if companding else s
    lo, hi = bounds
    return t * hi if t >= 0 else t * abs(lo)


def decode_packed(packed, bounds, companding):
    """(f0 (3,), coefficients (K, 3)) of one quantized row."""
    f0 = decode_r11g11b10(int.from_bytes(bytes(packed[:4]), "little"))
    q = packed[4:].view(np.int8).reshape(-1, 3)
    coefficients = np.array([[decode_ratio(q[k, c], bounds[k], companding) * f0[c] for c in range(3)]
                             for k in range(q.shape[0])])
    return f0, coefficients


def spec_irradiance(kind, fields, settings, row, n):
    """E(n) (N, 3) of row ``row`` of an irradiance encoding group, per the table of the spec."""
    if kind in ("sh2", "sh3"):
        return sh_irradiance(fields["radiance_sh"][row].astype(np.float64), n)
    if kind in ("zh3", "zh3_solved", "zh3_deringed"):
        return zh3_irradiance(fields["radiance_sh"][row].astype(np.float64), fields["zonal_l2"][row].astype(np.float64), n)
    if kind in ("zh3_hallucinated", "zh3_hallucinated_solved"):
        linear = fields["radiance_sh"][row].astype(np.float64)
        scale = int(fields["zonal_scale"][row][0]) / 64 if kind == "zh3_hallucinated_solved" else 1.0
        return zh3_irradiance(linear, scale * hallucinated_zonal(linear, parse_curve(settings)), n)
    if kind == "zh3_quantized":
        f0, c = decode_packed(fields["packed"][row], BOUNDS[:3] + [ZONAL_BOUNDS], settings["sqrt_companding"])
        return zh3_irradiance(np.concatenate([f0[None], c[:3]]), c[3], n)
    if kind == "sh3_quantized":
        f0, c = decode_packed(fields["packed"][row], BOUNDS, settings["sqrt_companding"])
        return sh_irradiance(np.concatenate([f0[None], c]), n)
    raise KeyError(kind)


def fibonacci(count):
    """Quality directions of the spec's `/diagnostics` section."""
    k = np.arange(count)
    z = 1 - (2 * k + 1) / count
    r = np.sqrt(1 - z * z)
    phi = k * pi * (3 - sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def equirect_quadrature(pixels):
    """Directions and exact solid angles of an equirect image's pixel centres (equirect_orientation)."""
    h, w, _ = pixels.shape
    lat = pi * (0.5 - (np.arange(h) + 0.5) / h)
    lon = pi * (1 - 2 * (np.arange(w) + 0.5) / w)
    lat, lon = np.meshgrid(lat, lon, indexing="ij")
    d = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], -1).reshape(-1, 3)
    edges = pi * (0.5 - np.arange(h + 1) / h)
    omega = np.repeat((2 * pi / w) * (np.sin(edges[:-1]) - np.sin(edges[1:])), w)
    return d, omega, pixels.reshape(-1, 3).astype(np.float64)


def read(path):
    """{root attrs, probes, encodings: {name: (attrs, fields)}, diagnostics} by h5py, as the spec lays them out."""
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == "bakery.probe-store"
        assert int(str(f.attrs["format_version"]).split(".")[0]) == 1
        names = [n.decode() if isinstance(n, bytes) else str(n) for n in f["probes/name"][()]]
        encodings = {}
        for name, group in f["encodings"].items():
            attrs = {k: group.attrs[k] for k in group.attrs}
            fields = {k: group[k][()] for k in group if isinstance(group[k], h5py.Dataset)}
            encodings[name] = (attrs, fields)
        diagnostics = {}
        f["diagnostics"].visititems(lambda k, v: diagnostics.__setitem__(k, v[()]) if isinstance(v, h5py.Dataset)
                                    else None)
        return {"attrs": dict(f.attrs), "names": names, "count": int(f["probes"].attrs["count"]),
                "encodings": encodings, "diagnostics": diagnostics}


# ------------------------------------------------------------------------------------------------- the stores
def _environments(folder, count=4):
    """Two sun-and-lamp skies, a plain gradient and (last) a lamp over a ring of lamps on the horizon: an interior
    whose L2 band is negative along the light, so ``zh3_hallucinated_solved`` stores scale 0 (plain SH2) there."""
    rng = np.random.default_rng(17)
    paths = []
    h = 16
    for i in range(count):
        rows = (np.arange(h) + 0.5) / h
        sky = np.broadcast_to((np.array([0.2, 0.3, 0.6]) * (1.5 - rows)[:, None])[:, None, :], (h, 2 * h, 3)).copy()
        if i < 2:
            sky[rng.integers(0, h // 2), rng.integers(0, 2 * h)] = rng.uniform(50, 400, size=3)  # a sun
            sky[rng.integers(h // 2, h), rng.integers(0, 2 * h)] = rng.uniform(5, 40, size=3)  # a lamp below
        elif i == 3:
            sky[0, :] += 20.0  # the lamp overhead (the first row spans the pole)
            sky[h // 2 - 1:h // 2 + 1, :] += np.array([6.0, 5.0, 4.0])  # the ring: most of the power
        paths.append(folder / f"env{i}.exr")
        write_exr(paths[-1], sky.astype(np.float32), half=False)
    return paths


IRRADIANCE = [n for n, e in ENCODINGS.items() if e.kind == "irradiance"]
VARIANTS = {"zh3_hallucinated": {"curve": "fit"}, "zh3_quantized": {"sqrt_companding": False},
            "sh3_quantized": {"sqrt_companding": False}, "zh3_hallucinated_solved": {"curve": [0.5, 0.1]}}


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    folder = tmp_path_factory.mktemp("spec")
    images = _environments(folder)
    default = folder / "default.h5"
    bakery.bake(images, default, encodings=tuple(IRRADIANCE), face_size=8, jobs=1)
    variant = folder / "variant.h5"
    bakery.bake(images, variant, encodings=tuple(IRRADIANCE), face_size=8, jobs=1,
                encoding_settings={k: v for k, v in VARIANTS.items() if k in ENCODINGS})
    return images, default, variant


@pytest.mark.parametrize("which", ["default", "variant"])
def test_spec_decoder_reconstructs_every_irradiance_encoding(stores, which):
    _, default, variant = stores
    path = default if which == "default" else variant
    store = read(path)
    api = bakery.open_store(path)
    n = fibonacci(200)
    assert set(IRRADIANCE) <= set(store["encodings"])
    # zh3_hallucinated_solved is exercised at scale 0 (plain sh2) and at solved scales other than Listing 1's 64
    codes = set(store["encodings"]["zh3_hallucinated_solved"][1]["zonal_scale"].ravel())
    assert 0 in codes and codes - {0, 64}
    for name, (attrs, fields) in store["encodings"].items():
        assert attrs["encoding_type"] == name and attrs["kind"] == "irradiance"
        settings = json.loads(attrs["settings"])
        assert attrs["bytes_per_probe"] == sum(fields[k][0].nbytes for k in fields if k != "probe_index")
        expected = api.evaluate_irradiance(name, n)
        for row, probe in enumerate(fields["probe_index"]):
            assert store["names"][probe] == api.probe_names[probe]
            np.testing.assert_allclose(spec_irradiance(name, fields, settings, row, n), expected[row],
                                       rtol=1e-6, atol=1e-6 * np.abs(expected[row]).max(), err_msg=name)


def test_fitted_curve_is_stored_as_a_pair(stores):
    _, _, variant = stores
    settings = json.loads(read(variant)["encodings"]["zh3_hallucinated"][0]["settings"])
    assert isinstance(settings["curve"], list) and len(settings["curve"]) == 2
    assert isinstance(settings["fit_samples"], int) and isinstance(settings["fitted"], bool)


def test_probe_names_count_and_reference_error_directions(stores):
    """Several images → /environment/<stem>; /probes@count; reference_error is the relative RMSE at the
    settings' quality_directions Fibonacci directions against the full-resolution image (spec `/diagnostics`)."""
    images, default, _ = stores
    store = read(default)
    assert store["names"] == [f"/environment/{p.stem}" for p in images] and store["count"] == len(images)
    settings = json.loads(store["attrs"]["settings"])
    n = fibonacci(settings["quality_directions"])
    api = bakery.open_store(default)
    from bakery.environment.io import read_environment

    for probe, path in enumerate(images):
        pixels = read_environment(path)[0].pixels
        d, omega, radiance = equirect_quadrature(pixels)
        reference = np.maximum(n @ d.T, 0.0) @ (radiance * omega[:, None])
        for name in ("sh2", "zh3", "zh3_hallucinated_solved"):
            values = api.evaluate_irradiance(name, n)[probe]
            expected = np.linalg.norm(values - reference) / np.linalg.norm(reference)
            np.testing.assert_allclose(store["diagnostics"][f"reference_error/{name}"][probe], expected, rtol=1e-3)


def test_int8_minus_128_and_exponent_31(stores):
    """−128 decodes as −127 (spec decoder and bakery agree); exponent 31 is refused by both."""
    from bakery.errors import StoreFormatError
    from bakery.irradiance import quantize

    _, default, _ = stores
    packed = read(default)["encodings"]["zh3_quantized"][1]["packed"][:1].copy()
    codes = packed[0, 4:].view(np.int8)
    codes[0] = -128
    twin = packed.copy()
    twin[0, 4:].view(np.int8)[0] = -127
    for p in (packed, twin):
        linear, _ = quantize.unpack_zh3(p, True)
        _, c = decode_packed(p[0], BOUNDS[:3] + [ZONAL_BOUNDS], True)
        np.testing.assert_allclose(linear[0, 1:], c[:3], rtol=1e-12)
    np.testing.assert_array_equal(quantize.unpack_zh3(packed, True)[0], quantize.unpack_zh3(twin, True)[0])
    word = int.from_bytes(bytes(packed[0, :4]), "little") | (31 << 6)  # R exponent = 31
    broken = packed.copy()
    broken[0, :4] = np.frombuffer(word.to_bytes(4, "little"), dtype=np.uint8)
    with pytest.raises(ValueError):
        decode_packed(broken[0], BOUNDS[:3] + [ZONAL_BOUNDS], True)
    with pytest.raises(StoreFormatError):
        quantize.unpack_zh3(broken, True)


def test_every_attribute_and_dataset_of_an_image_bake_is_specified(stores):
    """Completeness: the spec names every root attribute, group attribute and dataset an image bake writes
    (encoding names generalised to <encoding>)."""
    _, default, variant = stores
    missing = set()

    def named(token):
        return f"`{token}`" in SPEC_TEXT

    for path in (default, variant):
        with h5py.File(path, "r") as f:
            for key in f.attrs:
                if key.startswith("convention."):
                    if not (named("convention.*") or named("conventions")) or not re.search(
                            rf"\|\s*{re.escape(key.split('.', 1)[1])}\s*\|", SPEC_TEXT):
                        missing.add(f"@/{key}")
                elif not named(key):
                    missing.add(f"@/{key}")
            for key in json.loads(f.attrs["conventions"]):
                if not re.search(rf"\|\s*{re.escape(key)}\s*\|", SPEC_TEXT):
                    missing.add(f"conventions.{key}")
            for key in f["probes"].attrs:
                if not named(key):
                    missing.add(f"@/probes/{key}")

            def visit(name, item):
                parts = name.split("/")
                if parts[0] == "encodings" and len(parts) == 2:  # an encoding group: its attributes
                    missing.update(f"@/{name}/{k}" for k in item.attrs if not named(k))
                    return
                if not isinstance(item, h5py.Dataset):
                    return
                if parts[0] == "encodings":
                    tokens = [parts[-1]]
                elif parts[0] == "diagnostics":
                    rest = "/".join(p if p not in ENCODINGS else "<encoding>" for p in parts[1:])
                    tokens = [rest if not rest.startswith("finalize/") else "finalize/<encoding>/<field>"]
                else:  # /probes, /history, /checksums
                    tokens = [f"/{name}", parts[-1]] if parts[0] == "probes" else [f"/{name}"]
                if not any(named(t) for t in tokens):
                    missing.add(f"{name} ({tokens[0]})")

            f.visititems(visit)
    assert not missing, f"not in schemas/store*.md: {sorted(missing)}"
