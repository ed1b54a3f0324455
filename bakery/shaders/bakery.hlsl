// bakery shader library — HLSL (Shader Model 5+; DXC, FXC-compatible syntax, glslang's HLSL front end).
//
//     #include "bakery.hlsl"      // this file: portability macros + bakery_core.glsl + bakery_textures.hlsl
//
// bakery_core.glsl is written once for both languages (through the BK_* macros below), so the HLSL evaluates
// exactly the code that tests/shaders/ runs on a WebGL2 pipeline against bakery's Python API; this HLSL itself is run
// there too (tests/shaders/test_hlsl_execution.py: glslang's HLSL front end → SPIR-V → spirv-cross → GLSL ES 3.00).
// Conventions, layouts and formulas: schemas/store-v1.md, schemas/store-reflection.md, docs/engine-integration.md.

#ifndef BAKERY_HLSL
#define BAKERY_HLSL

#define BK_FLOAT2 float2
#define BK_FLOAT3 float3
#define BK_FLOAT4 float4
#define BK_UINT4 uint4
#define BK_INT2 int2
#define BK_LERP(a, b, t) lerp(a, b, t)
#define BK_SATURATE(x) saturate(x)
// Reinterpretation of bits (exact, no conversion).
#define BK_AS_FLOAT(u) asfloat(u)
#define BK_AS_INT(u) asint(u)

#include "bakery_core.glsl"
#include "bakery_textures.hlsl"

#endif // BAKERY_HLSL
