"""Runs bakery's shader library on a real GPU pipeline: WebGL2 in headless Chromium (SwiftShader where there is no GPU).

For every (store, encoding) a job is built from ``bakery/shaders/manifest.json``: the encoding's stored fields are
uploaded as an engine would (float fields as RGBA32F texels, uint8 layouts as R32UI little-endian words, shared tables
as RG32F/R32F textures, split-sum levels as RGBA16F face arrays), a generated fragment shader loads them and calls the
manifest's entry point at per-pixel inputs (normal, view, α, F0), and ``readPixels`` reads the RGBA32F target back.
All jobs run in one page, in one Chromium launch (:func:`run_jobs`).

Each job also carries the same harness as an HLSL pixel shader over ``bakery.hlsl`` (``Job.hlsl``); :func:`hlsl_jobs`
compiles it to SPIR-V (glslangValidator's HLSL front end) and translates that to GLSL ES 3.00 (spirv-cross), giving
jobs that run the HLSL on the same page (tests/shaders/test_hlsl_execution.py).
"""

from __future__ import annotations

import base64
import hashlib
import html
import json
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bakery.shaders import SHADER_DIR, entry_for, glsl_library, manifest

HERE = Path(__file__).resolve().parent
#: The report test's flags (tests/report/test_report.py) without --disable-gpu: a GPU is used where there is one,
#: SwiftShader (WebGL2 on the CPU) otherwise.
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-quic", "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--enable-unsafe-swiftshader",
                  "--ignore-gpu-blocklist"]
#: Hardware-filtering counterparts of the exact (texelFetch) lookups.
SAMPLED_LOOKUP = {"bakery_dfg_fetch": "bakery_dfg_sample", "bakery_cube_fetch_bilinear": "bakery_cube_sample_bilinear"}
#: The harness's GLSL types → HLSL.
HLSL_TYPES = {"vec2": "float2", "vec3": "float3", "vec4": "float4", "uvec4": "uint4", "uint": "uint", "int": "int",
              "float": "float", "bool": "bool"}
#: BAKERY_HYBRID_MAX_LEVELS of bakery_core.glsl (the size of the level-α array).
MAX_HYBRID_LEVELS = 16
#: Tolerances of a GPU value against the API's (docs/engine-integration.md): exact lookups (texelFetch) to float32
#: rounding of the peak (+ of the value for reflection), hardware-filtered ones to 8-bit filter weights.
ULP_PEAK = 2.0**-19
ULP_VALUE = 2.0**-16
FILTERED = 2.0**-8


def tolerance(kind: str, variant: str, reference: np.ndarray) -> np.ndarray:
    """The bound on |GPU − API| for each value of ``reference`` (P, M, C) of an encoding of ``kind`` evaluated by the
    ``variant`` lookup ("fetch": exact; else filtered), per probe relative to its peak."""
    peak = np.max(np.abs(reference), axis=(1, 2), keepdims=True) + 1e-30
    if variant != "fetch":
        return FILTERED * peak
    if kind == "irradiance":
        return ULP_PEAK * peak
    return ULP_PEAK * peak + ULP_VALUE * np.abs(reference)


def chromium_binary() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


# ------------------------------------------------------------------------------------------------------ inputs
def fibonacci(count: int) -> np.ndarray:
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=-1)


def _f32(a: np.ndarray) -> np.ndarray:
    """Inputs rounded to float32 (what the GPU receives), as float64 for the Python reference."""
    return np.asarray(a, dtype=np.float32).astype(np.float64)


def irradiance_inputs() -> dict[str, np.ndarray]:
    normals = np.concatenate([np.eye(3), -np.eye(3), fibonacci(58)])
    return {"normal": _f32(normals)}


def reflection_inputs(count: int = 96, seed: int = 18) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    normals = fibonacci(count)[rng.permutation(count)]
    tangent = np.cross(normals, rng.normal(size=(count, 3)))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    # views below the horizon (n·v < 0: the reflection functions clamp them to it) in rows 3..8 and 9 more
    cos_v = np.concatenate([[1.0, 0.03, 0.5, -0.02, -0.3, -0.9, -0.999, -0.5, -0.1],
                            rng.uniform(0.02, 1.0, count - 18), rng.uniform(-1.0, 0.0, 9)])
    views = cos_v[:, None] * normals + np.sqrt(1.0 - cos_v**2)[:, None] * tangent
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    # α = 0 and α below the SH exponentials' fitted α_lo (clamped into alpha_range), the hybrid's level α's
    alpha = np.concatenate([[0.01, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 0.0, 0.0, 0.003, 0.02, 0.144325, 0.27346],
                            rng.uniform(0.02, 1.0, count - 14)])
    f0 = rng.uniform(0.02, 1.0, size=(count, 3))
    f0[:8] = 0.04
    return {"normal": _f32(normals), "view": _f32(views), "alpha": _f32(alpha), "f0": _f32(f0)}


# ------------------------------------------------------------------------------------------------------ jobs
@dataclass
class Job:
    id: str
    encoding: str
    store: str
    variant: str  # "fetch": exact bilinear weights (texelFetch); "sample": the GPU's filtering units
    fragment: str
    width: int
    height: int
    reference: np.ndarray  # (P, N, 3)
    mask: np.ndarray | None = None  # (P, N) samples compared (None: all)
    textures: list[dict] = field(default_factory=list)
    uniforms: list[dict] = field(default_factory=list)
    hlsl: str = ""  # the same job as an HLSL pixel shader (bakery.hlsl), for hlsl_jobs()

    def page_entry(self) -> dict:
        return {"id": self.id, "fragment": self.fragment, "width": self.width, "height": self.height,
                "textures": self.textures, "uniforms": self.uniforms}


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode()


def _rgba(array: np.ndarray, fill: float = 0.0) -> np.ndarray:
    """(..., 3) → (..., 4) with a constant fourth channel."""
    pad = np.full(array.shape[:-1] + (1,), fill, dtype=array.dtype)
    return np.concatenate([array, pad], axis=-1)


def _array_type(glsl_type: str) -> tuple[str, int | None]:
    match = re.fullmatch(r"(\w+)\[(\d+)\]", glsl_type)
    return (match.group(1), int(match.group(2))) if match else (glsl_type, None)


def build_jobs(store, label: str, variants: tuple[str, ...] = ("fetch", "sample", "cube")) -> tuple[list[Job], list[str]]:
    """Jobs for every encoding of ``store`` (a :class:`bakery.api.ProbeStore`), and the names of encodings the
    manifest has no entry for."""
    jobs, missing = [], []
    for name, info in store.encodings.items():
        spec = entry_for(name, info.settings)
        if spec is None:
            missing.append(name)
            continue
        has_lookup = any("lookup" in a for a in spec["arguments"])
        has_chain = any("chain" in a for a in spec["arguments"])
        for variant in variants:
            if variant == "sample" and not has_lookup or variant == "cube" and not has_chain:
                continue
            if variant == "cube":  # one job per probe: each level of the probe is a cube texture
                jobs += [_job(store, label, name, info, spec, variant, probe=p)
                         for p in range(len(store.fields(name)["probe_index"]))]
            else:
                jobs.append(_job(store, label, name, info, spec, variant))
    return jobs, missing


def _job(store, label: str, name: str, info, spec: dict, variant: str, probe: int | None = None) -> Job:
    """``variant``: "fetch" (exact lookups), "sample" (hardware bilinear on face arrays / tables) or "cube" (the
    split-sum levels of probe ``probe`` as cube textures, compared where no bilinear tap crosses a face edge)."""
    fields = store.fields(name)
    count = int(len(fields["probe_index"]))
    mask = None
    inputs = irradiance_inputs() if info.kind == "irradiance" else reflection_inputs()
    samples = len(inputs["normal"])
    if info.kind == "irradiance":
        reference = store.evaluate_irradiance(name, inputs["normal"])
    else:
        reference = store.evaluate_reflection(name, inputs["view"], inputs["normal"], inputs["alpha"], inputs["f0"])
    if probe is not None:
        fields = {k: np.asarray(v)[probe:probe + 1] for k, v in fields.items()}
        count, reference = 1, reference[probe:probe + 1]

    decls: list[str] = []
    body: list[str] = []
    call: list[str] = []  # the entry point's arguments: the same variable names in the GLSL and the HLSL
    hdecls: list[str] = []  # the HLSL counterparts of decls (resources, helper functions), body, settings
    hbody: list[str] = []
    hsettings: list[str] = []
    hfunctions: list[str] = []
    textures: list[dict] = []
    uniforms: list[dict] = []
    float_texels: list[np.ndarray] = []  # per field (P, K, 4)
    word_texels: list[np.ndarray] = []  # per field (P, W)

    rows = np.zeros((3, samples, 4), np.float32)
    rows[0, :, :3] = inputs["normal"]
    if info.kind == "reflection":
        rows[1, :, :3] = inputs["view"]
        rows[2, :, 0] = inputs["alpha"]
        rows[2, :, 1:] = inputs["f0"]
    textures.append({"uniform": "u_inputs", "target": "2D", "internal": "RGBA32F", "width": samples, "height": 3,
                     "filter": "NEAREST", "data": _b64(rows)})
    decls.append("uniform highp sampler2D u_inputs;")
    body += ["vec3 normal = texelFetch(u_inputs, ivec2(s, 0), 0).xyz;",
             "vec3 view = texelFetch(u_inputs, ivec2(s, 1), 0).xyz;",
             "vec4 alpha_f0 = texelFetch(u_inputs, ivec2(s, 2), 0);",
             "float alpha = alpha_f0.x;", "vec3 f0 = alpha_f0.yzw;"]
    hdecls.append("Texture2D<float4> u_inputs;")
    hbody += ["float3 normal = u_inputs.Load(int3(s, 0, 0)).xyz;",
              "float3 view = u_inputs.Load(int3(s, 1, 0)).xyz;",
              "float4 alpha_f0 = u_inputs.Load(int3(s, 2, 0));",
              "float alpha = alpha_f0.x;", "float3 f0 = alpha_f0.yzw;"]
    float_offset = word_offset = 0
    field_vars: dict[str, str] = {}  # stored field → its GLSL variable
    for k, argument in enumerate(spec["arguments"]):
        var = f"a{k}"
        if "field" in argument:
            data = np.asarray(fields[argument["field"]])
            base, size = _array_type(argument["type"])
            field_vars[argument["field"]] = var
            if base in ("vec3", "vec2"):
                width = int(base[-1])
                expected = (size, width) if size is not None else (width,)
                assert data.shape[1:] == expected, f"{name}.{argument['field']}: stored {data.shape[1:]}, shader {expected}"
                assert data.dtype.kind == "f", f"{name}.{argument['field']}: {data.dtype}"
                texels = data.reshape(count, -1, width).astype(np.float32)
                texels = np.concatenate([texels, np.zeros((count, texels.shape[1], 4 - width), np.float32)], axis=-1)
                float_texels.append(texels)
                swizzle = "xyz" if width == 3 else "xy"
                hbase = HLSL_TYPES[base]
                if size is None:
                    body.append(f"{base} {var} = texelFetch(u_fields, ivec2({float_offset}, probe), 0).{swizzle};")
                    hbody.append(f"{hbase} {var} = u_fields.Load(int3({float_offset}, probe, 0)).{swizzle};")
                else:
                    body.append(f"{base} {var}[{size}]; for (int i = 0; i < {size}; ++i) "
                                f"{var}[i] = texelFetch(u_fields, ivec2({float_offset} + i, probe), 0).{swizzle};")
                    hbody.append(f"{hbase} {var}[{size}]; for (int i = 0; i < {size}; ++i) "
                                 f"{var}[i] = u_fields.Load(int3({float_offset} + i, probe, 0)).{swizzle};")
                float_offset += texels.shape[1]
            elif base == "int":  # a (1,) integer field, uploaded as one R32UI word (two's complement)
                assert data.shape[1:] == (1,) and data.dtype.kind in "iu", f"{name}.{argument['field']}: {data.dtype}"
                word_texels.append(data.astype("<i4").view("<u4").reshape(count, 1))
                body.append(f"int {var} = int(texelFetch(u_words, ivec2({word_offset}, probe), 0).x);")
                hbody.append(f"int {var} = asint(u_words.Load(int3({word_offset}, probe, 0)));")
                word_offset += 1
            else:  # uint words of the uint8 layout, little-endian
                assert data.dtype == np.uint8, f"{name}.{argument['field']}: {data.dtype}"
                words = np.ascontiguousarray(data).view("<u4").reshape(count, -1)
                n_words = 4 if base == "uvec4" else size
                assert words.shape[1] == n_words, f"{name}.{argument['field']}: {words.shape[1]} words, shader {n_words}"
                word_texels.append(words)
                fetch = [f"texelFetch(u_words, ivec2({word_offset + i}, probe), 0).x" for i in range(n_words)]
                hfetch = [f"u_words.Load(int3({word_offset + i}, probe, 0))" for i in range(n_words)]
                if base == "uvec4":
                    body.append(f"uvec4 {var} = uvec4({', '.join(fetch)});")
                    hbody.append(f"uint4 {var} = uint4({', '.join(hfetch)});")
                else:
                    body.append(f"uint {var}[{n_words}]; for (int i = 0; i < {n_words}; ++i) "
                                f"{var}[i] = texelFetch(u_words, ivec2({word_offset} + i, probe), 0).x;")
                    hbody.append(f"uint {var}[{n_words}]; for (int i = 0; i < {n_words}; ++i) "
                                 f"{var}[i] = u_words.Load(int3({word_offset} + i, probe, 0));")
                word_offset += n_words
            call.append(var)
        elif "setting" in argument:
            value = info.settings[argument["setting"]]
            value = argument.get("values", {}).get(value, value) if isinstance(value, str) else value
            if argument.get("value") == "length":
                value = len(value)
            uniform = f"u_setting_{argument['setting']}"
            decls.append(f"uniform {argument['type']} {uniform};")
            hsettings.append(f"{HLSL_TYPES[argument['type']]} {uniform};")
            kind = argument["type"]
            uniforms.append({"name": uniform, "type": kind,
                             "value": [float(v) for v in value] if kind == "vec2" else float(value) if kind == "float"
                             else int(value) if kind == "int" else int(bool(value))})
            call.append(uniform)
        elif "input" in argument:
            call.append(argument["input"])
        elif "table" in argument:
            table = np.asarray(store.shared(name)[argument["table"]], dtype=np.float32)
            uniform = f"u_table_{argument['table']}"
            internal = {2: "RG32F", 1: "R32F"}[table.shape[2] if table.ndim == 3 else 1]
            textures.append({"uniform": uniform, "target": "2D", "internal": internal, "width": table.shape[1],
                             "height": table.shape[0], "filter": "LINEAR", "data": _b64(table)})
            decls.append(f"uniform highp sampler2D {uniform};")
            hdecls.append(f"Texture2D<float4> {uniform};")
            lookup = argument["lookup"]
            if variant == "sample":
                lookup = SAMPLED_LOOKUP.get(lookup, lookup)
            body.append(f"{argument['type']} {var} = {lookup}({uniform}, dot(normal, view), alpha);")
            sampler = f"{uniform}, u_linear_clamp" if lookup in SAMPLED_LOOKUP.values() else uniform
            hbody.append(f"{HLSL_TYPES[argument['type']]} {var} = {lookup}({sampler}, dot(normal, view), alpha);")
            call.append(var)
        elif "chain" in argument:
            hybrid = "level_alphas" in argument
            if hybrid:  # shexp_hybrid: levels at the stored α's, the probe's first_level k0 and up
                level_alphas = [float(a) for a in info.settings[argument["level_alphas"]]]
                levels = len(level_alphas)
                first = np.asarray(fields[argument["first_level"]]).reshape(-1)
                decls.append(f"uniform float u_level_alphas[{MAX_HYBRID_LEVELS}];")
                hsettings.append(f"float u_level_alphas[{MAX_HYBRID_LEVELS}];")
                uniforms.append({"name": "u_level_alphas", "type": "float[]",
                                 "value": level_alphas + [1.0] * (MAX_HYBRID_LEVELS - levels)})
            else:
                levels = int(info.settings[argument["levels"]])
                first = np.zeros(count, np.int64)
            lookup = argument["lookup"]
            if variant == "sample":
                lookup = SAMPLED_LOOKUP.get(lookup, lookup)
            branches = []
            hbranches = []
            sizes = []
            for i in range(levels):
                level = np.asarray(fields[f"{argument['chain']}{i}"])  # (P, 6, N, N, 3) float16
                size = level.shape[2]
                sizes.append(size)
                if variant == "cube" and i < int(first.min()):
                    continue  # below the probe's first_level: not uploaded (store-reflection.md), never read
                if (variant == "cube" and hybrid and argument.get("gap_skipped") in fields
                        and 1 <= i <= int(np.min(np.asarray(fields[argument["gap_skipped"]])))):
                    continue  # a skipped gap level (1 … s): not uploaded, never read
                faces = _rgba(level.astype(np.float16).reshape(count * 6, size, size, 3), fill=1.0)
                target = "CUBE" if variant == "cube" else "2D_ARRAY"
                textures.append({"uniform": f"u_level{i}", "target": target, "internal": "RGBA16F", "width": size,
                                 "height": size, "depth": count * 6, "filter": "LINEAR", "data": _b64(faces.view(np.uint16))})
                if variant == "cube":
                    decls.append(f"uniform highp samplerCube u_level{i};")
                    branches.append(f"    if (level == {i}) return bakery_cube_sample_seamless(u_level{i}, d);")
                    hdecls.append(f"TextureCube<float4> u_level{i};")
                    hbranches.append(f"    if (level == {i}) "
                                     f"return bakery_cube_sample_seamless(u_level{i}, u_linear_clamp, d);")
                else:
                    decls.append(f"uniform highp sampler2DArray u_level{i};")
                    branches.append(f"    if (level == {i}) return {lookup}(u_level{i}, first_layer, d);")
                    hdecls.append(f"Texture2DArray<float4> u_level{i};")
                    sampler = f"u_level{i}, u_linear_clamp" if lookup in SAMPLED_LOOKUP.values() else f"u_level{i}"
                    hbranches.append(f"    if (level == {i}) return {lookup}({sampler}, first_layer, d);")
            if variant == "cube":  # seamless filtering differs within half a texel of a face edge
                mask = _inner_face_mask(inputs, sizes, levels, first, level_alphas if hybrid else None)
            decls.append("vec3 bk_chain(int level, int first_layer, vec3 d)\n{\n" + "\n".join(branches)
                         + "\n    return vec3(0.0, 0.0, 0.0);\n}")
            hfunctions.append("float3 bk_chain(int level, int first_layer, float3 d)\n{\n" + "\n".join(hbranches)
                              + "\n    return float3(0.0, 0.0, 0.0);\n}")
            gap = argument.get("gap_skipped")
            if hybrid and gap in fields:  # a gap_level store: the probe's gap_skipped word
                gap_var = f"{var}_gap"
                data = np.asarray(fields[gap])
                assert data.shape[1:] == (1,) and data.dtype.kind in "iu", f"{name}.{gap}: {data.dtype}"
                word_texels.append(data.astype("<i4").view("<u4").reshape(count, 1))
                body.append(f"int {gap_var} = int(texelFetch(u_words, ivec2({word_offset}, probe), 0).x);")
                hbody.append(f"int {gap_var} = asint(u_words.Load(int3({word_offset}, probe, 0)));")
                word_offset += 1
                first_arguments = f"{field_vars[argument['first_level']]}, {gap_var}, "
            elif hybrid:
                first_arguments = f"{field_vars[argument['first_level']]}, "
            coordinate = (f"bakery_hybrid_levels(alpha, u_level_alphas, {levels}, {first_arguments}"
                          if hybrid else f"bakery_splitsum_levels(alpha, {levels}, ")
            body += [f"int {var}_i0, {var}_i1; float {var}_f;",
                     f"{coordinate}{var}_i0, {var}_i1, {var}_f);",
                     f"vec3 {var}_r = bakery_chain_direction(view, normal);",
                     f"vec3 {var}_c0 = bk_chain({var}_i0, 6 * probe, {var}_r);",
                     f"vec3 {var}_c1 = bk_chain({var}_i1, 6 * probe, {var}_r);"]
            hbody += [f"int {var}_i0, {var}_i1; float {var}_f;",
                      f"{coordinate}{var}_i0, {var}_i1, {var}_f);",
                      f"float3 {var}_r = bakery_chain_direction(view, normal);",
                      f"float3 {var}_c0 = bk_chain({var}_i0, 6 * probe, {var}_r);",
                      f"float3 {var}_c1 = bk_chain({var}_i1, 6 * probe, {var}_r);"]
            call += [f"{var}_c0", f"{var}_c1", f"{var}_f"]
        else:
            raise ValueError(f"{name}: unknown manifest argument {argument}")
    if float_texels:
        packed = np.concatenate(float_texels, axis=1)
        textures.append({"uniform": "u_fields", "target": "2D", "internal": "RGBA32F", "width": packed.shape[1],
                         "height": count, "filter": "NEAREST", "data": _b64(packed)})
        decls.append("uniform highp sampler2D u_fields;")
        hdecls.append("Texture2D<float4> u_fields;")
    if word_texels:
        packed = np.concatenate(word_texels, axis=1).astype("<u4")
        textures.append({"uniform": "u_words", "target": "2D", "internal": "R32UI", "width": packed.shape[1],
                         "height": count, "filter": "NEAREST", "data": _b64(packed)})
        decls.append("uniform highp usampler2D u_words;")
        hdecls.append("Texture2D<uint> u_words;")
    fragment = "\n".join([
        "#version 300 es", glsl_library(), "// ---- test harness (tests/shaders/shader_pipeline.py)", *decls,
        "out vec4 o_value;", "void main()", "{", "    int s = int(gl_FragCoord.x);",
        "    int probe = int(gl_FragCoord.y);" if probe is None else "    int probe = 0;",
        *("    " + line for line in body), f"    o_value = vec4({spec['entry']}({', '.join(call)}), 1.0);", "}", ""])
    hlsl = "\n".join([
        '#include "bakery.hlsl"', "// ---- test harness (tests/shaders/shader_pipeline.py)", *hdecls,
        "SamplerState u_linear_clamp;", *(["cbuffer Settings", "{", *("    " + m for m in hsettings), "};"]
                                          if hsettings else []),
        *hfunctions, "float4 main(float4 position : SV_Position) : SV_Target", "{", "    int s = int(position.x);",
        "    int probe = int(position.y);" if probe is None else "    int probe = 0;",
        *("    " + line for line in hbody), f"    return float4({spec['entry']}({', '.join(call)}), 1.0);", "}", ""])
    suffix = "" if probe is None else f"/probe{probe}"
    return Job(id=f"{label}/{name}/{variant}{suffix}", encoding=name, store=label, variant=variant, fragment=fragment,
               width=samples, height=count, reference=reference, mask=mask, textures=textures, uniforms=uniforms,
               hlsl=hlsl)


def _inner_face_mask(inputs: dict, sizes: list[int], levels: int, first: np.ndarray,
                     level_alphas: list[float] | None) -> np.ndarray:
    """(P, N) rows whose chain lookups (at the levels each row reads) stay 1.5 texels inside a face: there a cube
    texture's seamless filtering equals bakery's within-face bilinear lookup."""
    from bakery.brdf.ggx import reflect
    from bakery.reflection.splitsum import level_coordinate
    from bakery.reflection.validation import clamp_view_to_horizon
    from bakery.sphere.cubemap import direction_to_cube_face_uv

    r = reflect(clamp_view_to_horizon(inputs["view"], inputs["normal"]), inputs["normal"])
    _, u, v = direction_to_cube_face_uv(r)
    edge = np.maximum(np.abs(u), np.abs(v))
    if level_alphas is None:
        x = np.clip(np.sqrt(inputs["alpha"]), 0.0, 1.0) * (levels - 1)
        xs = x[None, :].repeat(len(first), axis=0)
    else:
        x = level_coordinate(np.asarray(level_alphas), inputs["alpha"])
        xs = np.maximum(x[None, :], np.minimum(first, levels - 1)[:, None])
    i0 = np.minimum(np.floor(xs).astype(int), levels - 1)
    i1 = np.minimum(i0 + 1, levels - 1)
    size = np.asarray(sizes)
    smallest = np.where(xs > i0, np.minimum(size[i0], size[i1]), size[i0])
    return edge[None, :] <= 1.0 - 1.5 / smallest


# ------------------------------------------------------------------------------------------------------ running
@dataclass
class PipelineRun:
    renderer: str
    version: str
    extensions: list[str]
    results: dict[str, np.ndarray]  # job id → (P, N, 3)
    errors: dict[str, str]
    seconds: float


def run_jobs(jobs: list[Job], workdir: Path, timeout: float = 120.0) -> PipelineRun:
    """Render every job in one page, in one headless Chromium launch."""
    import time

    binary = chromium_binary()
    if binary is None:
        raise FileNotFoundError("headless Chromium is not installed (apt-get install -y chromium)")
    workdir.mkdir(parents=True, exist_ok=True)
    shutil.copy(HERE / "webgl_runner.html", workdir / "index.html")
    (workdir / "jobs.js").write_text("window.BAKERY_JOBS = " + json.dumps([j.page_entry() for j in jobs]) + ";\n")
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as profile:
        result = subprocess.run([binary, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--dump-dom",
                                 (workdir / "index.html").as_uri()], capture_output=True, text=True, timeout=timeout)
    seconds = time.perf_counter() - start
    match = re.search(r'<pre id="results">(.*?)</pre>', result.stdout, re.S)
    if not match or not match.group(1).strip():
        raise RuntimeError(f"the WebGL2 page produced no results (exit {result.returncode}):\n{result.stderr[-3000:]}")
    page = json.loads(html.unescape(match.group(1)))
    if page.get("error"):
        raise RuntimeError(f"WebGL2 unavailable: {page['error']} (renderer {page.get('renderer')})")
    results, errors = {}, {}
    for job in jobs:
        entry = page["jobs"].get(job.id, {"error": "not run"})
        if "error" in entry:
            errors[job.id] = entry["error"]
            continue
        pixels = np.frombuffer(base64.b64decode(entry["data"]), dtype=np.float32).reshape(job.height, job.width, 4)
        results[job.id] = pixels[..., :3].astype(np.float64)
    return PipelineRun(page["renderer"], page["version"], page["extensions"], results, errors, seconds)


# ------------------------------------------------------------------------------------------------------ glslang
def glslang_binary() -> str | None:
    return shutil.which("glslangValidator")


def validate(source: str, suffix: str, extra: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    """Run glslangValidator on ``source`` (``suffix`` ".frag" for GLSL ES, ".hlsl" with ``extra`` HLSL options)."""
    digest = hashlib.sha256(source.encode()).hexdigest()[:16]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"shader_{digest}{suffix}"
        path.write_text(source)
        return subprocess.run([glslang_binary(), *extra, str(path)], capture_output=True, text=True, timeout=60,
                              cwd=tmp)


def hlsl_test_entry() -> str:
    """An HLSL pixel shader that calls every manifest entry point (and every texture lookup), for compiling."""
    types = {"vec2": "float2", "vec3": "float3", "uvec4": "uint4", "uint": "uint", "bool": "bool", "float": "float",
             "int": "int"}
    lines = ['#include "bakery.hlsl"', "Texture2D<float4> u_table; Texture2DArray<float4> u_faces;",
             "TextureCube<float4> u_cube; SamplerState u_linear_clamp;", "cbuffer Inputs { float4 u_values[64]; uint4 u_words[8]; };",
             "float4 main(float4 position : SV_Position) : SV_Target", "{",
             "    float3 normal = normalize(u_values[0].xyz); float3 view = normalize(u_values[1].xyz);",
             "    float alpha = u_values[2].x; float3 f0 = u_values[2].yzw; float3 e = float3(0.0, 0.0, 0.0);"]
    calls = []
    for index, (name, spec) in enumerate(sorted(manifest()["encodings"].items())):
        for variant_index, entry in enumerate([spec, *spec.get("variants", ())]):
            args = []
            for k, argument in enumerate(entry["arguments"]):
                var = f"v{index}_{variant_index}_{k}"
                if "field" in argument or "setting" in argument:
                    base, size = _array_type(argument.get("type", "float"))
                    hlsl = types[base]
                    init = {"vec3": "u_values[4 + i].xyz", "uint": "u_words[3 + i / 4][i % 4]", "vec2": "u_values[3].xy",
                            "uvec4": "u_words[1]", "bool": "u_words[2].x != 0u", "float": "u_values[3].x",
                            "int": "int(u_words[2].y)"}[base]
                    if size is None:
                        lines.append(f"    {hlsl} {var} = {init.replace('4 + i', '4')};")
                    else:
                        lines.append(f"    {hlsl} {var}[{size}]; for (int i = 0; i < {size}; ++i) {var}[i] = {init};")
                    args.append(var)
                elif "input" in argument:
                    args.append(argument["input"])
                elif "table" in argument:
                    lookup = argument["lookup"]
                    lines.append(f"    {types[argument['type']]} {var} = {lookup}(u_table, dot(normal, view), alpha);")
                    args.append(var)
                elif "chain" in argument:
                    if "level_alphas" in argument:
                        lines += [(f"    float {var}_la[{MAX_HYBRID_LEVELS}]; for (int i = 0; i < {MAX_HYBRID_LEVELS}; ++i) "
                                   f"{var}_la[i] = u_values[8 + i].x;"),
                                  f"    int {var}_i0, {var}_i1; float {var}_f;",
                                  f"    bakery_hybrid_levels(alpha, {var}_la, 5, int(u_words[2].y), {var}_i0, {var}_i1, {var}_f);"]
                    else:
                        lines += [f"    int {var}_i0, {var}_i1; float {var}_f;",
                                  f"    bakery_splitsum_levels(alpha, 6, {var}_i0, {var}_i1, {var}_f);"]
                    lines += [f"    float3 {var}_r = bakery_chain_direction(view, normal);",
                              f"    float3 {var}_c0 = {argument['lookup']}(u_faces, 6 * {var}_i0, {var}_r);",
                              f"    float3 {var}_c1 = bakery_cube_sample_bilinear(u_faces, u_linear_clamp, 6 * {var}_i1, {var}_r)"
                              f" + bakery_cube_sample_seamless(u_cube, u_linear_clamp, {var}_r);"]
                    args += [f"{var}_c0", f"{var}_c1", f"{var}_f"]
            calls.append(f"    e += {entry['entry']}({', '.join(args)});")
    lines += calls
    lines += ["    e.xy += bakery_dfg_sample(u_table, u_linear_clamp, dot(normal, view), alpha);",
              "    return float4(e, 1.0);", "}", ""]
    return "\n".join(lines)


def hlsl_include_dir() -> Path:
    return SHADER_DIR


# ------------------------------------------------------------------------------------------------------ HLSL, executed
# The HLSL of each job (Job.hlsl: the same harness as the GLSL one, over bakery.hlsl) is compiled by glslang's HLSL
# front end to SPIR-V, SPIR-V is turned into GLSL ES 3.00 by spirv-cross, and that runs in the same WebGL2 page.
# spirv-cross does not re-derive anything: it writes out the SPIR-V instructions the HLSL compiled to (glslang has
# already inlined the library into main), so a difference from the GLSL library is a difference of the HLSL.
HLSL_TO_SPIRV = ("-D", "-V", "-S", "frag", "-e", "main")
#: ES 3.00 for WebGL2; the cbuffer as a plain uniform struct (the page sets uniforms, not uniform buffers).
SPIRV_TO_ESSL = ("--es", "--version", "300", "--glsl-emit-ubo-as-plain-uniforms")
#: spirv-cross names each (texture, sampler) pair it combines SPIRV_Cross_Combined<texture><sampler>; Load() pairs the
#: texture with a dummy sampler.
_COMBINED = re.compile(r"^uniform\s+(?:(?:highp|mediump|lowp)\s+)?\w+\s+"
                       r"(SPIRV_Cross_Combined(\w+?)(u_linear_clamp|SPIRV_Cross_DummySampler));$", re.M)
_SETTINGS = re.compile(r"^struct Settings\n\{\n(.*?)\n\};\n.*?^uniform Settings (\w+);$", re.M | re.S)
_MEMBER = re.compile(r"^\s*(?:(?:highp|mediump|lowp)\s+)?(\w+)\s+(\w+)(\[\d+\])?;$", re.M)


def spirv_cross_binary() -> str | None:
    return shutil.which("spirv-cross")


class TranslationError(RuntimeError):
    """glslangValidator or spirv-cross refused a job's HLSL."""


def hlsl_to_essl(source: str, workdir: Path) -> str:
    """``source`` (an HLSL pixel shader, entry ``main``, including bakery.hlsl) → SPIR-V → GLSL ES 3.00."""
    digest = hashlib.sha256(source.encode()).hexdigest()[:16]
    hlsl, spirv, essl = (workdir / f"{digest}{ext}" for ext in (".hlsl", ".spv", ".frag"))
    hlsl.write_text(source)
    steps = ([glslang_binary(), *HLSL_TO_SPIRV, f"-I{SHADER_DIR}", "-o", str(spirv), str(hlsl)],
             [spirv_cross_binary(), str(spirv), *SPIRV_TO_ESSL, "--output", str(essl)])
    for command in steps:
        result = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=workdir)
        if result.returncode != 0:
            raise TranslationError(f"{Path(command[0]).name}: {result.stdout[-2000:]}{result.stderr[-2000:]}")
    text = essl.read_text()
    # spirv-cross declares ES fragment floats mediump by default (and qualifies what SPIR-V does not mark relaxed as
    # highp); the HLSL is float32 throughout (no min16float), so the default is highp as well.
    return re.sub(r"^precision mediump float;$", "precision highp float;", text, flags=re.M)


def _hlsl_job(job: Job, essl: str) -> Job:
    """``job`` with its fragment shader replaced by ``essl`` (hlsl_to_essl of job.hlsl): each texture is bound to
    every combined sampler spirv-cross made of it, each setting to its member of the Settings struct."""
    by_name = {t["uniform"]: t for t in job.textures}
    textures = []
    for combined, texture, _ in _COMBINED.findall(essl):
        if texture not in by_name:
            raise TranslationError(f"{job.id}: spirv-cross sampler {combined} of an unknown texture")
        textures.append({**by_name[texture], "uniform": combined})
    uniforms = []
    if job.uniforms:
        match = _SETTINGS.search(essl)
        if match is None:
            raise TranslationError(f"{job.id}: no Settings struct in the spirv-cross output")
        members = {name: (kind, array) for kind, name, array in _MEMBER.findall(match.group(1))}
        for uniform in job.uniforms:
            kind, _ = members[uniform["name"]]
            runner_type = "uint" if kind == "uint" else uniform["type"]  # an HLSL bool in a cbuffer is a uint
            uniforms.append({**uniform, "name": f"{match.group(2)}.{uniform['name']}", "type": runner_type})
    return Job(id=f"hlsl:{job.id}", encoding=job.encoding, store=job.store, variant=job.variant, fragment=essl,
               width=job.width, height=job.height, reference=job.reference, mask=job.mask, textures=textures,
               uniforms=uniforms, hlsl=job.hlsl)


def hlsl_jobs(jobs: list[Job], workdir: Path) -> tuple[list[Job], dict[str, str]]:
    """The HLSL counterparts of ``jobs`` (ids "hlsl:<id>", the same inputs, textures, settings and reference), and
    the ids of those whose HLSL did not translate → the error. Identical sources are translated once."""
    from concurrent.futures import ThreadPoolExecutor

    workdir.mkdir(parents=True, exist_ok=True)
    sources = sorted({job.hlsl for job in jobs})

    def translate(source: str) -> str | TranslationError:
        try:
            return hlsl_to_essl(source, workdir)
        except TranslationError as error:
            return error

    with ThreadPoolExecutor(max_workers=2) as pool:
        translated = dict(zip(sources, pool.map(translate, sources), strict=True))
    result, errors = [], {}
    for job in jobs:
        essl = translated[job.hlsl]
        try:
            if isinstance(essl, TranslationError):
                raise essl
            result.append(_hlsl_job(job, essl))
        except TranslationError as error:
            errors[f"hlsl:{job.id}"] = str(error)
    return result, errors
