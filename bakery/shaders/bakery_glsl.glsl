// bakery shader library — GLSL ES 3.00 (WebGL2) prelude.
//
// Concatenate, after your own `#version 300 es` line:
//     bakery_glsl.glsl  (this file: precision and the portability macros)
//     bakery_core.glsl  (decoding and evaluation of every stored encoding; no texture access)
//     bakery_textures.glsl (DFG table and split-sum cube-chain lookups)
// GLSL ES has no #include; desktop GLSL can #include these with GL_GOOGLE_include_directive. The same
// bakery_core.glsl compiles as HLSL after bakery.hlsl's prelude, so the two languages share one implementation.
// Conventions, layouts and formulas: schemas/store-v1.md, schemas/store-reflection.md, docs/engine-integration.md.

precision highp float;
precision highp int;
precision highp sampler2D;
precision highp sampler2DArray;
precision highp samplerCube;
precision highp usampler2D;

#define BK_FLOAT2 vec2
#define BK_FLOAT3 vec3
#define BK_FLOAT4 vec4
#define BK_UINT4 uvec4
#define BK_INT2 ivec2
#define BK_LERP(a, b, t) mix(a, b, t)
#define BK_SATURATE(x) clamp(x, 0.0, 1.0)
// Reinterpretation of bits (exact, no conversion).
#define BK_AS_FLOAT(u) uintBitsToFloat(u)
#define BK_AS_INT(u) int(u)
