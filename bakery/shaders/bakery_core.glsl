// bakery shader library — portable core: decode and evaluate every stored encoding.
//
// Written once for GLSL ES 3.00 and HLSL: include it after a prelude that defines the BK_* macros
// (bakery_glsl.glsl for GLSL, bakery.hlsl for HLSL). No texture access here: the table and cube-chain lookups are
// in bakery_textures.glsl / bakery_textures.hlsl, and every function below takes already-fetched values.
// Encoding name -> entry point: manifest.json. tests/shaders/ renders these functions on a WebGL2 pipeline and
// compares them with bakery's Python API (ProbeStore.evaluate_irradiance / evaluate_reflection).
//
// Conventions (schemas/store-v1.md "Conventions"): right-handed, +Y up; real orthonormal SH with the
// Condon–Shortley phase, Y1,-1 = -c·y, Y1,0 = c·z, Y1,1 = -c·x, index k = l(l+1)+m; stored SH are of RADIANCE;
// irradiance E(n) = ∫ L max(0, n·ω) dω (not divided by π); linear Rec.709 RGB; roughness is GGX α.
// Directions passed in are unit vectors in the bake frame; v points towards the viewer.
//
// References
//   [ZH3]   Roughton, Sloan, Silvennoinen, Iwanicki, Shirley, "ZH3: Quadratic Zonal Harmonics", Proc. ACM
//           Comput. Graph. Interact. Tech. 7(1), 2024 (seed 001).
//   [SHExp] Silvennoinen, Sloan, Iwanicki, Nowrouzezahrai, "Spherical Harmonic Exponentials for Efficient
//           Glossy Reflections", HPG 2025 (seed 000).
//   [RH01]  Ramamoorthi, Hanrahan, "An Efficient Representation for Irradiance Environment Maps", 2001.
//   [Kar13] Karis, "Real Shading in Unreal Engine 4", SIGGRAPH 2013 course notes (split sum).

#ifndef BAKERY_CORE
#define BAKERY_CORE

#define BAKERY_PI 3.14159265358979
// Cosine-lobe band factors A_l of the clamped cosine ([RH01] Eq. 8; store-v1.md "sh_content").
#define BAKERY_A0 3.14159265358979
#define BAKERY_A1 2.09439510239320
#define BAKERY_A2 0.785398163397448
// Rec.709 luminance weights (store-v1.md "colour"; [ZH3] Listing 1 "lumCoeffs").
#define BAKERY_LUMINANCE BK_FLOAT3(0.2126, 0.7152, 0.0722)
// Paper curve of the hallucinated zonal L2 term, (c2, c1) of f2^0 = (c2 p² + c1 p) f0 ([ZH3] Eq. 21).
#define BAKERY_ZH3_PAPER_CURVE BK_FLOAT2(0.6, 0.08)
// `zh3_hallucinated_solved` zonal_scale codes per unit scale (store-v1.md; 64 = Listing 1 as published).
#define BAKERY_ZONAL_SCALE_UNIT 64.0

// ============================================================================================ SH basis
// Real orthonormal SH in bakery's convention, as polynomials of a unit direction ([ZH3] Eq. 4–5 for l ≤ 2;
// bands 3–4: the standard Cartesian forms times (-1)^m, Condon–Shortley phase). Index k = l(l+1) + m.
void bakery_sh_basis2(BK_FLOAT3 d, out float Y[9])
{
    float x = d.x, y = d.y, z = d.z;
    Y[0] = 0.282094791773878;                       // Y00 = 1/(2√π)
    Y[1] = -0.488602511902920 * y;                  // Y1,-1 = -√(3/4π) y   ([ZH3] Eq. 4)
    Y[2] = 0.488602511902920 * z;                   // Y1,0
    Y[3] = -0.488602511902920 * x;                  // Y1,1
    Y[4] = 1.092548430592079 * x * y;               // Y2,-2 = √(15/4π) xy  ([ZH3] Eq. 5)
    Y[5] = -1.092548430592079 * y * z;              // Y2,-1
    Y[6] = 0.315391565252520 * (3.0 * z * z - 1.0); // Y2,0 = √(5/16π)(3z² - 1)
    Y[7] = -1.092548430592079 * x * z;              // Y2,1
    Y[8] = 0.546274215296040 * (x * x - y * y);     // Y2,2 = √(15/16π)(x² - y²)
}

void bakery_sh_basis4(BK_FLOAT3 d, out float Y[25])
{
    float x = d.x, y = d.y, z = d.z;
    float x2 = x * x, y2 = y * y, z2 = z * z;
    Y[0] = 0.282094791773878;
    Y[1] = -0.488602511902920 * y;
    Y[2] = 0.488602511902920 * z;
    Y[3] = -0.488602511902920 * x;
    Y[4] = 1.092548430592079 * x * y;
    Y[5] = -1.092548430592079 * y * z;
    Y[6] = 0.315391565252520 * (3.0 * z2 - 1.0);
    Y[7] = -1.092548430592079 * x * z;
    Y[8] = 0.546274215296040 * (x2 - y2);
    Y[9] = -0.590043589926644 * y * (3.0 * x2 - y2);
    Y[10] = 2.890611442640554 * x * y * z;
    Y[11] = -0.457045799464466 * y * (5.0 * z2 - 1.0);
    Y[12] = 0.373176332590115 * z * (5.0 * z2 - 3.0);
    Y[13] = -0.457045799464466 * x * (5.0 * z2 - 1.0);
    Y[14] = 1.445305721320277 * z * (x2 - y2);
    Y[15] = -0.590043589926644 * x * (x2 - 3.0 * y2);
    Y[16] = 2.503342941796705 * x * y * (x2 - y2);
    Y[17] = -1.770130769779930 * y * z * (3.0 * x2 - y2);
    Y[18] = 0.946174695757560 * x * y * (7.0 * z2 - 1.0);
    Y[19] = -0.669046543557289 * y * z * (7.0 * z2 - 3.0);
    Y[20] = 0.105785546915204 * (35.0 * z2 * z2 - 30.0 * z2 + 3.0);
    Y[21] = -0.669046543557289 * x * z * (7.0 * z2 - 3.0);
    Y[22] = 0.473087347878780 * (x2 - y2) * (7.0 * z2 - 1.0);
    Y[23] = -1.770130769779930 * x * z * (x2 - 3.0 * y2);
    Y[24] = 0.625835735449176 * (x2 * (x2 - 3.0 * y2) - y2 * (3.0 * x2 - y2));
}

// ============================================================================================ SH irradiance
// sh2, sh3 (store-v1.md): E(n) = Σ_l A_l Σ_m f_lm Y_lm(n), radiance SH f, A = (π, 2π/3, π/4).

// `sh2`: radiance_sh (4 RGB). [ZH3] Listing 1's SHLinearEvaluateIrradiance.
BK_FLOAT3 bakery_sh2_irradiance(BK_FLOAT3 sh[4], BK_FLOAT3 n)
{
    float Y[9];
    bakery_sh_basis2(n, Y);
    return BAKERY_A0 * Y[0] * sh[0] + BAKERY_A1 * (Y[1] * sh[1] + Y[2] * sh[2] + Y[3] * sh[3]);
}

// `sh3`: radiance_sh (9 RGB).
BK_FLOAT3 bakery_sh3_irradiance(BK_FLOAT3 sh[9], BK_FLOAT3 n)
{
    float Y[9];
    bakery_sh_basis2(n, Y);
    BK_FLOAT3 e = BAKERY_A0 * Y[0] * sh[0] + BAKERY_A1 * (Y[1] * sh[1] + Y[2] * sh[2] + Y[3] * sh[3]);
    return e + BAKERY_A2 * (Y[4] * sh[4] + Y[5] * sh[5] + Y[6] * sh[6] + Y[7] * sh[7] + Y[8] * sh[8]);
}

// ============================================================================================ ZH3
// Linear band of channel c as a Cartesian vector v_c = (-f1,1, -f1,-1, f1,0) (store-v1.md; [ZH3] Sec. 2.2, Eq. 32).
BK_FLOAT3 bakery_linear_band_vector(BK_FLOAT3 sh[4], int c)
{
    return BK_FLOAT3(-sh[3][c], -sh[1][c], sh[2][c]);
}

// Shared zonal axis a = normalize(Σ_c w_c v_c), the optimal linear direction of the luminance SH
// ([ZH3] Sec. 3.2, Eq. 29–32; Listing 1 "zonalAxis"); (0, 0, 1) when that vector vanishes (|·| ≤ 1e-30).
// The vector is scaled by its largest component first so that tiny linear bands do not underflow in float32.
BK_FLOAT3 bakery_zh3_luminance_axis(BK_FLOAT3 sh[4])
{
    BK_FLOAT3 u = BK_FLOAT3(-dot(sh[3], BAKERY_LUMINANCE), -dot(sh[1], BAKERY_LUMINANCE), dot(sh[2], BAKERY_LUMINANCE));
    float m = max(abs(u.x), max(abs(u.y), abs(u.z)));
    if (!(m > 0.0))
        return BK_FLOAT3(0.0, 0.0, 1.0);
    BK_FLOAT3 s = u / m;
    float len = length(s);
    if (!(m * len > 1e-30))
        return BK_FLOAT3(0.0, 0.0, 1.0);
    return s / len;
}

// Irradiance of the zonal L2 radiance coefficient f2^0 about axis a: (π/4) f2^0 Y20(a·n), Y20(t) = √(5/16π)(3t² − 1)
// ([ZH3] Eq. 9–10 for the coefficient, Listing 1 "zhDir" and the 1/4 (here π/4, unnormalised cosine) factor).
BK_FLOAT3 bakery_zonal_l2_irradiance(BK_FLOAT3 zonal_l2, BK_FLOAT3 axis, BK_FLOAT3 n)
{
    float t = dot(axis, n);
    return (BAKERY_A2 * 0.315391565252520 * (3.0 * t * t - 1.0)) * zonal_l2;
}

// `zh3`, `zh3_solved`, `zh3_deringed`: radiance_sh (4 RGB) + zonal_l2 (RGB) on the luminance axis of the stored
// linear band (store-v1.md). E(n) = sh2 term + (π/4) zonal_l2 · Y20(a·n). (zh3_deringed's E ≥ 0 for every n is a
// property of the stored values: nothing changes at evaluation.)
BK_FLOAT3 bakery_zh3_irradiance(BK_FLOAT3 sh[4], BK_FLOAT3 zonal_l2, BK_FLOAT3 n)
{
    return bakery_sh2_irradiance(sh, n) + bakery_zonal_l2_irradiance(zonal_l2, bakery_zh3_luminance_axis(sh), n);
}

// Hallucinated zonal L2 coefficient ([ZH3] Sec. 3.4.3–3.4.4, Eq. 21, Listing 1):
// p_c = |v_c · a| / f0_c (0 if f0_c ≤ 0), f2^0_c = (c2 p_c² + c1 p_c) f0_c with curve = (c2, c1).
BK_FLOAT3 bakery_zh3_hallucinate_zonal_l2(BK_FLOAT3 sh[4], BK_FLOAT3 axis, BK_FLOAT2 curve)
{
    BK_FLOAT3 zonal = BK_FLOAT3(0.0, 0.0, 0.0);
    for (int c = 0; c < 3; ++c)
    {
        float f0 = sh[0][c];
        float p = f0 > 0.0 ? abs(dot(bakery_linear_band_vector(sh, c), axis)) / f0 : 0.0;  // Listing 1 "ratio"
        zonal[c] = (curve.x * p * p + curve.y * p) * f0;                                     // Eq. 21
    }
    return zonal;
}

// `zh3_hallucinated` (and `zh3_hallucinated_solved` at zonal_scale 64): radiance_sh (4 RGB) only; curve = the
// stored settings' `curve` ((0.6, 0.08) for "paper", BAKERY_ZH3_PAPER_CURVE). With the paper's curve this is [ZH3]
// Listing 1 unchanged.
BK_FLOAT3 bakery_zh3_hallucinated_irradiance(BK_FLOAT3 sh[4], BK_FLOAT2 curve, BK_FLOAT3 n)
{
    BK_FLOAT3 axis = bakery_zh3_luminance_axis(sh);
    return bakery_sh2_irradiance(sh, n) + bakery_zonal_l2_irradiance(bakery_zh3_hallucinate_zonal_l2(sh, axis, curve), axis, n);
}

// `zh3_hallucinated_solved` (1.2.0): radiance_sh (4 RGB) + the per-probe byte `zonal_scale`: Listing 1 with its
// zonal term times zonal_scale / 64 (64: Listing 1 as published; 0: plain `sh2`, the probes where nothing beats it).
// A 1.1.0 store's 0/1 flag `hallucinate` is passed as zonal_scale = 64 × flag.
BK_FLOAT3 bakery_zh3_hallucinated_solved_irradiance(BK_FLOAT3 sh[4], BK_FLOAT2 curve, int zonal_scale, BK_FLOAT3 n)
{
    BK_FLOAT3 axis = bakery_zh3_luminance_axis(sh);
    BK_FLOAT3 zonal = (float(zonal_scale) / BAKERY_ZONAL_SCALE_UNIT) * bakery_zh3_hallucinate_zonal_l2(sh, axis, curve);
    return bakery_sh2_irradiance(sh, n) + bakery_zonal_l2_irradiance(zonal, axis, n);
}

// ============================================================================================ quantized layouts
// [ZH3] App. A.1 (store-v1.md "Quantized layouts"). The packed bytes are uploaded as little-endian uint32 words:
// byte b is bits 8·(b mod 4) .. 8·(b mod 4)+7 of word b / 4 (a uint4 for the 16-byte layout, uint[7] for 28).

// Unsigned small float with a 5-bit exponent (bias 15) and `mantissa_bits` mantissa bits, i.e. float16's layout
// without the sign and with truncated mantissa: value = float16 bits (code << (10 − mantissa_bits)). Exact: the
// float32 is assembled bit by bit. Exponent 31 (float16's Inf/NaN) is never written (writers clamp to the largest
// finite value); a store holding one is corrupt and bakery's reader refuses it (schemas/store-v1.md).
float bakery_small_float(uint code, uint mantissa_bits)
{
    uint exponent = code >> mantissa_bits;
    uint mantissa = code & ((1u << mantissa_bits) - 1u);
    if (exponent == 0u)  // denormal: mantissa · 2^(−14 − mantissa_bits), an exact power-of-two scale
        return float(mantissa) * BK_AS_FLOAT((113u - mantissa_bits) << 23);
    return BK_AS_FLOAT(((exponent + 112u) << 23) | (mantissa << (23u - mantissa_bits)));
}

// DXGI_FORMAT_R11G11B10_FLOAT: R = bits 0–10, G = bits 11–21, B = bits 22–31 (6, 6, 5 mantissa bits).
BK_FLOAT3 bakery_r11g11b10f(uint word)
{
    return BK_FLOAT3(bakery_small_float(word & 0x7FFu, 6u), bakery_small_float((word >> 11) & 0x7FFu, 6u),
                     bakery_small_float(word >> 22, 5u));
}

// int8 SNORM code in bits shift..shift+7 of a word, sign-extended.
int bakery_int8(uint word, uint shift)
{
    return BK_AS_INT(word << (24u - shift)) >> 24;
}

// Ratio x of an int8 code q: s = max(q/127, −1) (the GPU SNORM8 rule: −128 reads as −127, never written),
// t = s (or sign(s)·s² with sqrt companding), x = t·hi if t ≥ 0 else t·|lo|
// ([ZH3] App. A.1: bound-remapped SNORM8, "square root to encode the magnitude").
float bakery_decode_ratio(int q, float lo, float hi, bool sqrt_companding)
{
    float s = max(float(q) / 127.0, -1.0);
    float t = sqrt_companding ? s * abs(s) : s;
    return t * (t >= 0.0 ? hi : -lo);
}

// Ratio bounds of a non-negative function's radiance SH relative to f0 ([ZH3] App. A): band 1 ±√3; band 2, m ≠ 0:
// ±√15/2; band 2 zonal (f2,0, or the ZH3 zonal_l2 in its own frame): [−√5/2, √5].
#define BAKERY_BOUND_L1 1.732050807568877
#define BAKERY_BOUND_L2 1.936491673103709
#define BAKERY_BOUND_ZONAL_LO -1.118033988749895
#define BAKERY_BOUND_ZONAL_HI 2.236067977499790

// `zh3_quantized` (16 bytes): word 0 R11G11B10F f0; bytes 4–6 f1,−1 RGB, 7–9 f1,0, 10–12 f1,1, 13–15 zonal L2;
// coefficient = ratio · f0 of its channel.
void bakery_zh3_quantized_unpack(BK_UINT4 words, bool sqrt_companding, out BK_FLOAT3 sh[4], out BK_FLOAT3 zonal_l2)
{
    BK_FLOAT3 f0 = bakery_r11g11b10f(words.x);
    sh[0] = f0;
    BK_FLOAT3 coefficient[4];
    for (int j = 0; j < 4; ++j)
    {
        float lo = j < 3 ? -BAKERY_BOUND_L1 : BAKERY_BOUND_ZONAL_LO;
        float hi = j < 3 ? BAKERY_BOUND_L1 : BAKERY_BOUND_ZONAL_HI;
        for (int c = 0; c < 3; ++c)
        {
            int b = 4 + 3 * j + c;
            int q = bakery_int8(words[b / 4], uint(8 * (b % 4)));
            coefficient[j][c] = bakery_decode_ratio(q, lo, hi, sqrt_companding) * f0[c];
        }
    }
    sh[1] = coefficient[0];
    sh[2] = coefficient[1];
    sh[3] = coefficient[2];
    zonal_l2 = coefficient[3];
}

// `zh3_quantized`: decode, then evaluate as `zh3` (the axis is computed from the decoded linear band). The decoded
// values are the probe: with settings `dering` the writer chose codes whose decoded irradiance is ≥ 0 everywhere,
// so a reader must not re-dering, window or clamp them (schemas/store-v1.md "What readers do after decoding").
BK_FLOAT3 bakery_zh3_quantized_irradiance(BK_UINT4 words, bool sqrt_companding, BK_FLOAT3 n)
{
    BK_FLOAT3 sh[4];
    BK_FLOAT3 zonal_l2;
    bakery_zh3_quantized_unpack(words, sqrt_companding, sh, zonal_l2);
    return bakery_zh3_irradiance(sh, zonal_l2, n);
}

// `sh3_quantized` (28 bytes): word 0 R11G11B10F f0; bytes 4–27 coefficients k = 1..8, 3 bytes (RGB) each.
void bakery_sh3_quantized_unpack(uint words[7], bool sqrt_companding, out BK_FLOAT3 sh[9])
{
    BK_FLOAT3 f0 = bakery_r11g11b10f(words[0]);
    sh[0] = f0;
    for (int k = 1; k < 9; ++k)
    {
        float lo = k < 4 ? -BAKERY_BOUND_L1 : (k == 6 ? BAKERY_BOUND_ZONAL_LO : -BAKERY_BOUND_L2);
        float hi = k < 4 ? BAKERY_BOUND_L1 : (k == 6 ? BAKERY_BOUND_ZONAL_HI : BAKERY_BOUND_L2);
        BK_FLOAT3 value;
        for (int c = 0; c < 3; ++c)
        {
            int b = 4 + 3 * (k - 1) + c;
            value[c] = bakery_decode_ratio(bakery_int8(words[b / 4], uint(8 * (b % 4))), lo, hi, sqrt_companding) * f0[c];
        }
        sh[k] = value;
    }
}

// `sh3_quantized`: decode, then evaluate as `sh3`.
BK_FLOAT3 bakery_sh3_quantized_irradiance(uint words[7], bool sqrt_companding, BK_FLOAT3 n)
{
    BK_FLOAT3 sh[9];
    bakery_sh3_quantized_unpack(words, sqrt_companding, sh);
    return bakery_sh3_irradiance(sh, n);
}

// ============================================================================================ reflection: inputs
// store-reflection.md "Evaluation inputs" (bakery.reflection.validation). α MUST be GGX α in [0, 1]: bakery's API
// rejects anything else; a shader cannot raise, so callers pass saturate(α) (every function below assumes it).

// Height above the horizon of a clamped view (HORIZON_EPSILON).
#define BAKERY_HORIZON_EPSILON 1e-6

// Views below or on the horizon (n·v ≤ 0) are clamped to it, as engines clamp n·v to 0: v turned onto the tangent plane,
// a hair (10⁻⁶) above it, t = v − (n·v)n or normalize(e × n) (e = +X, or +Z where |n_x| > 0.9) when |t| < 10⁻⁹.
// Then r = 2(n·v)n − v lies on the horizon and h_r = normalize(n + r) is defined for every input. Views with
// n·v > 0 are returned unchanged (so the clamp is idempotent). Every reflection entry point applies it.
// float32: t is orthogonalised twice (the same t in exact arithmetic). For v near −n one pass leaves a component
// along n of ~10⁻⁷/|t| from cancellation, which swamps the 10⁻⁶ lift (|t| = 0.045 at n·v = −0.999) and can put the
// clamped view below the horizon, where the lights' visibility is 0.
// t is taken from w = v + n (t = w − (n·w)n up to a multiple of n that the second pass removes): near v = −n the
// sum is exact (Sterbenz), so t keeps its direction to float32 precision however small it is, and v = −n (bit for
// bit) gives t = 0 and the fixed tangent, as the float64 reference does. v − (n·v)n instead leaves rounding noise
// of ~10⁻⁷ in every component, a tangent in an arbitrary direction (above the 10⁻⁹ test) at v = −n.
BK_FLOAT3 bakery_clamp_view_to_horizon(BK_FLOAT3 v, BK_FLOAT3 n)
{
    float nv = dot(n, v);
    if (!(nv <= 0.0))
        return v;
    BK_FLOAT3 w = v + n;
    BK_FLOAT3 t = w - dot(n, w) * n;
    t -= dot(t, n) * n;
    float len = length(t);
    if (len < 1e-9)
        t = normalize(cross(abs(n.x) > 0.9 ? BK_FLOAT3(0.0, 0.0, 1.0) : BK_FLOAT3(1.0, 0.0, 0.0), n));
    else
        t = t / len;
    BK_FLOAT3 s = t + BAKERY_HORIZON_EPSILON * n;
    return s / length(s);
}

// Mirror direction r = 2(n·v)n − v ([SHExp] Eq. 10) of a view (not clamped here).
BK_FLOAT3 bakery_reflect(BK_FLOAT3 v, BK_FLOAT3 n)
{
    return 2.0 * dot(n, v) * n - v;
}

// The direction a cube chain (`splitsum`, the `shexp_hybrid` levels) is looked up at: r of the clamped view.
BK_FLOAT3 bakery_chain_direction(BK_FLOAT3 v, BK_FLOAT3 n)
{
    return bakery_reflect(bakery_clamp_view_to_horizon(v, n), n);
}

// ============================================================================================ reflection: BRDF
// Cook–Torrance with GGX D, height-correlated Smith V = G2 / (4 (n·v)(n·l)) and Schlick F ([SHExp] Eq. 2–4),
// roughness GGX α (schemas/store-reflection.md "BRDF").

// GGX D = α² / (π ((n·h)²(α² − 1) + 1)²) ([SHExp] Eq. 2), with 1 − (n·h)² passed separately (|n × h|²) so that
// the denominator (n·h)² α² + (1 − (n·h)²) has no cancellation near the peak in float32.
float bakery_ggx_d(float n_dot_h, float one_minus_n_dot_h2, float a2)
{
    if (!(n_dot_h > 0.0))
        return 0.0;
    float d = n_dot_h * n_dot_h * a2 + one_minus_n_dot_h2;
    return a2 / (BAKERY_PI * d * d);
}

// Height-correlated Smith visibility V ([SHExp] Eq. 3; closed form of Lagarde & de Rousiers 2014).
float bakery_smith_visibility(float n_dot_v, float n_dot_l, float a2)
{
    if (!(n_dot_v > 0.0) || !(n_dot_l > 0.0))
        return 0.0;
    float gv = n_dot_l * sqrt(n_dot_v * n_dot_v * (1.0 - a2) + a2);
    float gl = n_dot_v * sqrt(n_dot_l * n_dot_l * (1.0 - a2) + a2);
    return 0.5 / max(gv + gl, 1e-12);
}

// Split-sum specular albedo F0·A + B of a DFG table value AB = (A, B) ([Kar13]; store-reflection.md "dfg").
BK_FLOAT3 bakery_dfg_albedo(BK_FLOAT3 F0, BK_FLOAT2 AB)
{
    return F0 * AB.x + AB.y;
}

// Bilinear clamp-to-edge lookup of a size×size table with rows α_i = (i + ½)/size and columns
// (n·v)_j = (j + ½)/size (store-reflection.md "dfg"): the four texels are (x0|x1, y0|y1), weights f.
// Equivalent to a GPU bilinear sampler at u = n·v, v = α; bakery_textures.* fetch with it (exact weights).
void bakery_table_bilinear(float n_dot_v, float alpha, int size, out BK_INT2 t0, out BK_INT2 t1, out BK_FLOAT2 f)
{
    float last = float(size - 1);
    float x = clamp(BK_SATURATE(n_dot_v) * float(size) - 0.5, 0.0, last);
    float y = clamp(alpha * float(size) - 0.5, 0.0, last);
    t0 = BK_INT2(min(int(floor(x)), size - 1), min(int(floor(y)), size - 1));
    t1 = BK_INT2(min(t0.x + 1, size - 1), min(t0.y + 1, size - 1));
    f = BK_FLOAT2(x - float(t0.x), y - float(t0.y));
}

// ============================================================================================ SH exponentials
// `shexp` (store-reflection.md): p = log-space SH of P(r), bands 0..p_band, index l(l+1)+m; q = log-space SH of
// Q(h_r), bands 1..q_band without DC, index l(l+1)+m−1. Defaults p_band = 4, q_band = 2 (25 + 8 RGB). Other bands
// up to 4: define these before including the core.
#ifndef BAKERY_SHEXP_P_COUNT
#define BAKERY_SHEXP_P_COUNT 25
#endif
#ifndef BAKERY_SHEXP_Q_COUNT
#define BAKERY_SHEXP_Q_COUNT 8
#endif
#ifndef BAKERY_SHEXP_MAX_LIGHTS
#define BAKERY_SHEXP_MAX_LIGHTS 8
#endif

// P·Q = exp(⟨vMF(1/α) ⊙ Y(r), p⟩ + ⟨vMF(1/α) ⊙ Y(h_r), q⟩) ([SHExp] Eq. 9–11), r = 2(n·v)n − v and
// h_r = normalize(n + r) (Eq. 10), vMF band factor g_l(α) = exp(−l(l+1)α/2) (Eq. 12), at the α given (no clamp:
// bakery_shexp_pq_clamped is what the encodings evaluate). v must already be clamped to the horizon.
BK_FLOAT3 bakery_shexp_pq(BK_FLOAT3 p[BAKERY_SHEXP_P_COUNT], BK_FLOAT3 q[BAKERY_SHEXP_Q_COUNT], BK_FLOAT3 v,
                          BK_FLOAT3 n, float alpha)
{
    BK_FLOAT3 r = bakery_reflect(v, n);                        // Eq. 10
    BK_FLOAT3 hr = n + r;
    hr = hr / max(length(hr), 1e-12);
    float Yr[25];
    float Yh[25];
    bakery_sh_basis4(r, Yr);
    bakery_sh_basis4(hr, Yh);
    BK_FLOAT3 s = BK_FLOAT3(0.0, 0.0, 0.0);
    int k = 0;
    for (int l = 0; l <= 4; ++l)
    {
        float g = exp(-0.5 * float(l * (l + 1)) * alpha);     // Eq. 12
        for (int m = 0; m < 2 * l + 1; ++m)
        {
            if (k < BAKERY_SHEXP_P_COUNT)
                s += (g * Yr[k]) * p[k];                      // Eq. 11, P factor
            if (k >= 1 && k - 1 < BAKERY_SHEXP_Q_COUNT)
                s += (g * Yh[k]) * q[k - 1];                  // Eq. 11, Q factor (no DC, Sec. 4.1)
            k += 1;
        }
    }
    return exp(s);
}

// P·Q at α clamped into the probe's stored `alpha_range` = (α_lo, α_hi), the range its coefficients were fitted over
// (store-reflection.md `shexp` "clamp rule"; bakery.reflection.shexp.clamped_pq): the model is never evaluated
// outside it (below α_lo the vMF factors let the log-space peak grow without bound, issue 12). Stores before
// shexp 1.2.0 have no `alpha_range`: pass the settings' (alpha_min, alpha_max).
BK_FLOAT3 bakery_shexp_pq_clamped(BK_FLOAT3 p[BAKERY_SHEXP_P_COUNT], BK_FLOAT3 q[BAKERY_SHEXP_Q_COUNT],
                                  BK_FLOAT2 alpha_range, BK_FLOAT3 v, BK_FLOAT3 n, float alpha)
{
    return bakery_shexp_pq(p, q, v, n, clamp(alpha, alpha_range.x, alpha_range.y));
}

// `shexp` with settings albedo_normalized = true (default): v clamped to the horizon, E = PQ(α clamped into
// alpha_range) · (F0·A + B)(n·v, α), AB from the `dfg` table at the material's α (and saturate(n·v): the same texels
// for the raw and the clamped view).
BK_FLOAT3 bakery_shexp_reflection(BK_FLOAT3 p[BAKERY_SHEXP_P_COUNT], BK_FLOAT3 q[BAKERY_SHEXP_Q_COUNT],
                                  BK_FLOAT2 alpha_range, BK_FLOAT3 v, BK_FLOAT3 n, float alpha, BK_FLOAT3 F0,
                                  BK_FLOAT2 AB)
{
    v = bakery_clamp_view_to_horizon(v, n);
    return bakery_shexp_pq_clamped(p, q, alpha_range, v, n, alpha) * bakery_dfg_albedo(F0, AB);
}

// `shexp` with albedo_normalized = false (the paper's form): E = PQ · (F0 + (1 − F0) τ(n·v, α)), τ from the
// `fresnel_tail` table ([SHExp] Eq. 5, 15; τ = B/(A+B), store-reflection.md "fresnel_tail"); clamps as above.
BK_FLOAT3 bakery_shexp_reflection_paper(BK_FLOAT3 p[BAKERY_SHEXP_P_COUNT], BK_FLOAT3 q[BAKERY_SHEXP_Q_COUNT],
                                        BK_FLOAT2 alpha_range, BK_FLOAT3 v, BK_FLOAT3 n, float alpha, BK_FLOAT3 F0,
                                        float tau)
{
    v = bakery_clamp_view_to_horizon(v, n);
    return bakery_shexp_pq_clamped(p, q, alpha_range, v, n, alpha) * (F0 + (BK_FLOAT3(1.0, 1.0, 1.0) - F0) * tau);
}

// One analytic directional light of `shexp_lights` / `shexp_hybrid`, split into its base and Fresnel-tail terms
// ([SHExp] Eq. 6–7 for a delta light; bakery.reflection.lights.evaluate_light_parts):
//     base = Φ · D(h) · V(n·v, n·l) · ⟨n, l⟩₊,   tail = base · (1 − v·h)⁵,   h = normalize(v + l),
// so that its E = F0·base + (1 − F0)·tail (Schlick, [SHExp] Eq. 4). α is clamped at 0.002
// (bakery.reflection.lights.MIN_ALPHA); v must already be clamped to the horizon. An unused slot (Φ = 0) adds 0.
void bakery_ggx_directional_light_parts(BK_FLOAT3 direction, BK_FLOAT3 flux, BK_FLOAT3 v, BK_FLOAT3 n, float alpha,
                                        out BK_FLOAT3 base, out BK_FLOAT3 tail)
{
    base = BK_FLOAT3(0.0, 0.0, 0.0);
    tail = BK_FLOAT3(0.0, 0.0, 0.0);
    float n_dot_l = dot(n, direction);
    float n_dot_v = dot(n, v);
    if (!(n_dot_l > 0.0) || !(n_dot_v > 0.0))
        return;
    float a = max(alpha, 0.002);
    float a2 = a * a;
    BK_FLOAT3 h = v + direction;
    h = h / max(length(h), 1e-12);
    BK_FLOAT3 nxh = cross(n, h);
    float d = bakery_ggx_d(dot(n, h), dot(nxh, nxh), a2);
    float vis = bakery_smith_visibility(n_dot_v, n_dot_l, a2);
    float fc = 1.0 - BK_SATURATE(dot(v, h));
    base = flux * (d * vis * n_dot_l);
    tail = base * (fc * fc * fc * fc * fc);                   // Schlick's (1 − v·h)⁵ ([SHExp] Eq. 4)
}

// Σ_k of the lights' base and tail terms (light_direction, light_flux: BAKERY_SHEXP_MAX_LIGHTS RGB each, default 8).
void bakery_lights_parts(BK_FLOAT3 light_direction[BAKERY_SHEXP_MAX_LIGHTS],
                         BK_FLOAT3 light_flux[BAKERY_SHEXP_MAX_LIGHTS], BK_FLOAT3 v, BK_FLOAT3 n, float alpha,
                         out BK_FLOAT3 base, out BK_FLOAT3 tail)
{
    base = BK_FLOAT3(0.0, 0.0, 0.0);
    tail = BK_FLOAT3(0.0, 0.0, 0.0);
    for (int k = 0; k < BAKERY_SHEXP_MAX_LIGHTS; ++k)
    {
        BK_FLOAT3 b, t;
        bakery_ggx_directional_light_parts(light_direction[k], light_flux[k], v, n, alpha, b, t);
        base += b;
        tail += t;
    }
}

// One light's E = Φ · D(h) · V · ⟨n, l⟩₊ · (F0 + (1 − F0)(1 − v·h)⁵) ([SHExp] Eq. 1–8 for a delta light).
BK_FLOAT3 bakery_ggx_directional_light(BK_FLOAT3 direction, BK_FLOAT3 flux, BK_FLOAT3 v, BK_FLOAT3 n, float alpha,
                                       BK_FLOAT3 F0)
{
    BK_FLOAT3 base, tail;
    bakery_ggx_directional_light_parts(direction, flux, v, n, alpha, base, tail);
    return F0 * base + (BK_FLOAT3(1.0, 1.0, 1.0) - F0) * tail;
}

// `shexp_lights`: `shexp` (albedo-normalised; P·Q at α clamped into alpha_range) of the capture without its
// brightest texel clusters + those clusters as analytic GGX directional lights at the material's α (exact at any
// α); v clamped to the horizon for both.
BK_FLOAT3 bakery_shexp_lights_reflection(BK_FLOAT3 p[BAKERY_SHEXP_P_COUNT], BK_FLOAT3 q[BAKERY_SHEXP_Q_COUNT],
                                         BK_FLOAT2 alpha_range, BK_FLOAT3 light_direction[BAKERY_SHEXP_MAX_LIGHTS],
                                         BK_FLOAT3 light_flux[BAKERY_SHEXP_MAX_LIGHTS], BK_FLOAT3 v, BK_FLOAT3 n,
                                         float alpha, BK_FLOAT3 F0, BK_FLOAT2 AB)
{
    v = bakery_clamp_view_to_horizon(v, n);
    BK_FLOAT3 e = bakery_shexp_pq_clamped(p, q, alpha_range, v, n, alpha) * bakery_dfg_albedo(F0, AB);
    BK_FLOAT3 base, tail;
    bakery_lights_parts(light_direction, light_flux, v, n, alpha, base, tail);
    return e + F0 * base + (BK_FLOAT3(1.0, 1.0, 1.0) - F0) * tail;
}

// ============================================================================================ split sum
// `splitsum` (store-reflection.md): level i of L holds radiance prefiltered at GGX α_i = (i/(L−1))², i.e.
// perceptual roughness i/(L−1). Roughness ↔ level: x = √α·(L − 1) clamped to [0, L − 1], i0 = ⌊x⌋,
// i1 = min(i0 + 1, L − 1), f = x − i0 (settings `roughness_to_level`).
void bakery_splitsum_levels(float alpha, int n_levels, out int i0, out int i1, out float f)
{
    float x = BK_SATURATE(sqrt(max(alpha, 0.0))) * float(n_levels - 1);
    i0 = min(int(floor(x)), n_levels - 1);
    i1 = min(i0 + 1, n_levels - 1);
    f = x - float(i0);
}

// Cube face (+X, −X, +Y, −Y, +Z, −Z = 0..5) and face coordinates (u, v) ∈ [−1, 1]² of a direction (need not be
// unit), OpenGL/D3D/KTX orientation (store-v1.md "cube_face_orientation"); ties go to x, then y, then z.
// The texel (row i, column j) of a face of size N is at u = 2(j + ½)/N − 1, v = 2(i + ½)/N − 1.
void bakery_cube_face_uv(BK_FLOAT3 d, out int face, out BK_FLOAT2 uv)
{
    BK_FLOAT3 a = abs(d);
    float major;
    BK_FLOAT2 st;
    if (a.x >= a.y && a.x >= a.z)
    {
        major = d.x;
        face = d.x < 0.0 ? 1 : 0;
        st = d.x < 0.0 ? BK_FLOAT2(d.z, -d.y) : BK_FLOAT2(-d.z, -d.y);   // +X:(1,−v,−u)  −X:(−1,−v,u)
    }
    else if (a.y >= a.z)
    {
        major = d.y;
        face = d.y < 0.0 ? 3 : 2;
        st = d.y < 0.0 ? BK_FLOAT2(d.x, -d.z) : BK_FLOAT2(d.x, d.z);     // +Y:(u,1,v)  −Y:(u,−1,−v)
    }
    else
    {
        major = d.z;
        face = d.z < 0.0 ? 5 : 4;
        st = d.z < 0.0 ? BK_FLOAT2(-d.x, -d.y) : BK_FLOAT2(d.x, -d.y);   // +Z:(u,−v,1)  −Z:(−u,−v,−1)
    }
    float scale = abs(major) > 0.0 ? 1.0 / abs(major) : 0.0;
    uv = clamp(st * scale, BK_FLOAT2(-1.0, -1.0), BK_FLOAT2(1.0, 1.0));
}

// Bilinear taps within one face of size N (clamped at the face edges, as bakery's reference; seamless filtering
// across faces is an acceptable engine difference): texels (x0|x1, y0|y1) = (column, row), weights f.
void bakery_cube_face_bilinear(BK_FLOAT2 uv, int size, out BK_INT2 t0, out BK_INT2 t1, out BK_FLOAT2 f)
{
    float last = float(size - 1);
    BK_FLOAT2 xy = clamp((uv + BK_FLOAT2(1.0, 1.0)) * (0.5 * float(size)) - BK_FLOAT2(0.5, 0.5),
                         BK_FLOAT2(0.0, 0.0), BK_FLOAT2(last, last));
    t0 = BK_INT2(min(int(floor(xy.x)), size - 1), min(int(floor(xy.y)), size - 1));
    t1 = BK_INT2(min(t0.x + 1, size - 1), min(t0.y + 1, size - 1));
    f = xy - BK_FLOAT2(float(t0.x), float(t0.y));
}

// `splitsum`: E = ((1 − f)·c0 + f·c1) · (F0·A + B)(n·v, α), c0 / c1 = levels i0 / i1 looked up at r
// ([Kar13]; store-reflection.md "Reconstruction"; bakery_textures.* fetch c0, c1 and AB).
BK_FLOAT3 bakery_splitsum_reflection(BK_FLOAT3 c0, BK_FLOAT3 c1, float f, BK_FLOAT3 F0, BK_FLOAT2 AB)
{
    return ((1.0 - f) * c0 + f * c1) * bakery_dfg_albedo(F0, AB);
}

// ============================================================================================ hybrid
// `shexp_hybrid` (store-reflection.md; bakery.encodings.hybrid, bakery.reflection.hybrid): `shexp_lights` for rough
// α + a bandwidth split-sum chain of L ≤ 16 levels (level k at GGX α_k = settings `level_alphas`[k], α_0 = 0 the
// capture; face sizes from the dataset shapes) holding only the levels ≥ the probe's `first_level` k0, blended in
// log α (E0 and the Fresnel tail E1 cross over separately, [SHExp] Eq. 5).
#ifndef BAKERY_HYBRID_MAX_LEVELS
#define BAKERY_HYBRID_MAX_LEVELS 16
#endif

// Level coordinate x(α) (bakery.reflection.splitsum.level_coordinate): x = α/α_1 below α_1 (linear between the
// capture and level 1); x = k + log(α/α_k) / log(α_{k+1}/α_k) for α_k ≤ α < α_{k+1}, k ≥ 1 (linear in log α:
// the kernel is scale-invariant for small α, seed 003 §5.1); x = L − 1 above α_{L−1}; then clamped to
// [k0, L − 1] (never sharper than the sharpest stored level, never extrapolated). Returns the two levels read,
// i0 = ⌊x⌋, i1 = min(i0 + 1, L − 1), and the weight f = x − i0 of i1 (as bakery_splitsum_levels).
void bakery_hybrid_levels(float alpha, float level_alphas[BAKERY_HYBRID_MAX_LEVELS], int n_levels, int first_level,
                          out int i0, out int i1, out float f)
{
    float x = 0.0;
    if (n_levels > 1)
    {
        if (alpha < level_alphas[1])
            x = BK_SATURATE(alpha / level_alphas[1]);
        else
        {
            x = float(n_levels - 1);
            for (int k = 1; k < BAKERY_HYBRID_MAX_LEVELS - 1; ++k)
            {
                if (k >= n_levels - 1)
                    break;
                if (alpha < level_alphas[k + 1])
                {
                    x = float(k) + log(alpha / level_alphas[k]) / log(level_alphas[k + 1] / level_alphas[k]);
                    break;
                }
            }
        }
    }
    x = clamp(x, float(min(first_level, n_levels - 1)), float(n_levels - 1));
    i0 = min(int(floor(x)), n_levels - 1);
    i1 = min(i0 + 1, n_levels - 1);
    f = x - float(i0);
}

// The same for a `gap_level` chain (levels 1 … G = the gap levels α_1·2^(−G) … α_1/2) with the probe's
// `gap_skipped` word s: where s > 0 (the probe's materials are a mirror and α ≥ α_{s+1} only; levels 1 … s are not
// uploaded) the chain is read as the chain without levels 1 … s, exactly: between the capture and level s + 1 for
// α < α_{s+1} (f = α/α_{s+1}), as above from α_{s+1} up. A store with one gap level has s ∈ {0, 1}.
void bakery_hybrid_levels(float alpha, float level_alphas[BAKERY_HYBRID_MAX_LEVELS], int n_levels, int first_level,
                          int gap_skipped, out int i0, out int i1, out float f)
{
    int next = clamp(gap_skipped + 1, 1, BAKERY_HYBRID_MAX_LEVELS - 1);  // the first level read after the capture
    if (gap_skipped > 0 && first_level == 0 && n_levels > next && alpha < level_alphas[next])
    {
        i0 = 0;
        i1 = next;
        f = BK_SATURATE(alpha / level_alphas[next]);
    }
    else
        bakery_hybrid_levels(alpha, level_alphas, n_levels, first_level, i0, i1, f);
}

// Chain weight w(α; α_c) = 1 − smoothstep(0, 1, ½ + log2(α/α_c)/octaves) (bakery.reflection.hybrid.chain_weight):
// 1 below α_c·2^(−octaves/2), 0 above α_c·2^(+octaves/2), C¹ in α; α = 0 gives 1.
float bakery_chain_weight(float alpha, float crossover, float octaves)
{
    return 1.0 - smoothstep(0.0, 1.0, 0.5 + log2(max(alpha, 1e-30) / crossover) / octaves);
}

// `shexp_hybrid`: E = F0·E0 + (1 − F0)·E1 with ([SHExp] Eq. 5 with two partitions of unity,
// bakery.reflection.hybrid.combine)
//     E0 = w0·c·(A + B) + (1 − w0)·(PQ·(A + B) + L0),   w0 = w(α; crossover)
//     E1 = w1·c·B       + (1 − w1)·(PQ·B + L1),         w1 = w(α; tail_crossover)
// v clamped to the horizon; PQ at α clamped into alpha_range; (A, B) = AB, the `dfg` table at (n·v, α); L0/L1 the
// lights' base/tail terms at the material's α; c = (1 − f)·c0 + f·c1 the chain read at levels i0, i1 of
// bakery_hybrid_levels and direction bakery_chain_direction(v, n). A probe with first_level ≥ n_levels has no
// chain: w0 = w1 = 0 and c0, c1 are not read (pass 0; w1 ≥ w0 since tail_crossover ≥ crossover, so no level needs
// to be read where w1 = 0 either).
BK_FLOAT3 bakery_shexp_hybrid_reflection(BK_FLOAT3 p[BAKERY_SHEXP_P_COUNT], BK_FLOAT3 q[BAKERY_SHEXP_Q_COUNT],
                                         BK_FLOAT2 alpha_range, BK_FLOAT3 light_direction[BAKERY_SHEXP_MAX_LIGHTS],
                                         BK_FLOAT3 light_flux[BAKERY_SHEXP_MAX_LIGHTS], int first_level,
                                         int n_levels, float crossover, float tail_crossover, float blend_octaves,
                                         BK_FLOAT3 v, BK_FLOAT3 n, float alpha, BK_FLOAT3 F0, BK_FLOAT2 AB,
                                         BK_FLOAT3 c0, BK_FLOAT3 c1, float f)
{
    v = bakery_clamp_view_to_horizon(v, n);
    BK_FLOAT3 pq = bakery_shexp_pq_clamped(p, q, alpha_range, v, n, alpha);
    BK_FLOAT3 l0, l1;
    bakery_lights_parts(light_direction, light_flux, v, n, alpha, l0, l1);
    bool has_chain = first_level < n_levels;
    float w0 = has_chain ? bakery_chain_weight(alpha, crossover, blend_octaves) : 0.0;
    float w1 = has_chain ? bakery_chain_weight(alpha, tail_crossover, blend_octaves) : 0.0;
    BK_FLOAT3 c = w1 > 0.0 ? (1.0 - f) * c0 + f * c1 : BK_FLOAT3(0.0, 0.0, 0.0);
    float a_plus_b = AB.x + AB.y;
    BK_FLOAT3 e0 = w0 * c * a_plus_b + (1.0 - w0) * (pq * a_plus_b + l0);
    BK_FLOAT3 e1 = w1 * c * AB.y + (1.0 - w1) * (pq * AB.y + l1);
    return F0 * e0 + (BK_FLOAT3(1.0, 1.0, 1.0) - F0) * e1;
}

#endif // BAKERY_CORE
