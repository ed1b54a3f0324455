"""``bakery_ggx_directional_light`` — the public one-light entry point of the shader library (one analytic GGX
directional light, [SHExp] Eq. 1–8 for a delta light) — rendered on WebGL2 (GLSL) and through the HLSL path
(glslangValidator → SPIR-V → spirv-cross → WebGL2) in one headless Chromium launch, against a closed form written
here from the definitions, not from bakery:

    E = Φ · D(h) · G2(v, l) / (4 n·v) · (F0 + (1 − F0)(1 − v·h)⁵),   h = normalize(v + l),
    D = α² / (π ((n·h)² (α² − 1) + 1)²),   G2 = 1 / (1 + Λ(v) + Λ(l)),   Λ(x) = (√(1 + α² tan²θ_x) − 1) / 2,

with α clamped at 0.002 (docs: bakery.reflection.lights.MIN_ALPHA) and E = 0 where n·l ≤ 0 or n·v ≤ 0 (the
function expects v already clamped to the horizon). The other lights' paths (``bakery_lights_parts`` inside
``shexp_lights`` / ``shexp_hybrid``) are covered by test_shader_library.py / test_shader_edges.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from shader_pipeline import (Job, _b64, chromium_binary, glslang_binary, hlsl_jobs, run_jobs, spirv_cross_binary)
from bakery.shaders import glsl_library

#: The lights' α floor (bakery_core.glsl, bakery.reflection.lights.MIN_ALPHA).
ALPHA_FLOOR = 0.002
#: Float32 inputs → the GPU's float32 arithmetic: relative to the value, plus a floor relative to the largest value.
RTOL, ATOL_PEAK = 2e-4, 1e-6


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def light_rows(seed: int = 7) -> dict[str, np.ndarray]:
    """Rows (K, ·), float32-rounded as the GPU receives them: random (l, v, n) in the upper hemisphere of n, α over
    [0, 1] including 0 and values below the floor, chrome / glass / gold F0, coloured flux; plus edge rows: the
    light below the horizon of n, v below the horizon, the light at grazing n·l, α = 0 just off the mirror peak."""
    rng = np.random.default_rng(seed)
    count = 96
    n = _unit(rng.normal(size=(count, 3)))
    v, l = (_unit(rng.normal(size=(count, 3))) for _ in range(2))  # noqa: E741
    v = np.where((np.einsum("ij,ij->i", v, n) < 0.05)[:, None], _unit(v + 2.0 * n), v)
    l = np.where((np.einsum("ij,ij->i", l, n) < 0.05)[:, None], _unit(l + 2.0 * n), l)  # noqa: E741
    alpha = np.concatenate([[0.0, 1e-4, ALPHA_FLOOR, 1.0], rng.uniform(0.01, 1.0, count - 4)])
    f0 = np.array([[1.0, 1.0, 1.0], [0.04, 0.04, 0.04], [1.0, 0.78, 0.34]])[np.arange(count) % 3]
    flux = rng.uniform(0.5, 20.0, size=(count, 3))
    # edge rows: light under the horizon, view under the horizon, grazing light, α = 0 0.01 rad off the mirror peak
    edge_n = np.array([[0.0, 0.0, 1.0]] * 4)
    edge_v = _unit(np.array([[0.3, 0.0, 1.0], [0.3, 0.0, -0.2], [0.3, 0.1, 1.0], [0.5, 0.0, 1.0]]))
    mirror = edge_v[3] * np.array([-1.0, -1.0, 1.0])
    off_peak = _unit(mirror + np.array([0.0, 0.01, 0.0]))
    edge_l = np.stack([_unit(np.array([0.2, 0.3, -0.1])), _unit(np.array([-0.3, 0.0, 1.0])),
                       _unit(np.array([-1.0, 0.0, 0.02])), off_peak])
    rows = {"l": np.concatenate([l, edge_l]), "v": np.concatenate([v, edge_v]), "n": np.concatenate([n, edge_n]),
            "alpha": np.concatenate([alpha, [0.3, 0.3, 0.2, 0.0]]),
            "f0": np.concatenate([f0, [[1.0, 1.0, 1.0]] * 4]), "flux": np.concatenate([flux, np.ones((4, 3))])}
    return {k: x.astype(np.float32).astype(np.float64) for k, x in rows.items()}


def closed_form(rows: dict[str, np.ndarray]) -> np.ndarray:
    """E (K, 3) of the module docstring, in float64 with θ-based Λ (not bakery's algebraic visibility form)."""
    l, v, n = rows["l"], rows["v"], rows["n"]  # noqa: E741
    a = np.maximum(rows["alpha"], ALPHA_FLOOR)
    nl, nv = np.einsum("ij,ij->i", n, l), np.einsum("ij,ij->i", n, v)
    h = _unit(v + l)
    theta_h = np.arctan2(np.linalg.norm(np.cross(n, h), axis=1), np.einsum("ij,ij->i", n, h))
    d = 1.0 / (np.pi * a**2 * np.cos(theta_h) ** 4 * (1.0 + np.tan(theta_h) ** 2 / a**2) ** 2)

    def smith_lambda(cos_theta: np.ndarray) -> np.ndarray:
        tan2 = (1.0 - cos_theta**2) / np.maximum(cos_theta, 1e-300) ** 2
        return 0.5 * (np.sqrt(1.0 + a**2 * tan2) - 1.0)

    ok = (nl > 0) & (nv > 0)
    g2 = 1.0 / (1.0 + smith_lambda(np.clip(nv, 1e-12, 1)) + smith_lambda(np.clip(nl, 1e-12, 1)))
    fresnel = rows["f0"] + (1.0 - rows["f0"]) * (1.0 - np.einsum("ij,ij->i", v, h))[:, None] ** 5
    e = rows["flux"] * (d * g2 / (4.0 * np.clip(nv, 1e-12, 1)))[:, None] * fresnel  # f·⟨n, l⟩ = D G2 F/(4 n·v)
    return np.where(ok[:, None], e, 0.0)


def light_job(rows: dict[str, np.ndarray]) -> Job:
    """One job: pixel s evaluates row s (six RGBA32F input rows: l·α, v, n, F0, Φ)."""
    count = len(rows["l"])
    texels = np.zeros((5, count, 4), np.float32)
    texels[0, :, :3], texels[0, :, 3] = rows["l"], rows["alpha"]
    texels[1, :, :3], texels[2, :, :3], texels[3, :, :3], texels[4, :, :3] = (rows["v"], rows["n"], rows["f0"],
                                                                              rows["flux"])
    fetch = ["vec4 l_alpha = texelFetch(u_inputs, ivec2(s, 0), 0);",
             "vec3 view = texelFetch(u_inputs, ivec2(s, 1), 0).xyz;",
             "vec3 normal = texelFetch(u_inputs, ivec2(s, 2), 0).xyz;",
             "vec3 f0 = texelFetch(u_inputs, ivec2(s, 3), 0).xyz;",
             "vec3 flux = texelFetch(u_inputs, ivec2(s, 4), 0).xyz;"]
    call = "bakery_ggx_directional_light(l_alpha.xyz, flux, view, normal, l_alpha.w, f0)"
    fragment = "\n".join(["#version 300 es", glsl_library(), "uniform highp sampler2D u_inputs;", "out vec4 o_value;",
                          "void main()", "{", "    int s = int(gl_FragCoord.x);", *("    " + x for x in fetch),
                          f"    o_value = vec4({call}, 1.0);", "}", ""])
    hfetch = [x.replace("texelFetch(u_inputs, ivec2(s, ", "u_inputs.Load(int3(s, ").replace("), 0)", ", 0))")
              .replace("vec", "float") for x in fetch]
    hlsl = "\n".join(['#include "bakery.hlsl"', "Texture2D<float4> u_inputs;",
                      "float4 main(float4 position : SV_Position) : SV_Target", "{", "    int s = int(position.x);",
                      *("    " + x for x in hfetch), f"    return float4({call}, 1.0);", "}", ""])
    texture = {"uniform": "u_inputs", "target": "2D", "internal": "RGBA32F", "width": count, "height": 5,
               "filter": "NEAREST", "data": _b64(texels)}
    return Job(id="light/bakery_ggx_directional_light", encoding="shexp_lights", store="light", variant="fetch",
               fragment=fragment, width=count, height=1, reference=closed_form(rows)[None], textures=[texture],
               hlsl=hlsl)


@pytest.fixture(scope="module")
def light_run(tmp_path_factory):
    if chromium_binary() is None:
        pytest.skip("headless Chromium is not installed (apt-get install -y chromium)")
    rows = light_rows()
    glsl = light_job(rows)
    jobs = [glsl]
    if glslang_binary() is not None and spirv_cross_binary() is not None:
        translated, errors = hlsl_jobs([glsl], tmp_path_factory.mktemp("hlsl_light"))
        assert not errors, errors
        jobs += translated
    run = run_jobs(jobs, tmp_path_factory.mktemp("webgl_light"))
    assert not run.errors, run.errors
    return rows, jobs, run


def test_the_closed_form_is_the_ggx_lobe():
    """The reference itself: D integrates to 1 over projected solid angle of h (∫ D cos θ_h dω_h = 1) at the α of
    the rows (a Gauss–Legendre check of the D written above), and E vanishes where it must."""
    rows = light_rows()
    for a in (0.05, 0.3, 1.0):
        x, w = np.polynomial.legendre.leggauss(400)
        u = 0.5 * (x + 1.0)  # θ_h = u · π/2, substituted t = u² for the narrow peak
        theta = 0.5 * np.pi * u**2
        d = 1.0 / (np.pi * a**2 * np.cos(theta) ** 4 * (1.0 + np.tan(theta) ** 2 / a**2) ** 2)
        total = np.sum(w * 0.5 * d * np.cos(theta) * np.sin(theta) * 2.0 * np.pi * np.pi * u)
        assert abs(total - 1.0) < 1e-6, (a, total)
    e = closed_form(rows)
    assert np.all(e[-4:-2] == 0.0) and np.all(e[:-4].max(axis=1) > 0.0)


@pytest.mark.parametrize("language", ["glsl", "hlsl"])
def test_one_light_matches_the_closed_form(light_run, language):
    rows, jobs, run = light_run
    job = next((j for j in jobs if j.id.startswith("hlsl:") == (language == "hlsl")), None)
    if job is None:
        pytest.skip("glslangValidator / spirv-cross are not installed (apt-get install -y glslang-tools spirv-cross)")
    gpu, ref = run.results[job.id][0], job.reference[0]
    bound = RTOL * np.abs(ref) + ATOL_PEAK * np.abs(ref).max()
    bad = np.flatnonzero(np.any(~(np.abs(gpu - ref) <= bound), axis=1))
    assert not len(bad), "\n".join(f"row {i} α={rows['alpha'][i]}: GPU {gpu[i].tolist()} closed form {ref[i].tolist()}"
                                   for i in bad[:12])
    assert np.all(gpu[-4:-2] == 0.0), "a light or a view under the horizon must add exactly 0"
