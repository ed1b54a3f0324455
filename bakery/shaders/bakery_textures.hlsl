// bakery shader library — texture lookups (HLSL). Included by bakery.hlsl after bakery_core.glsl.
//
// Upload (schemas/store-reflection.md):
//   dfg            64×64 DXGI_FORMAT_R32G32_FLOAT (or R16G16_FLOAT), width = n·v axis, height = α axis (row i of
//                  the stored (64, 64, 2) array is texture row i), clamp addressing, declared Texture2D<float4> (the
//                  lookups' parameter type; DXC need not convert a Texture2D<float2> to it).
//                  fresnel_tail: the same with R32_FLOAT.
//   splitsum       every level i as its own Texture2DArray of N_i × N_i with the 6 faces (+X, −X, +Y, −Y, +Z, −Z)
//                  as slices 6·probe + face, rows top-down as stored, R16G16B16A16_FLOAT, clamp addressing; or a
//                  TextureCube per level (seamless; an acceptable difference at face edges).
// "Fetch" functions reproduce bakery's reference exactly (bilinear weights in float32, Load); "Sample" functions use
// the filtering units (pass a linear, clamp sampler).

float4 bakery_table_fetch_bilinear(Texture2D<float4> table, float n_dot_v, float alpha)
{
    uint width, height;
    table.GetDimensions(width, height);
    int2 t0, t1;
    float2 f;
    bakery_table_bilinear(n_dot_v, alpha, int(width), t0, t1, f);
    float4 top = lerp(table.Load(int3(t0.x, t0.y, 0)), table.Load(int3(t1.x, t0.y, 0)), f.x);
    float4 bottom = lerp(table.Load(int3(t0.x, t1.y, 0)), table.Load(int3(t1.x, t1.y, 0)), f.x);
    return lerp(top, bottom, f.y);
}

float2 bakery_dfg_fetch(Texture2D<float4> dfg, float n_dot_v, float alpha)
{
    return bakery_table_fetch_bilinear(dfg, n_dot_v, alpha).xy;
}

float2 bakery_dfg_sample(Texture2D<float4> dfg, SamplerState linear_clamp, float n_dot_v, float alpha)
{
    return dfg.SampleLevel(linear_clamp, float2(saturate(n_dot_v), alpha), 0.0).xy;
}

float bakery_fresnel_tail_fetch(Texture2D<float4> fresnel_tail, float n_dot_v, float alpha)
{
    return bakery_table_fetch_bilinear(fresnel_tail, n_dot_v, alpha).x;
}

float3 bakery_cube_fetch_bilinear(Texture2DArray<float4> faces, int first_layer, float3 d)
{
    int face;
    float2 uv;
    bakery_cube_face_uv(d, face, uv);
    uint width, height, layers;
    faces.GetDimensions(width, height, layers);
    int2 t0, t1;
    float2 f;
    bakery_cube_face_bilinear(uv, int(width), t0, t1, f);
    int layer = first_layer + face;
    float3 top = lerp(faces.Load(int4(t0.x, t0.y, layer, 0)).rgb, faces.Load(int4(t1.x, t0.y, layer, 0)).rgb, f.x);
    float3 bottom = lerp(faces.Load(int4(t0.x, t1.y, layer, 0)).rgb, faces.Load(int4(t1.x, t1.y, layer, 0)).rgb, f.x);
    return lerp(top, bottom, f.y);
}

float3 bakery_cube_sample_bilinear(Texture2DArray<float4> faces, SamplerState linear_clamp, int first_layer, float3 d)
{
    int face;
    float2 uv;
    bakery_cube_face_uv(d, face, uv);
    return faces.SampleLevel(linear_clamp, float3(0.5 * uv + float2(0.5, 0.5), float(first_layer + face)), 0.0).rgb;
}

float3 bakery_cube_sample_seamless(TextureCube<float4> level, SamplerState linear_clamp, float3 d)
{
    return level.SampleLevel(linear_clamp, d, 0.0).rgb;
}
