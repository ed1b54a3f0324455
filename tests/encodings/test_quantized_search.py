"""``zh3_quantized``: codes chosen by a search over neighbouring codes for the lowest error with a non-negative
decoded probe (instead of re-windowing after decoding).

Independent references: the spec-only decoder of ``test_store_spec_decoder`` (R11G11B10F and SNORM8 by hand),
dense direction sampling for non-negativity, brute-force enumeration of every single-code move for local
optimality, and the brute-force irradiance of the capture."""

from math import pi, sqrt

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bakery.encodings.quantized import ZH3Quantized
from bakery.irradiance.code_search import search_zh3_codes
from bakery.probe import ProbeBatch
from bakery.sphere.cubemap import cube_texel_directions
from bakery.sphere.fibonacci import fibonacci_directions
from tests.encodings.test_store_spec_decoder import (
    BOUNDS,
    ZONAL_BOUNDS,
    A,
    basis,
    decode_packed,
    luminance_axis,
    zh3_irradiance,
)

DENSE = fibonacci_directions(20000)
ZH3_BOUNDS = BOUNDS[:3] + [ZONAL_BOUNDS]


def decode(packed, companding=True):
    """(linear (4, 3), zonal (3,)) of one 16-byte row by the spec decoder."""
    f0, c = decode_packed(packed, ZH3_BOUNDS, companding)
    return np.concatenate([f0[None], c[:3]]), c[3]


def sh_error(packed, target, companding=True):
    """Irradiance SH error Σ_k A_k²(s_k − t_k)² of the decoded ZH3 expanded to SH3 (band 2 = zonal·√(4π/5)·Y2(a))."""
    linear, zonal = decode(packed, companding)
    band2 = sqrt(4 * pi / 5) * np.outer(basis(luminance_axis(linear)[None])[0, 4:9], zonal)
    return np.sum((A[:, None] * (np.concatenate([linear, band2]) - target)) ** 2)


def sunny_cubes(rng, count, n=16):
    d = cube_texel_directions(n)
    cubes = np.zeros((count, 6, n, n, 3))
    for i in range(count):
        for _ in range(rng.integers(1, 4)):
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            cubes[i] += np.exp(rng.uniform(20, 400) * (d @ axis - 1))[..., None] * rng.uniform(1, 300, size=3)
        cubes[i] += rng.uniform(0.0, 0.2, size=3)
    return cubes.astype(np.float32)


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=5)
def test_decoded_probe_is_non_negative_everywhere(seed):
    """Sun-dominated captures (where rounding the deringed ZH3 makes most decoded probes negative): dense sampling
    of the spec-decoded irradiance finds nothing below zero."""
    cubes = sunny_cubes(np.random.default_rng(seed), 4)
    packed = ZH3Quantized().encode(ProbeBatch(cubes))["packed"]
    for row in packed:
        linear, zonal = decode(row)
        values = zh3_irradiance(linear, zonal, DENSE[::2])
        assert values.min() >= -1e-9 * np.abs(values).max()


def _nearest_codes(linear, zonal, companding=True):
    """16-byte row of the nearest codes for a float ZH3 (linear (4, 3), zonal (3,)): bakery's packer, whose layout the
    spec decoder checks (test_store_spec_decoder)."""
    from bakery.irradiance import quantize

    packed, _ = quantize.pack_zh3(linear[None], zonal[None], companding)  # layout verified by the spec decoder
    return packed


def _moves(row):
    """Every single-code move of a row (the 12 SNORM codes ±1, the 3 DC fields ±1), enumerated one by one."""
    out = []
    for j in range(12):
        for step in (1, -1):
            moved = row.copy()
            code = int(row[4 + j].view(np.int8)) + step
            if -127 <= code <= 127:
                moved[4 + j] = np.int8(code).view(np.uint8)
                out.append(moved)
    word = int.from_bytes(bytes(row[:4]), "little")
    for shift, width in ((0, 11), (11, 11), (22, 10)):
        field = (word >> shift) & ((1 << width) - 1)
        for step in (1, -1):
            value = field + step
            if 0 <= value and (value >> (width - 5)) < 31:
                moved = row.copy()
                new = (word & ~(((1 << width) - 1) << shift)) | (value << shift)
                moved[:4] = np.frombuffer(new.to_bytes(4, "little"), dtype=np.uint8)
                out.append(moved)
    return out


def _distance(a, b):
    codes = np.abs(a[4:].view(np.int8).astype(int) - b[4:].view(np.int8).astype(int)).max()
    wa, wb = int.from_bytes(bytes(a[:4]), "little"), int.from_bytes(bytes(b[:4]), "little")
    fields = [abs(((wa >> s) & ((1 << w) - 1)) - ((wb >> s) & ((1 << w) - 1))) for s, w in ((0, 11), (11, 11),
                                                                                              (22, 10))]
    return max(codes, *fields)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_unconstrained_search_ends_in_a_local_minimum_of_the_error(seed):
    """Without the constraint, no single-code move within the radius lowers the error (brute-force enumeration),
    and the error is never above the nearest codes'."""
    from tests.conftest import random_positive_radiance_sh

    sh = random_positive_radiance_sh(np.random.default_rng(seed), 3)[0]
    a = luminance_axis(sh[:4])
    zonal = sqrt(4 * pi / 5) * basis(a[None])[0, 4:9] @ sh[4:9]  # [ZH3] Eq. 10
    start = _nearest_codes(sh[:4], zonal)
    found, _ = search_zh3_codes(start, sh[None], True, non_negative=False, radius=1)
    best = sh_error(found[0], sh)
    assert best <= sh_error(start[0], sh) * (1 + 1e-12)
    for move in _moves(found[0]):
        if _distance(move, start[0]) <= 1:
            assert sh_error(move, sh) >= best * (1 - 1e-9)


@pytest.mark.parametrize("seed", [4, 5])
def test_constrained_search_is_no_worse_than_the_nearest_codes_when_those_are_non_negative(seed):
    from tests.conftest import random_positive_radiance_sh

    sh = random_positive_radiance_sh(np.random.default_rng(seed), 2)[0]
    sh[0] += 3.0  # ambient: the nearest codes are non-negative
    a = luminance_axis(sh[:4])
    zonal = sqrt(4 * pi / 5) * basis(a[None])[0, 4:9] @ sh[4:9]
    start = _nearest_codes(sh[:4], zonal)
    assert zh3_irradiance(*decode(start[0]), DENSE).min() > 0
    found, stats = search_zh3_codes(start, sh[None], True, non_negative=True, radius=1)
    assert stats["negative"] == 0
    assert sh_error(found[0], sh) <= sh_error(start[0], sh) * (1 + 1e-12)
    assert zh3_irradiance(*decode(found[0]), DENSE).min() >= 0


def _dc_floor_and_errors(image, normals, reference):
    """(float zh3_deringed error, its error with only the DC rounded to R11G11B10F by hand, zh3_quantized error,
    decoded minimum over DENSE relative to the DC term) of one image."""
    from bakery.encodings.zh3 import ZH3Deringed
    from bakery.environment.resample import resample_to_cube

    batch = ProbeBatch(resample_to_cube(image, 64)[None])
    floating = ZH3Deringed().encode(batch)
    linear = floating["radiance_sh"][0].astype(np.float64)
    zonal = floating["zonal_l2"][0].astype(np.float64)

    def rounded(value, mantissa_bits):  # nearest representable unsigned small float (normal range)
        exponent = np.floor(np.log2(value))
        step = 2.0 ** (exponent - mantissa_bits)
        return np.round(value / step) * step

    dc_linear = linear.copy()
    dc_linear[0] = [rounded(linear[0, 0], 6), rounded(linear[0, 1], 6), rounded(linear[0, 2], 5)]
    packed = ZH3Quantized().encode(batch)["packed"][0]
    ql, qz = decode(packed)
    error = [np.linalg.norm(zh3_irradiance(li, zi, normals) - reference) / np.linalg.norm(reference)
             for li, zi in ((linear, zonal), (dc_linear, zonal), (ql, qz))]
    values = zh3_irradiance(ql, qz, DENSE)
    return (*error, values.min() / (pi * ql[0] / (2 * sqrt(pi))).max())


@pytest.mark.slow
def test_shared_maps_quantized_within_two_percent_of_float_or_of_its_dc_floor(shared_data):
    """On every shared map, against the full-resolution image: the 16 bytes add ≤ 2 % over float deringed ZH3, or
    over float deringed ZH3 with its DC alone rounded to R11G11B10F where that rounding is already more
    (the nearly constant synthetic patterns); and the decoded probe is non-negative."""
    from bakery.environment.io import read_environment
    from bakery.environment.resample import environment_samples
    from bakery.irradiance.reference import reference_irradiance

    normals = fibonacci_directions(384)  # the brute-force reference dominates the run time
    for path in sorted((shared_data / "hdri").rglob("*")):
        if path.suffix.lower() not in (".hdr", ".exr"):
            continue
        image, _ = read_environment(path)
        reference = reference_irradiance(environment_samples(image), normals)
        floating, dc_floor, quantized, minimum = _dc_floor_and_errors(image, normals, reference)
        assert quantized <= 1.02 * max(floating, dc_floor), (path.name, floating, dc_floor, quantized)
        assert minimum >= -1e-9, path.name


def _dc_step(value, mantissa_bits):
    """The spacing of unsigned small floats (``mantissa_bits`` explicit bits) around ``value``: 2^(e − m)."""
    return 2.0 ** (np.floor(np.log2(value)) - mantissa_bits)


def lamp_cubes(rng, count, n=16):
    """A small warm lamp (a disc of 2-10 degrees) over a dim floor: a probe beside a UsdLux SphereLight, where the
    decoded ZH3 of many probes stays negative after the search and takes the windowing fallback."""
    d = cube_texel_directions(n)
    cubes = np.zeros((count, 6, n, n, 3))
    for i in range(count):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        lamp = d @ axis > np.cos(np.radians(rng.uniform(2, 10)))
        cubes[i] += lamp[..., None] * rng.uniform(1, 300) * np.array([1.0, 0.85, 0.6])
        cubes[i] += (d[..., 1] < 0)[..., None] * rng.uniform(0.0, 0.05) * np.array([1.0, 0.9, 0.8])
    return cubes.astype(np.float32)


@pytest.mark.parametrize("captures", ["sunny", "lamp"])
def test_every_probe_keeps_its_mean_irradiance_within_the_dc_format(captures):
    """The 16 bytes keep each probe's mean irradiance (its DC) within R11G11B10F precision: half a step of rounding
    plus the search's one-step DC move, also for probes that need the windowing fallback. Before: the search
    lowered every DC field of a probe it could not make non-negative by its whole radius (scaling a channel scales
    its negative minimum), and the wider searches re-anchored at the last result: 6-18 % darker, and tinted."""
    cubes = (sunny_cubes if captures == "sunny" else lamp_cubes)(np.random.default_rng(1), 40)
    batch = ProbeBatch(cubes)
    captured_dc = batch.radiance_sh(0)[:, 0]  # (P, 3): the capture's f0, Y00 · ∫ L dω
    packed = ZH3Quantized().encode(batch)["packed"]
    decoded_dc = np.array([decode(row)[0][0] for row in packed])  # the spec decoder
    step = np.stack([_dc_step(captured_dc[:, 0], 6), _dc_step(captured_dc[:, 1], 6),
                     _dc_step(captured_dc[:, 2], 5)], axis=-1)
    assert np.all(np.abs(decoded_dc - captured_dc) <= 1.5 * step + 1e-12), np.max(
        np.abs(decoded_dc - captured_dc) / step)


def test_a_bake_names_the_probes_that_took_the_windowing_fallback():
    """The fallback's warning names its probes (a bake's warning said only how many): the names are of irradiance
    probes of the batch (reflection-only probes in between shift the rows), and each named probe, encoded alone,
    takes the fallback too (the search is per probe)."""
    import re
    import warnings

    from bakery.errors import ClampWarning
    from bakery.pipeline.encode import encode_batch
    from bakery.pipeline.settings import BakeSettings
    from bakery.probe import Probe

    lamps = lamp_cubes(np.random.default_rng(1), 12)
    cubes = np.concatenate([lamps[:1] * 0 + 1, lamps])  # a reflection-only probe first
    probes = [Probe("/mirror", kinds=("reflection",))] + [Probe(f"/lamp{i}", kinds=("irradiance",)) for i in range(12)]
    result = encode_batch(probes, ProbeBatch(cubes), BakeSettings(face_size=16, encodings=("zh3_quantized",)))
    messages = [w.message for w in result.warnings if "windowed instead" in w.message]
    assert len(messages) == 1, result.warnings
    count = int(re.search(r"(\d+) probes stayed negative", messages[0]).group(1))
    named = re.search(r"\(([^)]*)\)$", messages[0]).group(1)
    shown = named.split(" and ")[0].split(", ")
    assert len(shown) == min(count, 3) and (count <= 3 or named.endswith(f"and {count - 3} more"))
    for name in shown:
        assert name.startswith("/lamp")
        with warnings.catch_warnings(record=True) as alone:
            warnings.simplefilter("always", ClampWarning)
            ZH3Quantized().encode(ProbeBatch(lamps[int(name[5:])][None]))
        assert any("windowed instead" in str(w.message) for w in alone), name
