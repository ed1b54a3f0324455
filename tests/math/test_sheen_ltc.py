"""Zeltner et al.'s LTC fuzz (bakery.brdf.sheen_ltc). Closed form: a linearly transformed cosine integrates to 1
over the hemisphere (M⁻¹ keeps z, so nothing leaks below it), so the lobe's albedo is exactly the fitted E. An
independent transcription of MaterialX's GLSL — the explicit tangent frame and matrix product of
mx_zeltner_sheen_brdf — agrees with the cosine form the capture evaluates."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bakery.brdf import sheen_ltc


def _hemisphere(n: int = 700):
    cos_t = (np.arange(n) + 0.5) / n
    phi = (np.arange(2 * n) + 0.5) * (math.pi / n)
    c, p = np.meshgrid(cos_t, phi, indexing="ij")
    s = np.sqrt(1 - c * c)
    return s * np.cos(p), s * np.sin(p), c, (1 / n) * (math.pi / n)


@pytest.mark.parametrize("mu", [0.1, 0.4, 0.8, 1.0])
@pytest.mark.parametrize("roughness", [0.1, 0.3, 0.6, 1.0])
def test_the_ltc_integrates_to_one_so_the_lobes_albedo_is_the_fit(mu, roughness):
    x, y, z, weight = _hemisphere()
    total = float(np.sum(sheen_ltc.ltc_distribution(x, y * y, z, mu, roughness)) * weight)
    assert total == pytest.approx(1.0, abs=2e-3)
    lobe = sheen_ltc.sheen_lobe(z, mu, x * math.sqrt(1 - mu * mu) + z * mu, roughness)  # v = (√(1−μ²), 0, μ)
    assert float(np.sum(lobe) * weight) == pytest.approx(float(sheen_ltc.directional_albedo(mu, roughness)),
                                                          abs=2e-3)


def _glsl(l, v, n, roughness):  # noqa: ANN001, ANN202
    """mx_zeltner_sheen_brdf × mx_zeltner_sheen_dir_albedo, transcribed with its explicit frame."""
    nv = min(max(float(n @ v), 1e-6), 1.0)
    x_axis = v - n * nv
    length = float(x_axis @ x_axis)
    if length > 0:
        x_axis = x_axis / math.sqrt(length)
    else:
        x_axis = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(n, x_axis)
    w = np.array([l @ x_axis, l @ y_axis, l @ n])
    r = min(max(roughness, 0.01), 1.0)
    a_inv = (2.58126 * nv + 0.813703 * r) * r / (1.0 + 0.310327 * nv * nv + 2.60994 * nv * r)
    b_inv = math.sqrt(1.0 - nv) * (r - 1.0) * r**3 / (0.0000254053 + 1.71228 * nv - 1.71506 * nv * r + 1.34174 * r * r)
    wo = np.array([a_inv * w[0] + b_inv * w[2], a_inv * w[1], w[2]])
    d = max(wo[2], 0.0) / math.pi * (a_inv / float(wo @ wo)) ** 2
    s = r * (0.0206607 + 1.58491 * r) / (0.0379424 + r * (1.32227 + r))
    m = r * (-0.193854 + r * (-1.14885 + r * (1.7932 - 0.95943 * r * r))) / (0.046391 + r)
    o = r * (0.000654023 + (-0.0207818 + 0.119681 * r) * r) / (1.26264 + r * (-1.92021 + r))
    albedo = math.exp(-0.5 * ((nv - m) / s) ** 2) / (s * math.sqrt(2 * math.pi)) + o
    return max(albedo, 0.0) * d  # the fit dips to −1e-7 near r = 0.125, μ = 1: bakery clips it to [0, 1]


def _unit(values):  # noqa: ANN001, ANN202
    v = np.asarray(values, dtype=np.float64)
    return v / np.linalg.norm(v)


vectors = st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(lambda v: np.linalg.norm(v) > 0.1)


@settings(max_examples=200, deadline=None)
@given(vectors, vectors, st.floats(0.0, 1.0))
def test_the_cosine_form_is_materialxs_glsl(view, light, roughness):
    n = np.array([0.0, 0.0, 1.0])
    v, lt = _unit(view), _unit(light)
    v[2], lt[2] = abs(v[2]) + 1e-3, abs(lt[2])
    v, lt = _unit(v), _unit(lt)
    ours = float(sheen_ltc.sheen_lobe(lt @ n, v @ n, v @ lt, roughness))
    assert ours == pytest.approx(_glsl(lt, v, n, roughness), rel=1e-6, abs=1e-9)
