// bakery shader library — texture lookups (GLSL ES 3.00). Include after bakery_glsl.glsl and bakery_core.glsl.
//
// Upload (schemas/store-reflection.md):
//   dfg            64×64 RG32F (or RG16F) texture, width = n·v axis, height = α axis (row i of the stored (64, 64, 2)
//                  array is texture row i), clamp-to-edge. fresnel_tail: the same with R32F.
//   splitsum       every level i as its own texture: a TEXTURE_2D_ARRAY of N_i × N_i with the 6 faces (+X, −X, +Y,
//                  −Y, +Z, −Z) as layers 6·probe + face, rows top-down as stored, RGBA16F (the store is float16),
//                  clamp-to-edge. Or a cube texture per level (seamless; an acceptable difference at face edges).
// "fetch" functions reproduce bakery's reference exactly (bilinear weights in float32, texelFetch); "sample"
// functions use the GPU's filtering units (whose weights have a few fractional bits only: tests/shaders states
// the tolerance both are held to).

// --------------------------------------------------------------------------------------------- dfg / fresnel_tail
BK_FLOAT4 bakery_table_fetch_bilinear(sampler2D table, float n_dot_v, float alpha)
{
    BK_INT2 t0, t1;
    BK_FLOAT2 f;
    bakery_table_bilinear(n_dot_v, alpha, textureSize(table, 0).x, t0, t1, f);
    BK_FLOAT4 top = BK_LERP(texelFetch(table, BK_INT2(t0.x, t0.y), 0), texelFetch(table, BK_INT2(t1.x, t0.y), 0), f.x);
    BK_FLOAT4 bottom = BK_LERP(texelFetch(table, BK_INT2(t0.x, t1.y), 0), texelFetch(table, BK_INT2(t1.x, t1.y), 0), f.x);
    return BK_LERP(top, bottom, f.y);
}

// (A, B) of the `dfg` table at (n·v, α), exact bilinear.
BK_FLOAT2 bakery_dfg_fetch(sampler2D dfg, float n_dot_v, float alpha)
{
    return bakery_table_fetch_bilinear(dfg, n_dot_v, alpha).xy;
}

// (A, B) with the GPU's bilinear sampler (LINEAR, CLAMP_TO_EDGE): u = n·v, v = α.
BK_FLOAT2 bakery_dfg_sample(sampler2D dfg, float n_dot_v, float alpha)
{
    return textureLod(dfg, BK_FLOAT2(BK_SATURATE(n_dot_v), alpha), 0.0).xy;
}

// τ of the `fresnel_tail` table (shexp with albedo_normalized = false), exact bilinear.
float bakery_fresnel_tail_fetch(sampler2D fresnel_tail, float n_dot_v, float alpha)
{
    return bakery_table_fetch_bilinear(fresnel_tail, n_dot_v, alpha).x;
}

// --------------------------------------------------------------------------------------------- split-sum levels
// Level radiance at direction d from a face array (layers first_layer + face), exact bilinear within the face.
BK_FLOAT3 bakery_cube_fetch_bilinear(sampler2DArray faces, int first_layer, BK_FLOAT3 d)
{
    int face;
    BK_FLOAT2 uv;
    bakery_cube_face_uv(d, face, uv);
    BK_INT2 t0, t1;
    BK_FLOAT2 f;
    bakery_cube_face_bilinear(uv, textureSize(faces, 0).x, t0, t1, f);
    int layer = first_layer + face;
    BK_FLOAT3 top = BK_LERP(texelFetch(faces, ivec3(t0.x, t0.y, layer), 0).rgb,
                            texelFetch(faces, ivec3(t1.x, t0.y, layer), 0).rgb, f.x);
    BK_FLOAT3 bottom = BK_LERP(texelFetch(faces, ivec3(t0.x, t1.y, layer), 0).rgb,
                               texelFetch(faces, ivec3(t1.x, t1.y, layer), 0).rgb, f.x);
    return BK_LERP(top, bottom, f.y);
}

// The same with the GPU's bilinear sampler (LINEAR, CLAMP_TO_EDGE; filtering stays within the face's layer).
BK_FLOAT3 bakery_cube_sample_bilinear(sampler2DArray faces, int first_layer, BK_FLOAT3 d)
{
    int face;
    BK_FLOAT2 uv;
    bakery_cube_face_uv(d, face, uv);
    return textureLod(faces, vec3(0.5 * uv + BK_FLOAT2(0.5, 0.5), float(first_layer + face)), 0.0).rgb;
}

// A level uploaded as a cube texture: hardware face selection and seamless filtering (WebGL2 / GLES 3 cube maps
// are always seamless), equal to the face-array lookups away from face edges.
BK_FLOAT3 bakery_cube_sample_seamless(samplerCube level, BK_FLOAT3 d)
{
    return textureLod(level, d, 0.0).rgb;
}
