// Fused CPU kernel of the torch renderer's trilinear (mipmapped) path, render_torch.render_rays.
//
// In eager torch every pixel of a coarse scale costs ~80 tensor ops (the ray, both planes, the
// footprint's derivatives, the level of detail, the sub-samples, two bilinear lookups each), each
// a pass over memory plus dispatch. Here one loop per pixel does the same arithmetic in the same
// order, so the two agree to float rounding (tests/sim/test_sim.py). Only power-of-two textures (the
// levels' sizes and packing in closed form, as in render_torch._trilinear).
//
// SIMD across pixels: a row (one camera of one batch element) is rendered in blocks of N pixels
// (AVX-512: 16 floats or 8 doubles; AVX2: 8 or 4), every lane doing exactly the scalar code's
// operations in the same order (add/sub/mul/div/min/max/floor are exact in SIMD, no FMA: the
// build uses -ffp-contract=off and no fma intrinsics), so the result is bit-identical to the
// scalar loop (render_row_scalar: the fallback without AVX2, and for atlases of 2^31 elements or
// more). std::max(a, b) is (a < b ? b : a), i.e. max_ps(b, a), and std::min(a, b) is
// min_ps(b, a): the same result for NaN and signed zeros too.
//
// A row goes in chunks of 16 blocks, two passes each. First the rays, planes, footprints and
// levels of detail of the whole chunk into small buffers; the level of detail's log2 stays the
// scalar libm call (a vector log2 rounds differently), one scalar loop over the chunk, and is
// skipped where rho2 is so small (by a relative margin of 2^-10, far beyond libm's error) that
// the level is clamped to exactly 0 anyway (magnification: ~2/3 of the pixels when training).
// Then the sub-samples' lookups, block by block, while the next chunk's centre texels (finer
// level) are prefetched. The branches become masks: a pixel on neither plane is rendered as a
// dummy at texel (0, 0) of the background and stored as 0 (as are the dummy lanes after a row's
// last pixel); each lane's two levels (their scale, size and place in the atlas computed from
// the level as the scalar code's tables are); the second level is read only when some lane of
// the block has weight on it. Texel fetches are gathers with int32 indices, clamped into the
// layer so that no lane can read outside the atlas (not even from NaN inputs); float32 on AVX-512
// reads each pair of neighbours in a texel row with one 64-bit gather (half the gathered
// elements). Threads: OpenMP over rows (aectorch_kernel_threads()); each pixel is independent,
// so the result depends neither on the threads nor on the block size.
//
// Registered as aectorch::render_trilinear (built with the coder's kernels by
// aectorch.ops.native; its fake implementation for torch.compile lives there too).

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include <algorithm>
#include <optional>
#include <climits>
#include <cmath>
#include <cstring>
#include <vector>

#if defined(__AVX512F__) || defined(__AVX2__)
#include <immintrin.h>
#endif

int aectorch_kernel_threads();  // coder_cpu.cpp

namespace {

template <typename T>
inline T lookup(const T* layer, int64_t rows, int64_t cols, T x, T y) {
  // Bilinear at continuous texel coordinates (texel i centred at i + 0.5), already clamped to
  // a level's edge texel centres: the second neighbour then only ever gets weight 0 at an edge.
  const T fx = x - T(0.5), fy = y - T(0.5);
  const T x0f = std::floor(fx), y0f = std::floor(fy);
  const T wx = fx - x0f, wy = fy - y0f;
  const int64_t x0 = static_cast<int64_t>(x0f), y0 = static_cast<int64_t>(y0f);
  const int64_t x1 = std::min(x0 + 1, cols - 1), y1 = std::min(y0 + 1, rows - 1);
  const T a = layer[y0 * cols + x0], b = layer[y0 * cols + x1];
  const T c = layer[y1 * cols + x0], d = layer[y1 * cols + x1];
  const T top = a + wx * (b - a), bottom = c + wx * (d - c);
  return top + wy * (bottom - top);
}

// Everything a row needs: the call's constants and the row's camera.
template <typename T>
struct Row {
  // call
  const T* tex;
  const T* xs;
  const T* ys;
  const T* steps;
  int64_t pixels, layers, rows, cols, layer_size, top_level, samples, n_sub;
  T th, tw, bias, below_zero, obj_w, obj_h, bg_w, bg_h;
  const T* offsets;
  const T* level_scale;
  const T* level_h;
  const T* level_w;
  const T* level_row;
  const T* level_col;
  // row
  T r00, r01, r02, r10, r11, r12, r20, r21, r22;
  T reach_o, reach_b, uo0, vo0, ub0, vb0, ro_w, ro_h, rb_w, rb_h;
  int64_t object_layer;
  T* dst;
};

template <typename T>
void render_row_scalar(const Row<T>& R) {
  const T r00 = R.r00, r01 = R.r01, r02 = R.r02, r10 = R.r10, r11 = R.r11, r12 = R.r12;
  const T r20 = R.r20, r21 = R.r21, r22 = R.r22;
  const T reach_o = R.reach_o, reach_b = R.reach_b, tw = R.tw, th = R.th;
  const int64_t samples = R.samples, top_level = R.top_level;
  for (int64_t p = 0; p < R.pixels; ++p) {
    const T x = R.xs[p], y = R.ys[p];
    const T d0 = r00 * x - (r01 * y + r02);
    const T d1 = r10 * x - (r11 * y + r12);
    const T d2 = r20 * x - (r21 * y + r22);
    const bool ahead = d0 > T(1e-12);
    const T inv = T(1) / (ahead ? d0 : T(1));
    const T ry = d1 * inv, rz = d2 * inv;
    const T uo = R.uo0 - R.ro_w * ry, vo = R.vo0 - R.ro_h * rz;
    const T ub = R.ub0 - R.rb_w * ry, vb = R.vb0 - R.rb_h * rz;
    const bool on_object = ahead && reach_o > 0 && uo >= 0 && uo <= 1 && vo >= 0 && vo <= 1;
    const bool on_background = ahead && reach_b > 0 && ub >= 0 && ub <= 1 && vb >= 0 && vb <= 1;
    if (!(on_object || on_background)) {
      R.dst[p] = T(0);
      continue;
    }
    const T u = (on_object ? uo : ub) * tw, v = (on_object ? vo : vb) * th;
    const T ku = (on_object ? reach_o * (tw / R.obj_w) : reach_b * (tw / R.bg_w)) * R.steps[p];
    const T kv = (on_object ? reach_o * (th / R.obj_h) : reach_b * (th / R.bg_h)) * R.steps[p];
    const T du_c = ku * (r10 - ry * r00) * inv, dv_c = kv * (r20 - rz * r00) * inv;
    const T du_r = ku * (ry * r01 - r11) * inv, dv_r = kv * (rz * r01 - r21) * inv;
    const T rho2 = std::max(du_c * du_c + dv_c * dv_c, du_r * du_r + dv_r * dv_r);
    T lod = T(0.5) * std::log2(std::max(rho2, T(1e-30))) + R.bias;
    lod = std::min(std::max(lod, T(0)), T(top_level));
    const T low = std::floor(lod);
    const T fraction = lod - low;
    const T high = std::min(low + T(1), T(top_level));
    const T* layer = R.tex + (on_object ? R.object_layer : R.layers - 1) * R.layer_size;
    const int64_t level_of[2] = {static_cast<int64_t>(low), static_cast<int64_t>(high)};
    // One level when the other has no weight (magnification, or the last level).
    const int levels_read = (fraction == T(0) || high == low) ? 1 : 2;
    T sum = 0;
    // Sub-sample s = row * samples + column, in that order (no integer division per sample).
    for (int64_t srow = 0; srow < samples; ++srow) {
      const T orow = R.offsets[srow];
      for (int64_t scol = 0; scol < samples; ++scol) {
        const T oc = R.offsets[scol];
        const T us = samples > 1 ? u + du_c * oc + du_r * orow : u;
        const T vs = samples > 1 ? v + dv_c * oc + dv_r * orow : v;
        T value[2];
        for (int k = 0; k < levels_read; ++k) {
          const int64_t l = level_of[k];
          const T sx = std::min(std::max(us * R.level_scale[l], T(0.5)), R.level_w[l] - T(0.5)) + R.level_col[l];
          const T sy = std::min(std::max(vs * R.level_scale[l], T(0.5)), R.level_h[l] - T(0.5)) + R.level_row[l];
          value[k] = lookup(layer, R.rows, R.cols, sx, sy);
        }
        sum += levels_read == 1 ? value[0] : value[0] + fraction * (value[1] - value[0]);
      }
    }
    R.dst[p] = samples > 1 ? sum / T(R.n_sub) : sum;
  }
}

#if defined(__AVX512F__) || defined(__AVX2__)
// The vector operations, one struct per (ISA, dtype). min/max are the raw instructions
// (min(a, b) = a < b ? a : b, max(a, b) = a > b ? a : b); callers swap the operands to get
// std::min/std::max. I holds one int32 per lane (texel indices).
#if defined(__AVX512F__)
struct VecF {
  using T = float;
  static constexpr int N = 16;
  using V = __m512;
  using I = __m512i;
  using M = __mmask16;
  static V set1(T x) { return _mm512_set1_ps(x); }
  static V load(const T* p) { return _mm512_loadu_ps(p); }
  static void store(T* p, V v) { _mm512_storeu_ps(p, v); }
  static V add(V a, V b) { return _mm512_add_ps(a, b); }
  static V sub(V a, V b) { return _mm512_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm512_mul_ps(a, b); }
  static V div(V a, V b) { return _mm512_div_ps(a, b); }
  static V min(V a, V b) { return _mm512_min_ps(a, b); }
  static V max(V a, V b) { return _mm512_max_ps(a, b); }
  static V floor(V a) { return _mm512_roundscale_ps(a, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
  static M gt(V a, V b) { return _mm512_cmp_ps_mask(a, b, _CMP_GT_OQ); }
  static M lt(V a, V b) { return _mm512_cmp_ps_mask(a, b, _CMP_LT_OQ); }
  static M ge(V a, V b) { return _mm512_cmp_ps_mask(a, b, _CMP_GE_OQ); }
  static M le(V a, V b) { return _mm512_cmp_ps_mask(a, b, _CMP_LE_OQ); }
  static M eq(V a, V b) { return _mm512_cmp_ps_mask(a, b, _CMP_EQ_OQ); }
  static M mand(M a, M b) { return static_cast<M>(a & b); }
  static M mor(M a, M b) { return static_cast<M>(a | b); }
  static M mnot(M a) { return static_cast<M>(~a); }
  static M mnone() { return 0; }
  static unsigned bits(M m) { return m; }
  static V select(M m, V a, V b) { return _mm512_mask_blend_ps(m, b, a); }  // m ? a : b
  static I cvt(V a) { return _mm512_cvttps_epi32(a); }
  static I iset1(int x) { return _mm512_set1_epi32(x); }
  static I iload(const int* p) { return _mm512_load_si512(p); }
  static void istore(int* p, I v) { _mm512_store_si512(p, v); }
  static I iadd(I a, I b) { return _mm512_add_epi32(a, b); }
  static I imul(I a, I b) { return _mm512_mullo_epi32(a, b); }
  static I imin(I a, I b) { return _mm512_min_epi32(a, b); }
  static I imax(I a, I b) { return _mm512_max_epi32(a, b); }
  static V gather(const T* base, I idx) { return _mm512_i32gather_ps(idx, base, 4); }
  // a = base[row + x0], b = base[row + min(x0 + 1, cols - 1)] (cols >= 2): both from one 64-bit
  // gather per 8 lanes, of the pair at min(x0, cols - 2) (at x0 = cols - 1 both are its second).
  static void pair(const T* base, I row, I x0, int cols, V& a, V& b) {
    const I idx = _mm512_add_epi32(row, _mm512_min_epi32(x0, _mm512_set1_epi32(cols - 2)));
    const I lo = _mm512_i32gather_epi64(_mm512_castsi512_si256(idx), base, 4);
    const I hi = _mm512_i32gather_epi64(_mm512_extracti64x4_epi64(idx, 1), base, 4);
    const I even = _mm512_set_epi32(30, 28, 26, 24, 22, 20, 18, 16, 14, 12, 10, 8, 6, 4, 2, 0);
    const I odd = _mm512_set_epi32(31, 29, 27, 25, 23, 21, 19, 17, 15, 13, 11, 9, 7, 5, 3, 1);
    const V first = _mm512_castsi512_ps(_mm512_permutex2var_epi32(lo, even, hi));
    b = _mm512_castsi512_ps(_mm512_permutex2var_epi32(lo, odd, hi));
    a = _mm512_mask_blend_ps(_mm512_cmpeq_epi32_mask(x0, _mm512_set1_epi32(cols - 1)), first, b);
  }
  static V exp2neg(I l) {  // 2^-l, exact (0 <= l < 127)
    return _mm512_castsi512_ps(_mm512_slli_epi32(_mm512_sub_epi32(_mm512_set1_epi32(127), l), 23));
  }
};
struct VecD {
  using T = double;
  static constexpr int N = 8;
  using V = __m512d;
  using I = __m256i;
  using M = __mmask8;
  static V set1(T x) { return _mm512_set1_pd(x); }
  static V load(const T* p) { return _mm512_loadu_pd(p); }
  static void store(T* p, V v) { _mm512_storeu_pd(p, v); }
  static V add(V a, V b) { return _mm512_add_pd(a, b); }
  static V sub(V a, V b) { return _mm512_sub_pd(a, b); }
  static V mul(V a, V b) { return _mm512_mul_pd(a, b); }
  static V div(V a, V b) { return _mm512_div_pd(a, b); }
  static V min(V a, V b) { return _mm512_min_pd(a, b); }
  static V max(V a, V b) { return _mm512_max_pd(a, b); }
  static V floor(V a) { return _mm512_roundscale_pd(a, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
  static M gt(V a, V b) { return _mm512_cmp_pd_mask(a, b, _CMP_GT_OQ); }
  static M lt(V a, V b) { return _mm512_cmp_pd_mask(a, b, _CMP_LT_OQ); }
  static M ge(V a, V b) { return _mm512_cmp_pd_mask(a, b, _CMP_GE_OQ); }
  static M le(V a, V b) { return _mm512_cmp_pd_mask(a, b, _CMP_LE_OQ); }
  static M eq(V a, V b) { return _mm512_cmp_pd_mask(a, b, _CMP_EQ_OQ); }
  static M mand(M a, M b) { return static_cast<M>(a & b); }
  static M mor(M a, M b) { return static_cast<M>(a | b); }
  static M mnot(M a) { return static_cast<M>(~a); }
  static M mnone() { return 0; }
  static unsigned bits(M m) { return m; }
  static V select(M m, V a, V b) { return _mm512_mask_blend_pd(m, b, a); }
  static I cvt(V a) { return _mm512_cvttpd_epi32(a); }
  static I iset1(int x) { return _mm256_set1_epi32(x); }
  static I iload(const int* p) { return _mm256_load_si256(reinterpret_cast<const __m256i*>(p)); }
  static void istore(int* p, I v) { _mm256_store_si256(reinterpret_cast<__m256i*>(p), v); }
  static I iadd(I a, I b) { return _mm256_add_epi32(a, b); }
  static I imul(I a, I b) { return _mm256_mullo_epi32(a, b); }
  static I imin(I a, I b) { return _mm256_min_epi32(a, b); }
  static I imax(I a, I b) { return _mm256_max_epi32(a, b); }
  static V gather(const T* base, I idx) { return _mm512_i32gather_pd(idx, base, 8); }
  static void pair(const T* base, I row, I x0, int cols, V& a, V& b) {
    a = gather(base, iadd(row, x0));
    b = gather(base, iadd(row, imin(iadd(x0, iset1(1)), iset1(cols - 1))));
  }
  static V exp2neg(I l) {  // 2^-l, exact (0 <= l < 1023)
    const __m512i e = _mm512_sub_epi64(_mm512_set1_epi64(1023), _mm512_cvtepi32_epi64(l));
    return _mm512_castsi512_pd(_mm512_slli_epi64(e, 52));
  }
};
#else  // AVX2
struct VecF {
  using T = float;
  static constexpr int N = 8;
  using V = __m256;
  using I = __m256i;
  using M = __m256;
  static V set1(T x) { return _mm256_set1_ps(x); }
  static V load(const T* p) { return _mm256_loadu_ps(p); }
  static void store(T* p, V v) { _mm256_storeu_ps(p, v); }
  static V add(V a, V b) { return _mm256_add_ps(a, b); }
  static V sub(V a, V b) { return _mm256_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm256_mul_ps(a, b); }
  static V div(V a, V b) { return _mm256_div_ps(a, b); }
  static V min(V a, V b) { return _mm256_min_ps(a, b); }
  static V max(V a, V b) { return _mm256_max_ps(a, b); }
  static V floor(V a) { return _mm256_round_ps(a, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
  static M gt(V a, V b) { return _mm256_cmp_ps(a, b, _CMP_GT_OQ); }
  static M lt(V a, V b) { return _mm256_cmp_ps(a, b, _CMP_LT_OQ); }
  static M ge(V a, V b) { return _mm256_cmp_ps(a, b, _CMP_GE_OQ); }
  static M le(V a, V b) { return _mm256_cmp_ps(a, b, _CMP_LE_OQ); }
  static M eq(V a, V b) { return _mm256_cmp_ps(a, b, _CMP_EQ_OQ); }
  static M mand(M a, M b) { return _mm256_and_ps(a, b); }
  static M mor(M a, M b) { return _mm256_or_ps(a, b); }
  static M mnot(M a) { return _mm256_xor_ps(a, _mm256_castsi256_ps(_mm256_set1_epi32(-1))); }
  static M mnone() { return _mm256_setzero_ps(); }
  static unsigned bits(M m) { return static_cast<unsigned>(_mm256_movemask_ps(m)); }
  static V select(M m, V a, V b) { return _mm256_blendv_ps(b, a, m); }
  static I cvt(V a) { return _mm256_cvttps_epi32(a); }
  static I iset1(int x) { return _mm256_set1_epi32(x); }
  static I iload(const int* p) { return _mm256_load_si256(reinterpret_cast<const __m256i*>(p)); }
  static void istore(int* p, I v) { _mm256_store_si256(reinterpret_cast<__m256i*>(p), v); }
  static I iadd(I a, I b) { return _mm256_add_epi32(a, b); }
  static I imul(I a, I b) { return _mm256_mullo_epi32(a, b); }
  static I imin(I a, I b) { return _mm256_min_epi32(a, b); }
  static I imax(I a, I b) { return _mm256_max_epi32(a, b); }
  static V gather(const T* base, I idx) { return _mm256_i32gather_ps(base, idx, 4); }
  static void pair(const T* base, I row, I x0, int cols, V& a, V& b) {
    a = gather(base, iadd(row, x0));
    b = gather(base, iadd(row, imin(iadd(x0, iset1(1)), iset1(cols - 1))));
  }
  static V exp2neg(I l) {
    return _mm256_castsi256_ps(_mm256_slli_epi32(_mm256_sub_epi32(_mm256_set1_epi32(127), l), 23));
  }
};
struct VecD {
  using T = double;
  static constexpr int N = 4;
  using V = __m256d;
  using I = __m128i;
  using M = __m256d;
  static V set1(T x) { return _mm256_set1_pd(x); }
  static V load(const T* p) { return _mm256_loadu_pd(p); }
  static void store(T* p, V v) { _mm256_storeu_pd(p, v); }
  static V add(V a, V b) { return _mm256_add_pd(a, b); }
  static V sub(V a, V b) { return _mm256_sub_pd(a, b); }
  static V mul(V a, V b) { return _mm256_mul_pd(a, b); }
  static V div(V a, V b) { return _mm256_div_pd(a, b); }
  static V min(V a, V b) { return _mm256_min_pd(a, b); }
  static V max(V a, V b) { return _mm256_max_pd(a, b); }
  static V floor(V a) { return _mm256_round_pd(a, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
  static M gt(V a, V b) { return _mm256_cmp_pd(a, b, _CMP_GT_OQ); }
  static M lt(V a, V b) { return _mm256_cmp_pd(a, b, _CMP_LT_OQ); }
  static M ge(V a, V b) { return _mm256_cmp_pd(a, b, _CMP_GE_OQ); }
  static M le(V a, V b) { return _mm256_cmp_pd(a, b, _CMP_LE_OQ); }
  static M eq(V a, V b) { return _mm256_cmp_pd(a, b, _CMP_EQ_OQ); }
  static M mand(M a, M b) { return _mm256_and_pd(a, b); }
  static M mor(M a, M b) { return _mm256_or_pd(a, b); }
  static M mnot(M a) { return _mm256_xor_pd(a, _mm256_castsi256_pd(_mm256_set1_epi32(-1))); }
  static M mnone() { return _mm256_setzero_pd(); }
  static unsigned bits(M m) { return static_cast<unsigned>(_mm256_movemask_pd(m)); }
  static V select(M m, V a, V b) { return _mm256_blendv_pd(b, a, m); }
  static I cvt(V a) { return _mm256_cvttpd_epi32(a); }
  static I iset1(int x) { return _mm_set1_epi32(x); }
  static I iload(const int* p) { return _mm_load_si128(reinterpret_cast<const __m128i*>(p)); }
  static void istore(int* p, I v) { _mm_store_si128(reinterpret_cast<__m128i*>(p), v); }
  static I iadd(I a, I b) { return _mm_add_epi32(a, b); }
  static I imul(I a, I b) { return _mm_mullo_epi32(a, b); }
  static I imin(I a, I b) { return _mm_min_epi32(a, b); }
  static I imax(I a, I b) { return _mm_max_epi32(a, b); }
  static V gather(const T* base, I idx) { return _mm256_i32gather_pd(base, idx, 8); }
  static void pair(const T* base, I row, I x0, int cols, V& a, V& b) {
    a = gather(base, iadd(row, x0));
    b = gather(base, iadd(row, imin(iadd(x0, iset1(1)), iset1(cols - 1))));
  }
  static V exp2neg(I l) {
    const __m256i e = _mm256_sub_epi64(_mm256_set1_epi64x(1023), _mm256_cvtepi32_epi64(l));
    return _mm256_castsi256_pd(_mm256_slli_epi64(e, 52));
  }
};
#endif

template <typename T> struct VecOf;
template <> struct VecOf<float> { using type = VecF; };
template <> struct VecOf<double> { using type = VecD; };

// render_row_scalar for N pixels at a time; every lane's arithmetic is the scalar code's. In
// chunks of BLOCKS blocks: first each pixel's ray, plane, footprint and level of detail (the
// log2 calls in one scalar loop over the chunk), with a prefetch of its centre texels at the
// finer level; then the sub-samples' lookups, block by block.
template <typename S>
void render_row_simd(const Row<typename S::T>& R) {
  using T = typename S::T;
  using V = typename S::V;
  using I = typename S::I;
  using M = typename S::M;
  constexpr int N = S::N, BLOCKS = 16, K = N * BLOCKS;
  const V zero = S::set1(T(0)), one = S::set1(T(1)), half = S::set1(T(0.5));
  const V r00 = S::set1(R.r00), r01 = S::set1(R.r01), r02 = S::set1(R.r02);
  const V r10 = S::set1(R.r10), r11 = S::set1(R.r11), r12 = S::set1(R.r12);
  const V r20 = S::set1(R.r20), r21 = S::set1(R.r21), r22 = S::set1(R.r22);
  const V uo0 = S::set1(R.uo0), vo0 = S::set1(R.vo0), ub0 = S::set1(R.ub0), vb0 = S::set1(R.vb0);
  const V ro_w = S::set1(R.ro_w), ro_h = S::set1(R.ro_h), rb_w = S::set1(R.rb_w), rb_h = S::set1(R.rb_h);
  const V tw = S::set1(R.tw), th = S::set1(R.th), two_th = S::set1(T(2) * R.th);
  const V ku_o = S::set1(R.reach_o * (R.tw / R.obj_w)), ku_b = S::set1(R.reach_b * (R.tw / R.bg_w));
  const V kv_o = S::set1(R.reach_o * (R.th / R.obj_h)), kv_b = S::set1(R.reach_b * (R.th / R.bg_h));
  const V eps = S::set1(T(1e-12)), tiny = S::set1(T(1e-30)), top = S::set1(T(R.top_level));
  const V bias = S::set1(R.bias), n_sub = S::set1(T(R.n_sub));
  // rho2 below this: log2(rho2) < -2 bias by far more than libm's error, so 0.5 log2(rho2) + bias
  // < 0 and the level of detail is clamped to exactly 0 without the call.
  const V below_zero = S::set1(R.below_zero);
  const bool object_ahead = R.reach_o > 0, background_ahead = R.reach_b > 0;
  const int64_t samples = R.samples;
  const int cols = static_cast<int>(R.cols);
  const I icols = S::iset1(cols), icols1 = S::iset1(cols - 1), irows1 = S::iset1(static_cast<int>(R.rows - 1));
  const I izero = S::iset1(0), ione = S::iset1(1);
  const int object_offset = static_cast<int>(R.object_layer * R.layer_size);
  const int background_offset = static_cast<int>((R.layers - 1) * R.layer_size);
  const I layer_step = S::iset1(object_offset - background_offset), background_base = S::iset1(background_offset);
  // A chunk: per pixel (u, v) in level-0 texels, the footprint's sides, the level of detail
  // (first max(rho2, 1e-30)), the layer's offset in the atlas and the centre texel at the finer
  // level (to prefetch); per block which lanes see a plane and which need the log2. Two of them:
  // the next chunk's texels are prefetched while this one's are read.
  struct Chunk {
    alignas(64) T u[K], v[K], du_c[K], dv_c[K], du_r[K], dv_r[K], lod[K];
    alignas(64) int off[K], centre[K];
    M seen[BLOCKS], need[BLOCKS];
    int64_t start;
    int blocks;
  };
  Chunk chunks[2];
  alignas(64) T buffer[N], xin[N], yin[N], sin_[N];

  // Bilinear at clamped texel coordinates (lookup above), layer_off + the texel's index.
  auto bilinear = [&](V x, V y, I layer_off) {
    const V fx = S::sub(x, half), fy = S::sub(y, half);
    const V x0f = S::floor(fx), y0f = S::floor(fy);
    const V wx = S::sub(fx, x0f), wy = S::sub(fy, y0f);
    // (clamped into the layer: the identity for any level and coordinates the scalar code can
    // meet, and no lane can read outside the atlas even from NaN inputs)
    const I x0 = S::imin(S::imax(S::cvt(x0f), izero), icols1), y0 = S::imin(S::imax(S::cvt(y0f), izero), irows1);
    const I y1 = S::imin(S::iadd(y0, ione), irows1);
    const I row0 = S::iadd(layer_off, S::imul(y0, icols)), row1 = S::iadd(layer_off, S::imul(y1, icols));
    V a, b, c, d;
    S::pair(R.tex, row0, x0, cols, a, b);
    S::pair(R.tex, row1, x0, cols, c, d);
    const V t = S::add(a, S::mul(wx, S::sub(b, a))), bottom = S::add(c, S::mul(wx, S::sub(d, c)));
    return S::add(t, S::mul(wy, S::sub(bottom, t)));
  };
  // A level's scale, last texel centres and place in the atlas (the scalar code's tables).
  struct Level { V scale, wmax, hmax, col, row; };
  auto level_of = [&](V level) {
    Level L;
    L.scale = S::exp2neg(S::cvt(level));
    L.wmax = S::sub(S::max(one, S::mul(tw, L.scale)), half);
    L.hmax = S::sub(S::max(one, S::mul(th, L.scale)), half);
    L.row = S::max(zero, S::sub(th, S::mul(two_th, L.scale)));
    L.col = S::mul(S::min(one, level), tw);
    return L;
  };

  auto prepare = [&](Chunk& C, int64_t start) {
    C.start = start;
    const int blocks = C.blocks = static_cast<int>((std::min<int64_t>(K, R.pixels - start) + N - 1) / N);
    // 1. The rays, planes and footprints.
    for (int j = 0; j < blocks; ++j) {
      const int64_t p = C.start + j * N;
      const int n = static_cast<int>(std::min<int64_t>(N, R.pixels - p));
      V x, y, st;
      if (n == N) {
        x = S::load(R.xs + p), y = S::load(R.ys + p), st = S::load(R.steps + p);
      } else {  // the row's tail: dummy lanes at the centre ray (x = y = 0, no footprint), never stored
        for (int i = 0; i < N; ++i) {
          xin[i] = i < n ? R.xs[p + i] : T(0);
          yin[i] = i < n ? R.ys[p + i] : T(0);
          sin_[i] = i < n ? R.steps[p + i] : T(0);
        }
        x = S::load(xin), y = S::load(yin), st = S::load(sin_);
      }
      const V d0 = S::sub(S::mul(r00, x), S::add(S::mul(r01, y), r02));
      const V d1 = S::sub(S::mul(r10, x), S::add(S::mul(r11, y), r12));
      const V d2 = S::sub(S::mul(r20, x), S::add(S::mul(r21, y), r22));
      const M ahead = S::gt(d0, eps);
      const V inv = S::div(one, S::select(ahead, d0, one));
      const V ry = S::mul(d1, inv), rz = S::mul(d2, inv);
      const V uo = S::sub(uo0, S::mul(ro_w, ry)), vo = S::sub(vo0, S::mul(ro_h, rz));
      const V ub = S::sub(ub0, S::mul(rb_w, ry)), vb = S::sub(vb0, S::mul(rb_h, rz));
      const M on_object = object_ahead
          ? S::mand(S::mand(ahead, S::mand(S::ge(uo, zero), S::le(uo, one))), S::mand(S::ge(vo, zero), S::le(vo, one)))
          : S::mnone();
      const M on_background = background_ahead
          ? S::mand(S::mand(ahead, S::mand(S::ge(ub, zero), S::le(ub, one))), S::mand(S::ge(vb, zero), S::le(vb, one)))
          : S::mnone();
      const M seen = S::mor(on_object, on_background);
      C.seen[j] = seen;
      // Lanes on neither plane: u = v = 0 and no footprint (level 0 of the background, in range).
      const V u = S::select(seen, S::mul(S::select(on_object, uo, ub), tw), zero);
      const V v = S::select(seen, S::mul(S::select(on_object, vo, vb), th), zero);
      const V ku = S::mul(S::select(on_object, ku_o, ku_b), st);
      const V kv = S::mul(S::select(on_object, kv_o, kv_b), st);
      const V du_c = S::select(seen, S::mul(S::mul(ku, S::sub(r10, S::mul(ry, r00))), inv), zero);
      const V dv_c = S::select(seen, S::mul(S::mul(kv, S::sub(r20, S::mul(rz, r00))), inv), zero);
      const V du_r = S::select(seen, S::mul(S::mul(ku, S::sub(S::mul(ry, r01), r11)), inv), zero);
      const V dv_r = S::select(seen, S::mul(S::mul(kv, S::sub(S::mul(rz, r01), r21)), inv), zero);
      // std::max(c, r) = max_ps(r, c)
      const V rho2 = S::max(S::add(S::mul(du_r, du_r), S::mul(dv_r, dv_r)), S::add(S::mul(du_c, du_c), S::mul(dv_c, dv_c)));
      const V rho2c = S::max(tiny, rho2);
      C.need[j] = S::mand(seen, S::mnot(S::lt(rho2c, below_zero)));
      const int at = j * N;
      S::store(C.u + at, u), S::store(C.v + at, v);
      S::store(C.du_c + at, du_c), S::store(C.dv_c + at, dv_c), S::store(C.du_r + at, du_r), S::store(C.dv_r + at, dv_r);
      S::store(C.lod + at, rho2c);
      S::istore(C.off + at, S::iadd(background_base, S::imul(S::cvt(S::select(on_object, one, zero)), layer_step)));
    }
    // 2. log2 (libm, one lane at a time) where the level of detail is not surely 0.
    for (int j = 0; j < blocks; ++j) {
      for (unsigned need = S::bits(C.need[j]); need; need &= need - 1) {
        const int i = j * N + __builtin_ctz(need);
        C.lod[i] = std::log2(C.lod[i]);
      }
    }
    // 3. The levels of detail, and each pixel's centre texel at the finer level.
    for (int j = 0; j < blocks; ++j) {
      const int at = j * N;
      V lod = S::add(S::mul(half, S::load(C.lod + at)), bias);
      lod = S::select(C.need[j], S::min(top, S::max(zero, lod)), zero);
      S::store(C.lod + at, lod);
      const Level L = level_of(S::floor(lod));
      const V sx = S::add(S::min(L.wmax, S::max(half, S::mul(S::load(C.u + at), L.scale))), L.col);
      const V sy = S::add(S::min(L.hmax, S::max(half, S::mul(S::load(C.v + at), L.scale))), L.row);
      const I x0 = S::imax(S::cvt(S::sub(sx, half)), izero), y0 = S::imax(S::cvt(S::sub(sy, half)), izero);
      S::istore(C.centre + at, S::iadd(S::iload(C.off + at), S::iadd(S::imul(y0, icols), x0)));
    }
  };
  auto render_chunk = [&](const Chunk& C, const Chunk* next) {
    // 4. The sub-samples, two levels each where some lane of the block needs the second.
    for (int j = 0; j < C.blocks; ++j) {
      if (next != nullptr && j < next->blocks) {
        for (int i = j * N; i < (j + 1) * N; ++i) {
          const T* texel = R.tex + next->centre[i];
          __builtin_prefetch(texel);
          __builtin_prefetch(texel + cols);
        }
      }
      const int64_t p = C.start + j * N;
      const int n = static_cast<int>(std::min<int64_t>(N, R.pixels - p));
      const int at = j * N;
      const M seen = C.seen[j];
      const unsigned seen_bits = S::bits(seen);
      V out = zero;
      if (seen_bits != 0) {
        const V u = S::load(C.u + at), v = S::load(C.v + at);
        const V du_c = S::load(C.du_c + at), dv_c = S::load(C.dv_c + at);
        const V du_r = S::load(C.du_r + at), dv_r = S::load(C.dv_r + at);
        const V lod = S::load(C.lod + at);
        const I layer_off = S::iload(C.off + at);
        const V low = S::floor(lod);
        const V fraction = S::sub(lod, low);
        const V high = S::min(top, S::add(low, one));
        const M two_levels = S::mnot(S::mor(S::eq(fraction, zero), S::eq(high, low)));
        const bool any_two = (S::bits(two_levels) & seen_bits) != 0;
        Level level[2];
        level[0] = level_of(low);
        if (any_two) level[1] = level_of(high);
        V sum = zero;
        for (int64_t srow = 0; srow < samples; ++srow) {
          const V orow = S::set1(R.offsets[srow]);
          for (int64_t scol = 0; scol < samples; ++scol) {
            const V oc = S::set1(R.offsets[scol]);
            const V us = samples > 1 ? S::add(S::add(u, S::mul(du_c, oc)), S::mul(du_r, orow)) : u;
            const V vs = samples > 1 ? S::add(S::add(v, S::mul(dv_c, oc)), S::mul(dv_r, orow)) : v;
            V value[2];
            for (int k = 0; k < (any_two ? 2 : 1); ++k) {
              const Level& L = level[k];
              const V sx = S::add(S::min(L.wmax, S::max(half, S::mul(us, L.scale))), L.col);
              const V sy = S::add(S::min(L.hmax, S::max(half, S::mul(vs, L.scale))), L.row);
              value[k] = bilinear(sx, sy, layer_off);
            }
            const V blend = any_two
                ? S::select(two_levels, S::add(value[0], S::mul(fraction, S::sub(value[1], value[0]))), value[0])
                : value[0];
            sum = S::add(sum, blend);
          }
        }
        out = S::select(seen, samples > 1 ? S::div(sum, n_sub) : sum, zero);
      }
      if (n == N) {
        S::store(R.dst + p, out);
      } else {
        S::store(buffer, out);
        for (int i = 0; i < n; ++i) R.dst[p + i] = buffer[i];
      }
    }
  };

  prepare(chunks[0], 0);
  for (int i = 0; i < chunks[0].blocks * N; ++i) __builtin_prefetch(R.tex + chunks[0].centre[i]);
  for (int64_t start = 0, k = 0; start < R.pixels; start += K, k ^= 1) {
    const bool more = start + K < R.pixels;
    if (more) prepare(chunks[k ^ 1], start + K);
    render_chunk(chunks[k], more ? &chunks[k ^ 1] : nullptr);
  }
}
#endif

template <typename T>
void render(const at::Tensor& poses, const at::Tensor& plane_x, const at::Tensor& texture_index,
            const at::Tensor& atlas, const at::Tensor& xs_t, const at::Tensor& ys_t,
            const at::Tensor& steps_t, const std::vector<double>& scene, int64_t tex_h, int64_t tex_w,
            int64_t levels, double lod_bias, int64_t samples, const at::Tensor* plane_y, at::Tensor& out) {
  const int64_t batch = poses.size(0), cams = poses.size(1), pixels = xs_t.size(0);
  const int64_t layers = atlas.size(0), rows = atlas.size(1), cols = atlas.size(2);
  const T* pose = poses.data_ptr<T>();
  const T* px = plane_x.data_ptr<T>();
  const T* py = plane_y == nullptr ? nullptr : plane_y->data_ptr<T>();  // the object's lateral offsets
  const int64_t* index = texture_index.data_ptr<int64_t>();
  T* result = out.data_ptr<T>();
  const T obj_cy = scene[0], obj_cz = scene[1], obj_w = scene[2], obj_h = scene[3];
  const T bg_x = scene[4], bg_cy = scene[5], bg_cz = scene[6], bg_w = scene[7], bg_h = scene[8];
  const T th = T(tex_h), tw = T(tex_w);
  std::vector<T> offsets(samples);
  for (int64_t i = 0; i < samples; ++i) offsets[i] = (T(i) + T(0.5)) / T(samples) - T(0.5);
  // Each level's scale, size and place in the packed atlas, once per call (the same numbers the
  // per-pixel code computed: exact powers of two, then the same products).
  std::vector<T> level_scale(levels), level_h(levels), level_w(levels), level_row(levels), level_col(levels);
  for (int64_t l = 0; l < levels; ++l) {
    const T scale = std::ldexp(T(1), -static_cast<int>(l));
    level_scale[l] = scale;
    level_h[l] = std::max(th * scale, T(1));
    level_w[l] = std::max(tw * scale, T(1));
    level_row[l] = std::max(th - T(2) * th * scale, T(0));
    level_col[l] = std::min(T(l), T(1)) * tw;
  }
  Row<T> call{};
  call.tex = atlas.data_ptr<T>();
  call.xs = xs_t.data_ptr<T>();
  call.ys = ys_t.data_ptr<T>();
  call.steps = steps_t.data_ptr<T>();
  call.pixels = pixels, call.layers = layers, call.rows = rows, call.cols = cols;
  call.layer_size = rows * cols, call.top_level = levels - 1, call.samples = samples, call.n_sub = samples * samples;
  call.th = th, call.tw = tw, call.bias = T(lod_bias - std::log2(double(samples)));
  // (margin 2^-10 relative, i.e. log2 off by > 1e-3: libm is within a few ulps; inf or 0 when
  // 2^(-2 bias) is outside T's range, both still right)
  call.below_zero = T(std::exp2(-2.0 * double(call.bias)) * (1.0 - 1.0 / 1024));
  call.obj_w = obj_w, call.obj_h = obj_h, call.bg_w = bg_w, call.bg_h = bg_h;
  call.offsets = offsets.data();
  call.level_scale = level_scale.data(), call.level_h = level_h.data(), call.level_w = level_w.data();
  call.level_row = level_row.data(), call.level_col = level_col.data();
#if defined(__AVX512F__) || defined(__AVX2__)
  // int32 texel indices, pairs of texels in a row (cols >= 2), 2^-level from the exponent bits.
  const bool vector = layers * rows * cols <= INT_MAX && cols >= 2 && levels < 127;
#endif

  const int64_t rows_total = batch * cams;
  const int threads = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(aectorch_kernel_threads(), rows_total)));
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t bc = 0; bc < rows_total; ++bc) {
    const int64_t b = bc / cams;
    const T* m = pose + bc * 16;  // row-major 4 x 4 camera-to-world
    Row<T> R = call;
    R.r00 = m[0], R.r01 = m[1], R.r02 = m[2];
    R.r10 = m[4], R.r11 = m[5], R.r12 = m[6];
    R.r20 = m[8], R.r21 = m[9], R.r22 = m[10];
    const T o0 = m[3], o1 = m[7], o2 = m[11];
    R.reach_o = px[b] - o0, R.reach_b = bg_x - o0;
    const T cy = py == nullptr ? obj_cy : obj_cy + py[b];
    R.uo0 = (cy + T(0.5) * obj_w - o1) / obj_w, R.vo0 = (obj_cz + T(0.5) * obj_h - o2) / obj_h;
    R.ub0 = (bg_cy + T(0.5) * bg_w - o1) / bg_w, R.vb0 = (bg_cz + T(0.5) * bg_h - o2) / bg_h;
    R.ro_w = R.reach_o / obj_w, R.ro_h = R.reach_o / obj_h, R.rb_w = R.reach_b / bg_w, R.rb_h = R.reach_b / bg_h;
    R.object_layer = index[b];
    R.dst = result + bc * pixels;
#if defined(__AVX512F__) || defined(__AVX2__)
    if (vector) {
      render_row_simd<typename VecOf<T>::type>(R);
      continue;
    }
#endif
    render_row_scalar(R);
  }
}

at::Tensor render_trilinear(const at::Tensor& poses, const at::Tensor& plane_x, const at::Tensor& texture_index,
                            const at::Tensor& atlas, const at::Tensor& xs, const at::Tensor& ys,
                            const at::Tensor& steps, at::ArrayRef<double> scene, int64_t tex_h, int64_t tex_w,
                            int64_t levels, double lod_bias, int64_t samples,
                            const std::optional<at::Tensor>& plane_y) {
  TORCH_CHECK(poses.dim() == 4 && poses.size(2) == 4 && poses.size(3) == 4, "poses must be [B, C, 4, 4]");
  TORCH_CHECK(atlas.dim() == 3, "atlas must be [L, H, W]");
  TORCH_CHECK(scene.size() == 9, "scene must hold 9 numbers");
  TORCH_CHECK(samples >= 1, "samples must be >= 1");
  auto dtype = poses.scalar_type();
  auto p = poses.contiguous();
  auto x = plane_x.to(dtype).contiguous();
  TORCH_CHECK(!plane_y.has_value() || plane_y->numel() == poses.size(0), "plane_y must be [B]");
  const at::Tensor y = plane_y.has_value() ? plane_y->to(dtype).contiguous() : at::Tensor();
  auto idx = texture_index.to(at::kLong).contiguous();
  auto a = atlas.to(dtype).contiguous();
  auto cx = xs.to(dtype).contiguous(), cy = ys.to(dtype).contiguous(), st = steps.to(dtype).contiguous();
  auto out = at::empty({poses.size(0), poses.size(1), xs.size(0)}, poses.options());
  std::vector<double> sc(scene.begin(), scene.end());
  AT_DISPATCH_FLOATING_TYPES(dtype, "render_trilinear", [&] {
    render<scalar_t>(p, x, idx, a, cx, cy, st, sc, tex_h, tex_w, levels, lod_bias, samples,
                     plane_y.has_value() ? &y : nullptr, out);
  });
  return out;
}

// aectorch.sim.env.pyramid_blur's 3-tap kernel [side, centre, side] along the rows and then the
// columns of images [N, H, W] (contiguous) over the valid region: [N, H - 2, W - 2]. Each value is
// torch's arithmetic, operation by operation (x * centre + (left + right) * side, each product and
// sum rounded to T, no fused multiply-add: -ffp-contract=off), so the bits are those of the
// eight elementwise torch operations it replaces. Images are split over the threads from 2^20
// values (B = 32's largest call has 113k: there a second thread cost more than it saved,
// benchmarks/kernels_ab.py).
at::Tensor pyramid_blur(const at::Tensor& images, double centre, double side) {
  TORCH_CHECK(images.dim() == 3 && images.size(1) >= 3 && images.size(2) >= 3,
              "aectorch::pyramid_blur expects images [N, H, W] with H, W >= 3, got ", images.sizes());
  const auto x = images.detach().contiguous();
  const int64_t n = x.size(0), h = x.size(1), w = x.size(2), oh = h - 2, ow = w - 2;
  auto out = at::empty({n, oh, ow}, x.options());
  const int threads = static_cast<int>(std::max<int64_t>(
      1, std::min<int64_t>({static_cast<int64_t>(aectorch_kernel_threads()), n, n * h * w / (1 << 20) + 1})));
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "aectorch_pyramid_blur", [&] {
    const scalar_t c = static_cast<scalar_t>(centre), a = static_cast<scalar_t>(side);
    const scalar_t* xs = x.const_data_ptr<scalar_t>();
    scalar_t* os = out.data_ptr<scalar_t>();
    _Pragma("omp parallel num_threads(threads)")  // (in a macro argument: _Pragma, not #pragma)
    {
      std::vector<scalar_t> rows(h * ow);  // the first pass: along each row, [H, W - 2]
      _Pragma("omp for schedule(static)")
      for (int64_t i = 0; i < n; ++i) {
        const scalar_t* img = xs + i * h * w;
        for (int64_t r = 0; r < h; ++r) {
          const scalar_t* __restrict in = img + r * w;
          scalar_t* __restrict o = rows.data() + r * ow;
          for (int64_t q = 0; q < ow; ++q) {
            const scalar_t centred = in[q + 1] * c, sides = (in[q] + in[q + 2]) * a;
            o[q] = centred + sides;
          }
        }
        scalar_t* dst = os + i * oh * ow;
        for (int64_t r = 0; r < oh; ++r) {
          const scalar_t* __restrict up = rows.data() + r * ow;
          const scalar_t* __restrict mid = up + ow;
          const scalar_t* __restrict down = mid + ow;
          scalar_t* __restrict o = dst + r * ow;
          for (int64_t q = 0; q < ow; ++q) {
            const scalar_t centred = mid[q] * c, sides = (up[q] + down[q]) * a;
            o[q] = centred + sides;
          }
        }
      }
    }
  });
  return out;
}

}  // namespace

TORCH_LIBRARY_FRAGMENT(aectorch, m) {
  m.def("render_trilinear(Tensor poses, Tensor plane_x, Tensor texture_index, Tensor atlas, Tensor xs, "
        "Tensor ys, Tensor steps, float[] scene, int tex_h, int tex_w, int levels, float lod_bias, int samples, "
        "Tensor? plane_y=None)"
        " -> Tensor");
  m.def("pyramid_blur(Tensor images, float centre, float side) -> Tensor");
}

TORCH_LIBRARY_IMPL(aectorch, CPU, m) {
  m.impl("render_trilinear", &render_trilinear);
  m.impl("pyramid_blur", &pyramid_blur);
}
