// Fused CPU kernels of aectorch's greedy pursuits (matching pursuit and Batch-OMP).
//
// The torch implementation in aectorch/coding/batch_omp.py runs each coding step as ~20-45 tensor ops over a
// [block, N] tile of correlations; on CPU every op pays dispatch overhead and one more pass
// over the tile. Here one signal's whole coding runs in one loop nest while its N correlations
// sit in L1: select (max |alpha|, first index on ties, exactly torch.argmax's rule), record,
// and update through one (MP) or i (OMP) rows of the Gram matrix, which stays in L2.
// The correlations X D are a BLAS product per tile of rows (oneDNN for float32, else at::mm), threads
// split the rows.
//
// The algorithm is the one documented in coding/batch_omp.py (same stops as scikit-learn's
// orthogonal_mp_gram); only the order of floating-point sums differs.
//
// Registered as the operator aectorch::sparse_code so that torch.compile traces it (a fake
// implementation for shapes lives in aectorch/ops/native.py).

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <ATen/ThreadLocalState.h>
#include <ATen/core/dispatch/Dispatcher.h>
#include <torch/library.h>

#include <algorithm>
#if defined(__AVX512F__)
#include <immintrin.h>
#endif
#include <atomic>
#include <pthread.h>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <tuple>
#include <type_traits>
#include <utility>
#include <optional>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

// Threads of the fused kernels (set by aectorch.ops.native.set_threads; 1 by default): their
// loops split rows over OpenMP threads of their own, so torch's intra-op threads (which do not
// pay for the many small ops of a training iteration) can stay at 1 while these use every core.
static std::atomic<int> g_kernel_threads{1};
int aectorch_kernel_threads() { return g_kernel_threads.load(); }

// A fork's child has none of the parent's OpenMP threads, but libgomp still counts them: a second
// thread in a child would wait for them forever. Children run the kernels on one thread (as torch
// does its own operations in a DataLoader's workers); set_threads gives them more again.
static const int g_fork_guard = [] {
  pthread_atfork(nullptr, nullptr, [] { g_kernel_threads.store(1); });
  return 0;
}();

namespace {

// Vectors of 64 bytes with AVX-512, else 32 (AVX2, or two SSE registers). Results never depend
// on the width: every reduction below gives the same answer whatever the grouping of lanes.
#if defined(__AVX512F__)
constexpr int kVectorBytes = 64;
#else
constexpr int kVectorBytes = 32;
#endif

// The largest of the lanes' magnitudes (> 0) and the smallest index among the lanes that hold it:
// (0, n) when every lane is 0. With AVX-512 two reductions, else a loop over the lanes.
template <typename T, typename V, typename VI>
inline void merge_lanes(const V& best_lane, const VI& where, int64_t n, T* best, int64_t* at) {
  constexpr int kLanes = sizeof(V) / sizeof(T);
#if defined(__AVX512F__)
  if constexpr (sizeof(V) == 64) {
    if constexpr (sizeof(T) == 4) {
      __m512 b;
      __m512i w;
      std::memcpy(&b, &best_lane, 64);
      std::memcpy(&w, &where, 64);
      const float top = _mm512_reduce_max_ps(b);
      *best = 0;
      *at = n;
      if (top > 0) {
        *best = top;
        *at = _mm512_mask_reduce_min_epi32(_mm512_cmp_ps_mask(b, _mm512_set1_ps(top), _CMP_EQ_OQ), w);
      }
    } else {
      __m512d b;
      __m512i w;
      std::memcpy(&b, &best_lane, 64);
      std::memcpy(&w, &where, 64);
      const double top = _mm512_reduce_max_pd(b);
      *best = 0;
      *at = n;
      if (top > 0) {
        *best = top;
        *at = _mm512_mask_reduce_min_epi64(_mm512_cmp_pd_mask(b, _mm512_set1_pd(top), _CMP_EQ_OQ), w);
      }
    }
    return;
  }
#endif
  T b = 0;
  int64_t a = n;  // no value > 0 seen yet
  for (int l = 0; l < kLanes; ++l) {
    const T v = best_lane[l];
    if (v > b || (v == b && v > 0 && where[l] < a)) {
      b = v;
      a = where[l];
    }
  }
  *best = b;
  *at = a;
}

// One vector's step of a lane-wise argmax |a|: each lane keeps its largest magnitude and the first
// index that reached it (a strict comparison keeps the earlier index on ties); index moves on to
// the next vector's.
template <typename V, typename VI>
inline void keep_largest(V a, V& best_lane, VI& where, VI& index) {
  constexpr int kLanes = sizeof(V) / sizeof(a[0]);
  const V v = a < 0 ? -a : a;
  const VI better = v > best_lane;
  best_lane = better ? v : best_lane;
  where = better ? index : where;
  index += kLanes;
}

// Index and value of the largest |a[j]|, the first one on ties (torch.argmax's rule).
// One pass in GCC/Clang vector types (keep_largest), then the lanes are merged, ties going to the
// smaller index. The compilers do not vectorise this from scalar code
// (it ran 3.4x slower).
template <typename T>
inline int64_t argmax_abs(const T* a, int64_t n, T* value) {
  using I = std::conditional_t<sizeof(T) == 4, int32_t, int64_t>;
  constexpr int kBytes = kVectorBytes;
  constexpr int kLanes = kBytes / sizeof(T);
  typedef T V __attribute__((vector_size(kBytes)));
  typedef I VI __attribute__((vector_size(kBytes)));
  V best_lane = {};
  VI where = {};
  VI index;
  for (int l = 0; l < kLanes; ++l) index[l] = l;
  int64_t j = 0;
  for (; j + kLanes <= n; j += kLanes) {
    V v;
    std::memcpy(&v, a + j, sizeof(V));
    keep_largest(v, best_lane, where, index);
  }
  T best;
  int64_t at;
  merge_lanes<T>(best_lane, where, n, &best, &at);
  for (; j < n; ++j) {  // the tail comes after every lane's indices
    const T v = std::abs(a[j]);
    if (v > best) {
      best = v;
      at = j;
    }
  }
  if (at == n) at = 0;  // every |a| is 0 (or NaN, which inputs are checked against)
  *value = a[at];
  return at;
}

// One pass of a coding step, then the next step's selection in the same pass:
// alpha[j] = ((alpha[j] - s[0] rows[0][j]) - s[1] rows[1][j]) - ... (the rows in order: the same
// roundings as `count` separate passes alpha -= s[c] rows[c]), alpha[zero_at] = 0 (none when
// zero_at < 0), then the index and value of the largest |alpha[j]| with argmax_abs's rule (the
// first index on ties). alpha is read and written once per step, not once per row of G, and four
// vectors are updated side by side, so that their chains of subtractions overlap (one vector at a
// time waits for each subtraction's latency, count times).
template <typename T>
inline int64_t update_argmax_abs(T* __restrict alpha, const T* const* rows, const T* s, int64_t count,
                                 int64_t zero_at, int64_t n, T* value) {
  using I = std::conditional_t<sizeof(T) == 4, int32_t, int64_t>;
  constexpr int kBytes = kVectorBytes;
  constexpr int kLanes = kBytes / sizeof(T);
  typedef T V __attribute__((vector_size(kBytes)));
  typedef I VI __attribute__((vector_size(kBytes)));
  V best_lane = {};
  VI where = {};
  VI index;
  for (int l = 0; l < kLanes; ++l) index[l] = l;
  const I zero = static_cast<I>(zero_at);
  int64_t j = 0;
  // Four vectors side by side (their chains of subtractions overlap), then one at a time.
  for (; j + 4 * kLanes <= n; j += 4 * kLanes) {
    V a0, a1, a2, a3;
    std::memcpy(&a0, alpha + j, sizeof(V));
    std::memcpy(&a1, alpha + j + kLanes, sizeof(V));
    std::memcpy(&a2, alpha + j + 2 * kLanes, sizeof(V));
    std::memcpy(&a3, alpha + j + 3 * kLanes, sizeof(V));
    for (int64_t c = 0; c < count; ++c) {
      const V sc = V{} + s[c];
      const T* g = rows[c] + j;
      V g0, g1, g2, g3;
      std::memcpy(&g0, g, sizeof(V));
      std::memcpy(&g1, g + kLanes, sizeof(V));
      std::memcpy(&g2, g + 2 * kLanes, sizeof(V));
      std::memcpy(&g3, g + 3 * kLanes, sizeof(V));
      a0 = a0 - sc * g0;
      a1 = a1 - sc * g1;
      a2 = a2 - sc * g2;
      a3 = a3 - sc * g3;
    }
    const V* parts[4] = {&a0, &a1, &a2, &a3};
    for (int u = 0; u < 4; ++u) {
      V a = *parts[u];
      a = index == zero ? V{} : a;
      std::memcpy(alpha + j + u * kLanes, &a, sizeof(V));
      keep_largest(a, best_lane, where, index);
    }
  }
  for (; j + kLanes <= n; j += kLanes) {
    V a;
    std::memcpy(&a, alpha + j, sizeof(V));
    for (int64_t c = 0; c < count; ++c) {
      V g;
      std::memcpy(&g, rows[c] + j, sizeof(V));
      a = a - (V{} + s[c]) * g;
    }
    a = index == zero ? V{} : a;
    std::memcpy(alpha + j, &a, sizeof(V));
    keep_largest(a, best_lane, where, index);
  }
  T best;
  int64_t at;
  merge_lanes<T>(best_lane, where, n, &best, &at);
  for (; j < n; ++j) {  // the tail comes after every lane's indices
    T a = alpha[j];
    for (int64_t c = 0; c < count; ++c) a -= s[c] * rows[c][j];
    if (j == zero_at) a = 0;
    alpha[j] = a;
    const T v = std::abs(a);
    if (v > best) {
      best = v;
      at = j;
    }
  }
  if (at == n) at = 0;  // every |a| is 0 (or NaN, which inputs are checked against)
  *value = alpha[at];
  return at;
}

// MP of R consecutive rows of correlations alpha [R, n], their codes into idx, coef [R, k]. The rows'
// steps are taken in turn: each step ends in a chain of reductions (the lanes' maximum, then its
// index) that the row's next step waits for, and the other rows' steps fill that wait (out-of-order
// execution overlaps them). Each row's arithmetic is the same for any R: the same codes.
template <typename T, int R>
void mp_rows(T* alpha, const T* gram, int64_t n, int64_t k, int64_t* idx, T* coef) {
  T c[R];
  int64_t lam[R];
  for (int r = 0; r < R; ++r) lam[r] = argmax_abs(alpha + r * n, n, &c[r]);
  for (int64_t i = 0; i < k; ++i) {
    for (int r = 0; r < R; ++r) {
      idx[r * k + i] = lam[r];
      coef[r * k + i] = c[r];
    }
    if (i + 1 < k) {
      for (int r = 0; r < R; ++r) {  // alpha -= c G[lam], and the next selection
        const T* row = gram + lam[r] * n;
        const T s = c[r];
        lam[r] = update_argmax_abs(alpha + r * n, &row, &s, 1, -1, n, &c[r]);
      }
    }
  }
}

// Batch-OMP with the inverse Cholesky factor Linv of G[I, I] (row-major, k x k, lower).
// work: k * k + 4 * k values of T; rows: k pointers.
template <typename T>
void omp_row(T* alpha, const T* gram, int64_t n, int64_t k, int64_t* idx, T* coef, T* work, const T** rows) {
  const T eps = std::numeric_limits<T>::epsilon();
  T* linv = work;         // [k, k]
  T* y = linv + k * k;    // coordinates along the orthonormalised chosen atoms
  T* w = y + k;           // Linv G[I, lam]
  T* g = w + k;           // G[I, lam]
  T* scale = g + k;       // the update's multiples of G[I_c] (rows[c])
  std::fill(linv, linv + k * k, T(0));
  int64_t used = 0;
  T a;
  int64_t lam = argmax_abs(alpha, n, &a);
  for (int64_t i = 0; i < k; ++i) {
    T lkk = gram[lam * n + lam];
    for (int64_t r = 0; r < i; ++r) g[r] = gram[idx[r] * n + lam];
    for (int64_t r = 0; r < i; ++r) {
      T s = 0;
      for (int64_t c = 0; c <= r; ++c) s += linv[r * k + c] * g[c];
      w[r] = s;
      lkk -= s * s;
    }
    // scikit-learn's stops: residual correlation below eps, or an atom dependent on the
    // chosen ones. Remaining slots keep index 0 and coefficient 0.
    if (!(a * a >= eps) || !(lkk > eps)) break;
    const T inv = T(1) / std::sqrt(lkk);
    for (int64_t c = 0; c < i; ++c) {  // row i of Linv: -(w^T Linv[:i, :i]) / L_ii
      T s = 0;
      for (int64_t r = c; r < i; ++r) s += w[r] * linv[r * k + c];
      linv[i * k + c] = -s * inv;
    }
    linv[i * k + i] = inv;
    idx[i] = lam;
    y[i] = a * inv;
    used = i + 1;
    if (i + 1 < k) {  // alpha -= y_i (D^T q_i), D^T q_i = sum_c Linv[i, c] G[I_c]; the next selection
      for (int64_t c = 0; c <= i; ++c) {
        rows[c] = gram + idx[c] * n;
        scale[c] = y[i] * linv[i * k + c];
      }
      // alpha[lam] = 0: exact in arithmetic; no rounding residue
      lam = update_argmax_abs(alpha, rows, scale, i + 1, lam, n, &a);
    }
  }
  for (int64_t c = 0; c < used; ++c) {  // gamma = Linv^T y
    T s = 0;
    for (int64_t r = c; r < used; ++r) s += linv[r * k + c] * y[r];
    coef[c] = s;
  }
}

// The Gram matrix D^T D of atoms [P, N] (contiguous) is computed in `gram_blocks(N)` blocks of rows,
// each a BLAS product D[:, block]^T D (`gram_block`, oneDNN's or torch's as below): two blocks (one
// when N < 64) on up to two threads. The blocks do not depend on the number of threads, so neither
// does the result.
inline int64_t gram_blocks(int64_t n) { return n >= 64 ? 2 : 1; }

// float32 products through oneDNN (torch's mkldnn::_linear_pointwise, x W^T), unless torch lacks it
// or AECTORCH_ONEDNN=0: torch's at::mm calls MKL, which on AMD CPUs runs its AVX2 code even where
// the CPU has AVX-512 (half of oneDNN's rate on an AMD EPYC with AVX-512; at AVX2 the two ran at
// about the same rate: benchmarks/stages.py records both). The products sum in another order than
// MKL's: not the same bits as torch's `x @ d`, but the same on any number of threads (each
// product's operands do not depend on it).
using LinearFn = at::Tensor(const at::Tensor&, const at::Tensor&, const std::optional<at::Tensor>&,
                            c10::string_view, c10::List<std::optional<at::Scalar>>,
                            std::optional<c10::string_view>);

const c10::TypedOperatorHandle<LinearFn>* onednn_linear() {
  using Handle = std::optional<c10::TypedOperatorHandle<LinearFn>>;
  static const Handle handle = []() -> Handle {
    const char* flag = std::getenv("AECTORCH_ONEDNN");
    if (flag != nullptr && std::string(flag) == "0") return std::nullopt;
    auto found = c10::Dispatcher::singleton().findSchema({"mkldnn::_linear_pointwise", ""});
    if (!found.has_value()) return std::nullopt;
    return found->typed<LinearFn>();
  }();
  return handle.has_value() ? &*handle : nullptr;
}

// Whether the products of `x`'s dtype run in oneDNN.
inline bool onednn_products(const at::Tensor& x) {
  return x.scalar_type() == at::kFloat && onednn_linear() != nullptr;
}

// x w^T in oneDNN, for x [R, P] and w [N, P] (both contiguous).
inline at::Tensor linear_t(const at::Tensor& x, const at::Tensor& w) {
  return onednn_linear()->call(x, w, std::nullopt, "none", c10::List<std::optional<at::Scalar>>(),
                               std::nullopt);
}

// The Gram block of rows [lo, hi): D[:, lo:hi]^T D of atoms `d` [P, N], or (oneDNN) of their
// transpose `dt` [N, P].
inline void gram_block(at::Tensor& out, const at::Tensor& d, const at::Tensor& dt, int64_t b, int64_t blocks) {
  const int64_t n = d.size(1), lo = n * b / blocks, hi = n * (b + 1) / blocks;
  auto part = out.narrow(0, lo, hi - lo);
  if (onednn_products(d)) {
    part.copy_(linear_t(dt.narrow(0, lo, hi - lo), dt));
  } else {
    at::mm_out(part, d.narrow(1, lo, hi - lo).t(), d);
  }
}

// The checks and the contiguous operands of sparse_code and encode. Without a gram, `g` is memory for
// the caller to fill (`gram_block`) before the coders read it.
struct CoderInputs {
  at::Tensor x, d, g, dt;  // dt: memory for the atoms transposed, [N, P] (pursue fills it)
  int64_t m, n;
  bool gram_given;
};

CoderInputs coder_inputs(const char* op, const at::Tensor& signals, const at::Tensor& dictionary,
                             const std::optional<at::Tensor>& gram, int64_t k) {
  TORCH_CHECK(signals.dim() == 2 && dictionary.dim() == 2 && (!gram.has_value() || gram->dim() == 2),
              op, " expects signals [M, P], dictionary [P, N] and gram [N, N]");
  TORCH_CHECK(signals.scalar_type() == dictionary.scalar_type() &&
                  (!gram.has_value() || signals.scalar_type() == gram->scalar_type()),
              op, ": signals, dictionary and gram must share one dtype");
  // Detached: the codes are not differentiable (the torch code's support is a constant too), and a
  // worker thread must not see an input that requires grad in an out= product.
  CoderInputs in{signals.detach().contiguous(), dictionary.detach().contiguous(), at::Tensor(), at::Tensor(),
                   0, 0, gram.has_value()};
  in.m = in.x.size(0);
  in.n = in.d.size(1);
  in.g = gram.has_value() ? gram->detach().contiguous() : at::empty({in.n, in.n}, in.d.options());
  in.dt = at::empty({in.n, in.d.size(0)}, in.d.options());
  TORCH_CHECK(in.x.size(1) == in.d.size(0) && in.g.size(0) == in.n && in.g.size(1) == in.n,
              op, ": shapes do not match");
  TORCH_CHECK(k >= 1 && k <= in.n, op, ": k must be in [1, N]");
  return in;
}

// The sparse codes of M signals in tiles of rows, inside one OpenMP region: `before` (run by every
// thread; it may hold worksharing loops of its own), then the tiles (each thread takes whole
// tiles: its own correlations X D, a BLAS product, and each row's coding, after which `row_done(row)`
// runs while the row is in cache), then `after` (likewise). An even number of equal tiles, each at
// most `block` rows (at least two from 256 rows): two threads get the same work (1568 rows are 4
// tiles of 392, not 3 of 512 and one of 32). The tiling does not depend on the number of threads,
// so neither do the codes, whatever the BLAS.
template <typename T, typename Before, typename RowDone, typename After>
void pursue(const CoderInputs& in, int64_t k, bool orthogonal, int64_t block, int64_t* idx, T* coef,
            Before&& before, RowDone&& row_done, After&& after) {
  const int64_t m = in.m, n = in.n;
  block = std::max<int64_t>(1, std::min<int64_t>(block, m));
  int64_t tiles = (m + block - 1) / block;
  if (m >= 256) tiles = std::max<int64_t>(tiles, 2);
  if (tiles > 1 && tiles % 2) ++tiles;
  block = (m + tiles - 1) / tiles;
  tiles = (m + block - 1) / block;
  const int64_t available = std::max<int64_t>(1, std::min<int64_t>(aectorch_kernel_threads(), m));
  const int threads = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(available, tiles)));
  const at::ThreadLocalState caller_state;
  const T* g = in.g.const_data_ptr<T>();
  _Pragma("omp parallel num_threads(threads)")  // (in a macro argument: _Pragma, not #pragma)
  {
    // The caller's grad / inference mode and dispatch state, as at::parallel_for passes them on.
    at::ThreadLocalStateGuard state_guard(caller_state);
    {  // the atoms transposed (the products' weights, the reconstructions' rows), before `before`
      const int64_t p = in.d.size(0);
      const T* ds = in.d.const_data_ptr<T>();
      T* ts = in.dt.data_ptr<T>();
      _Pragma("omp for schedule(static)")  // (its implicit barrier: every atom's row is ready)
      for (int64_t c = 0; c < n; ++c)
        for (int64_t r = 0; r < p; ++r) ts[c * p + r] = ds[r * n + c];
    }
    before();
    const bool onednn = onednn_products(in.x);
    auto alpha = onednn ? at::Tensor() : at::empty({block, n}, in.x.options());
    std::vector<T> work(orthogonal ? k * k + 4 * k : 0);
    std::vector<const T*> gram_rows(orthogonal ? k : 0);
    _Pragma("omp for schedule(static)")
    for (int64_t t = 0; t < tiles; ++t) {
      const int64_t start = t * block;
      const int64_t rows = std::min(block, m - start);
      at::Tensor tile;
      if (onednn) {
        tile = linear_t(in.x.narrow(0, start, rows), in.dt);
      } else {
        tile = alpha.narrow(0, 0, rows);
        at::mm_out(tile, in.x.narrow(0, start, rows), in.d);
      }
      T* a = tile.data_ptr<T>();
      int64_t r = 0;
      if (!orthogonal) {  // MP: two rows at a time (mp_rows), the same codes as one at a time
        for (; r + 1 < rows; r += 2) {
          const int64_t row = start + r;
          mp_rows<T, 2>(a + r * n, g, n, k, idx + row * k, coef + row * k);
          row_done(row);
          row_done(row + 1);
        }
      }
      for (; r < rows; ++r) {
        const int64_t row = start + r;
        if (orthogonal) {
          omp_row(a + r * n, g, n, k, idx + row * k, coef + row * k, work.data(), gram_rows.data());
        } else {
          mp_rows<T, 1>(a + r * n, g, n, k, idx + row * k, coef + row * k);
        }
        row_done(row);
      }
    }
    after();
  }
}

std::tuple<at::Tensor, at::Tensor> sparse_code(
    const at::Tensor& signals, const at::Tensor& dictionary, const at::Tensor& gram, int64_t k,
    bool orthogonal, int64_t block) {
  const auto in = coder_inputs("aectorch::sparse_code", signals, dictionary, std::optional<at::Tensor>(gram), k);
  auto indices = at::zeros({in.m, k}, in.x.options().dtype(at::kLong));
  auto coefficients = at::zeros({in.m, k}, in.x.options());
  if (in.m == 0) return {indices, coefficients};
  AT_DISPATCH_FLOATING_TYPES(in.x.scalar_type(), "aectorch_sparse_code", [&] {
    auto nothing = [] {};
    pursue<scalar_t>(in, k, orthogonal, block, indices.data_ptr<int64_t>(), coefficients.data_ptr<scalar_t>(),
                     nothing, [](int64_t) {}, nothing);
  });
  return {indices, coefficients};
}

// The Gram matrix D^T D of atoms [P, N] (`gram_block`), on up to two of the kernels' threads.
at::Tensor gram(const at::Tensor& atoms) {
  TORCH_CHECK(atoms.dim() == 2, "aectorch::gram expects atoms [P, N]");
  const auto d = atoms.detach().contiguous();
  const int64_t n = d.size(1);
  auto out = at::empty({n, n}, d.options());
  const int64_t blocks = gram_blocks(n);
  const auto dt = onednn_products(d) ? d.t().contiguous() : at::Tensor();
  const int threads = static_cast<int>(std::min<int64_t>(blocks, aectorch_kernel_threads()));
  const at::ThreadLocalState caller_state;
  _Pragma("omp parallel for num_threads(threads) schedule(static)")
  for (int64_t b = 0; b < blocks; ++b) {
    at::ThreadLocalStateGuard state_guard(caller_state);
    gram_block(out, d, dt, b, blocks);
  }
  return out;
}

// Sums over a row in 8 independent lanes, added up at the end: the compiler vectorises these (a
// single running sum is one add per element at the add's latency, since without -ffast-math it may
// not reorder it), and the order of the additions is fixed, the same on every CPU and thread count.
constexpr int kLanes = 8;

template <typename T>
inline T lanes_total(const T* acc) {
  T s = 0;
  for (int l = 0; l < kLanes; ++l) s += acc[l];
  return s;
}

template <typename T>
inline T row_sum_squares(const T* __restrict a, int64_t n) {
  T acc[kLanes] = {};
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes)
    for (int l = 0; l < kLanes; ++l) acc[l] += a[i + l] * a[i + l];
  T s = lanes_total(acc);
  for (; i < n; ++i) s += a[i] * a[i];
  return s;
}

template <typename T>
inline T row_sum_squared_differences(const T* __restrict a, const T* __restrict b, int64_t n) {
  T acc[kLanes] = {};
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes)
    for (int l = 0; l < kLanes; ++l) {
      const T e = a[i + l] - b[i + l];
      acc[l] += e * e;
    }
  T s = lanes_total(acc);
  for (; i < n; ++i) s += (a[i] - b[i]) * (a[i] - b[i]);
  return s;
}

// pair_patches' passes over a half, two at a time. `row_sum_max_abs`: the sum of a row in the 8 lanes
// (lanes_total's order) and, beside it, its largest magnitude; `subtract_sum`: c subtracted from
// every value in place, and the sum of the results (of their squares with `Squares`) in the same
// lanes and order. The lanes are one GCC/Clang vector: from an array of lanes the compilers had
// kept std::max's NaN rule (`acc < x ? x : acc`) lane by lane in scalar registers. A maximum is
// exact, and the sums add in the order of separate passes: the same bits as one pass each.
template <typename T>
inline T row_sum_max_abs(const T* __restrict a, int64_t n, T* max_abs) {
  typedef T Lanes __attribute__((vector_size(kLanes * sizeof(T))));
  Lanes best = {}, acc = {};
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    Lanes x;
    std::memcpy(&x, a + i, sizeof(x));
    acc += x;
    x = x < 0 ? -x : x;  // |x| (-0 stays -0, equal to +0; NaN stays NaN and never wins below)
    best = best < x ? x : best;
  }
  T lanes[kLanes], top[kLanes];
  std::memcpy(lanes, &acc, sizeof(lanes));
  std::memcpy(top, &best, sizeof(top));
  T s = lanes_total(lanes), m = 0;
  for (int l = 0; l < kLanes; ++l) m = std::max(m, top[l]);
  for (; i < n; ++i) {
    s += a[i];
    m = std::max(m, std::abs(a[i]));
  }
  *max_abs = m;
  return s;
}

template <typename T, bool Squares>
inline T subtract_sum(T* __restrict a, int64_t n, T c) {
  typedef T Lanes __attribute__((vector_size(kLanes * sizeof(T))));
  Lanes acc = {};
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    Lanes x;
    std::memcpy(&x, a + i, sizeof(x));
    x -= c;
    std::memcpy(a + i, &x, sizeof(x));
    acc += Squares ? x * x : x;
  }
  T lanes[kLanes];
  std::memcpy(lanes, &acc, sizeof(lanes));
  T s = lanes_total(lanes);
  for (; i < n; ++i) {
    a[i] -= c;
    s += Squares ? a[i] * a[i] : a[i];
  }
  return s;
}

// The rows that a scatter-add visits jump at random over a matrix that does not fit in L1, and the
// hardware prefetchers do not follow: `prefetch_row` asks for row `row` of [n, p] values at `base`
// (for writing; nothing when it lies outside) kPrefetchAhead entries before it is added to.
constexpr int64_t kPrefetchAhead = 4;
template <typename T>
inline void prefetch_row(const T* base, int64_t row, int64_t n, int64_t p) {
  if (row < 0 || row >= n) return;
  const char* start = reinterpret_cast<const char*>(base + row * p);
  const char* end = reinterpret_cast<const char*>(base + (row + 1) * p);
  for (const char* c = start; c < end; c += 64) __builtin_prefetch(c, 1, 3);
}

// y += c x over a row (a function of its own: inlined, its loop vectorises on restrict pointers).
template <typename T>
inline void axpy(T* __restrict y, const T* __restrict x, T c, int64_t n) {
  for (int64_t i = 0; i < n; ++i) y[i] += c * x[i];
}

// One signal's reconstruction r = sum_j c_j D[:, i_j] (the atoms as rows, atoms_t [N, P]) and its
// eq. (4) error ||x - r||^2 / ||x||^2 (0 for a zero signal). False if an index lies outside [0, N)
// (that atom is skipped). Shared by reconstruct_error and encode: the same arithmetic, the same bits.
template <typename T>
inline bool reconstruct_row(const T* __restrict xr, const T* ds, int64_t n, int64_t p, const int64_t* ir,
                            const T* cr, int64_t k, T* __restrict r, T* error) {
  bool ok = true;
  std::fill(r, r + p, T(0));
  for (int64_t j = 0; j < k; ++j) {
    const int64_t atom = ir[j];
    if (atom < 0 || atom >= n) { ok = false; continue; }
    axpy(r, ds + atom * p, cr[j], p);
  }
  const T energy = row_sum_squares(xr, p), residual = row_sum_squared_differences(xr, r, p);
  *error = residual / std::max(energy, std::numeric_limits<T>::min());
  return ok;
}

// Eq. (3) of one group of `patches` codes into f [N] (zeroed by the caller): the squared
// coefficients per atom, an atom picked twice in a patch summed before squaring. False if an
// index lies outside [0, N). Shared by pooled_power and encode.
template <typename T>
inline bool pool_group(const int64_t* is, const T* cs, int64_t patches, int64_t k, int64_t n, T* f) {
  bool ok = true;
  for (int64_t patch = 0; patch < patches; ++patch) {
    const int64_t* ip = is + patch * k;
    const T* cp = cs + patch * k;
    for (int64_t j = 0; j < k; ++j) {
      const int64_t atom = ip[j];
      if (atom < 0 || atom >= n) { ok = false; continue; }
      bool earlier = false;
      for (int64_t i = 0; i < j; ++i) earlier = earlier || ip[i] == atom;
      if (earlier) continue;  // added with its first pick
      T c = cp[j];
      for (int64_t i = j + 1; i < k; ++i) if (ip[i] == atom) c += cp[i];
      f[atom] += c * c;
    }
  }
  return ok;
}

// Reconstructions D a and eq. (4)'s errors ||x - D a||^2 / ||x||^2 (0 for a zero signal) of sparse
// codes, one row at a time from the atoms as rows ([N, P], the transposed dictionary): the k
// atoms' rows are summed into the output row while the signal's row is in L1. Rows are split
// over the kernels' threads; each row is computed alone, so the result does not depend on them.
std::tuple<at::Tensor, at::Tensor> reconstruct_error(
    const at::Tensor& signals, const at::Tensor& atoms_t, const at::Tensor& indices,
    const at::Tensor& coefficients) {
  TORCH_CHECK(signals.dim() == 2 && atoms_t.dim() == 2 && indices.dim() == 2 && coefficients.dim() == 2,
              "aectorch::reconstruct_error expects signals [M, P], atoms_t [N, P], indices and coefficients [M, k]");
  TORCH_CHECK(signals.scalar_type() == atoms_t.scalar_type() && signals.scalar_type() == coefficients.scalar_type(),
              "aectorch::reconstruct_error: signals, atoms_t and coefficients must share one dtype");
  TORCH_CHECK(indices.scalar_type() == at::kLong, "aectorch::reconstruct_error: indices must be int64");
  const auto x = signals.detach().contiguous();
  const auto d = atoms_t.detach().contiguous();
  const auto idx_t = indices.contiguous();
  const auto coef_t = coefficients.detach().contiguous();
  const int64_t m = x.size(0), p = x.size(1), n = d.size(0), k = idx_t.size(1);
  TORCH_CHECK(d.size(1) == p && idx_t.size(0) == m && coef_t.size(0) == m && coef_t.size(1) == k,
              "aectorch::reconstruct_error: shapes do not match");
  auto recon = at::empty({m, p}, x.options());
  auto error = at::empty({m}, x.options());
  const int threads = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(aectorch_kernel_threads(), m / 64 + 1)));
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "aectorch_reconstruct_error", [&] {
    const scalar_t* xs = x.const_data_ptr<scalar_t>();
    const scalar_t* ds = d.const_data_ptr<scalar_t>();
    const int64_t* is = idx_t.const_data_ptr<int64_t>();
    const scalar_t* cs = coef_t.const_data_ptr<scalar_t>();
    scalar_t* rs = recon.data_ptr<scalar_t>();
    scalar_t* es = error.data_ptr<scalar_t>();
    bool bad = false;
    _Pragma("omp parallel for num_threads(threads) schedule(static) reduction(||:bad)")
    for (int64_t row = 0; row < m; ++row) {
      bad = !reconstruct_row(xs + row * p, ds, n, p, is + row * k, cs + row * k, k, rs + row * p, es + row) || bad;
    }
    TORCH_CHECK(!bad, "aectorch::reconstruct_error: an index lies outside [0, N)");
  });
  return {recon, error};
}

// One signal's weighted residual w = (x - r) / ||x||^2 (||x||^2 at least the smallest normal number).
template <typename T>
inline void weighted_residual(const T* __restrict xr, const T* __restrict rr, T* __restrict w, int64_t p) {
  const T energy = std::max(row_sum_squares(xr, p), std::numeric_limits<T>::min());
  for (int64_t q = 0; q < p; ++q) w[q] = (xr[q] - rr[q]) / energy;  // (as torch's r / e rounds)
}

// sum_i c_ij (x_i - r_i) / ||x_i||^2 into row indices_ij of an [N, P] result: the gradient of eq. (4)
// from the active atoms only (k per signal) instead of a dense [P, M] x [M, N] product. First the
// weighted residuals, row by row; then each thread adds into the rows of its own atoms, visiting
// the signals in order, so the sums (and the result) do not depend on the number of threads.
at::Tensor sparse_gradient(const at::Tensor& signals, const at::Tensor& reconstruction, const at::Tensor& indices,
                           const at::Tensor& coefficients, int64_t num_atoms) {
  TORCH_CHECK(signals.dim() == 2 && reconstruction.sizes() == signals.sizes() && indices.dim() == 2 &&
                  coefficients.sizes() == indices.sizes() && indices.size(0) == signals.size(0),
              "aectorch::sparse_gradient expects signals and reconstruction [M, P], indices and coefficients [M, k]");
  TORCH_CHECK(signals.scalar_type() == reconstruction.scalar_type() && signals.scalar_type() == coefficients.scalar_type(),
              "aectorch::sparse_gradient: signals, reconstruction and coefficients must share one dtype");
  TORCH_CHECK(indices.scalar_type() == at::kLong, "aectorch::sparse_gradient: indices must be int64");
  TORCH_CHECK(num_atoms >= 1, "aectorch::sparse_gradient: num_atoms must be >= 1");
  const auto x = signals.detach().contiguous();
  const auto rec = reconstruction.detach().contiguous();
  const auto idx_t = indices.contiguous();
  const auto coef_t = coefficients.detach().contiguous();
  const int64_t m = x.size(0), p = x.size(1), k = idx_t.size(1), n = num_atoms;
  auto out = at::zeros({n, p}, x.options());
  auto weighted = at::empty({m, p}, x.options());
  // Every thread reads all M k indices to find its atoms' entries: below kThreadedGradient values of
  // signals, one thread is faster (B = 32's 1,568 x 200 patches of a scale: the training loop took
  // 0.935x and 0.969x the CPU time, 0.967x and 0.985x the wall time, with the dictionary step on one
  // thread; two runs of 30 interleaved rounds, benchmarks/gradient_threads_ab.py); at B = 256 two
  // threads are faster (docs/performance.md, the stage tables).
  constexpr int64_t kThreadedGradient = int64_t(1) << 20;
  const int threads = m * p < kThreadedGradient
      ? 1 : static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(aectorch_kernel_threads(), n)));
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "aectorch_sparse_gradient", [&] {
    const scalar_t* xs = x.const_data_ptr<scalar_t>();
    const scalar_t* recs = rec.const_data_ptr<scalar_t>();
    const int64_t* is = idx_t.const_data_ptr<int64_t>();
    const scalar_t* cs = coef_t.const_data_ptr<scalar_t>();
    scalar_t* ws = weighted.data_ptr<scalar_t>();
    scalar_t* os = out.data_ptr<scalar_t>();
    bool bad = false;
    _Pragma("omp parallel num_threads(threads) reduction(||:bad)")
    {
      _Pragma("omp for schedule(static)")
      for (int64_t row = 0; row < m; ++row) {
        const scalar_t* __restrict xr = xs + row * p;
        const scalar_t* __restrict rr = recs + row * p;
        scalar_t* __restrict w = ws + row * p;
        weighted_residual(xr, rr, w, p);
      }
      // (the implicit barrier of the loop above: every weighted row is ready)
      int nthreads = 1, me = 0;
#ifdef _OPENMP
      nthreads = omp_get_num_threads();
      me = omp_get_thread_num();
#endif
      const int64_t lo = n * me / nthreads, hi = n * (me + 1) / nthreads;
      for (int64_t e = 0; e < m * k; ++e) {
        const int64_t atom = is[e];
        if (atom < lo || atom >= hi) {
          if (atom < 0 || atom >= n) bad = true;
          continue;
        }
        axpy(os + atom * p, ws + (e / k) * p, cs[e], p);
      }
    }
    TORCH_CHECK(!bad, "aectorch::sparse_gradient: an index lies outside [0, num_atoms)");
  });
  return out;
}

// Eq. (3): f_gn = sum over the patches of group g of (the patch's coefficient of atom n)^2, the
// coefficients of an atom picked twice in a patch (plain MP) added before squaring, as a dense code
// would; from the k (index, coefficient) pairs of each patch, without the dense [G, patches, N] code.
// Groups are split over the threads; each group's sum runs over its patches in order.
at::Tensor pooled_power(const at::Tensor& indices, const at::Tensor& coefficients, int64_t num_atoms) {
  TORCH_CHECK(indices.dim() == 3 && coefficients.sizes() == indices.sizes(),
              "aectorch::pooled_power expects indices and coefficients [G, patches, k]");
  TORCH_CHECK(indices.scalar_type() == at::kLong, "aectorch::pooled_power: indices must be int64");
  TORCH_CHECK(num_atoms >= 1, "aectorch::pooled_power: num_atoms must be >= 1");
  const auto idx_t = indices.contiguous();
  const auto coef_t = coefficients.detach().contiguous();
  const int64_t groups = idx_t.size(0), patches = idx_t.size(1), k = idx_t.size(2), n = num_atoms;
  auto out = at::zeros({groups, n}, coef_t.options());
  const int threads = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(aectorch_kernel_threads(), groups)));
  AT_DISPATCH_FLOATING_TYPES(coef_t.scalar_type(), "aectorch_pooled_power", [&] {
    const int64_t* is = idx_t.const_data_ptr<int64_t>();
    const scalar_t* cs = coef_t.const_data_ptr<scalar_t>();
    scalar_t* os = out.data_ptr<scalar_t>();
    bool bad = false;
    _Pragma("omp parallel for num_threads(threads) schedule(static) reduction(||:bad)")
    for (int64_t g = 0; g < groups; ++g) {
      bad = !pool_group(is + g * patches * k, cs + g * patches * k, patches, k, n, os + g * n) || bad;
    }
    TORCH_CHECK(!bad, "aectorch::pooled_power: an index lies outside [0, num_atoms)");
  });
  return out;
}

// Encode in one pass: the Gram matrix (unless given; aectorch::gram's blocks), aectorch::sparse_code's
// codes; for each signal, as soon as its coding ends (the signal still in cache), reconstruct_error's
// reconstruction and error; after every signal, pooled_power's eq. (3) features of the `groups`
// consecutive groups of M / groups signals. One OpenMP region instead of four, with the atoms
// transposed (the reconstructions' rows) inside it rather than by a strided torch copy. The same
// arithmetic as those operators: the same bits.
std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor> encode(
    const at::Tensor& signals, const at::Tensor& dictionary, const std::optional<at::Tensor>& gram, int64_t k,
    bool orthogonal, int64_t block, int64_t groups) {
  auto in = coder_inputs("aectorch::encode", signals, dictionary, gram, k);
  const int64_t m = in.m, n = in.n, p = in.x.size(1);
  TORCH_CHECK(groups >= 1 && m % groups == 0, "aectorch::encode: groups must be >= 1 and divide the ", m,
              " signals, got ", groups);
  auto indices = at::zeros({m, k}, in.x.options().dtype(at::kLong));
  auto coefficients = at::zeros({m, k}, in.x.options());
  auto recon = at::empty({m, p}, in.x.options());
  auto error = at::empty({m}, in.x.options());
  auto pooled = at::zeros({groups, n}, in.x.options());
  if (m == 0) return {indices, coefficients, recon, error, pooled};
  const int64_t blocks = in.gram_given ? 0 : gram_blocks(n);  // the Gram matrix's blocks to compute
  const int64_t patches = m / groups;
  AT_DISPATCH_FLOATING_TYPES(in.x.scalar_type(), "aectorch_encode", [&] {
    const scalar_t* xs = in.x.const_data_ptr<scalar_t>();
    const scalar_t* ts = in.dt.const_data_ptr<scalar_t>();  // (pursue transposes the atoms first)
    int64_t* idx = indices.data_ptr<int64_t>();
    scalar_t* coef = coefficients.data_ptr<scalar_t>();
    scalar_t* rs = recon.data_ptr<scalar_t>();
    scalar_t* es = error.data_ptr<scalar_t>();
    scalar_t* os = pooled.data_ptr<scalar_t>();
    pursue<scalar_t>(
        in, k, orthogonal, block, idx, coef,
        [&] {
          _Pragma("omp for schedule(static)")  // (its implicit barrier: the Gram matrix is ready)
          for (int64_t b = 0; b < blocks; ++b) gram_block(in.g, in.d, in.dt, b, blocks);
        },
        [&](int64_t row) {  // (the code's indices always lie in [0, N))
          reconstruct_row(xs + row * p, ts, n, p, idx + row * k, coef + row * k, k, rs + row * p, es + row);
        },
        [&] {
          _Pragma("omp for schedule(static)")
          for (int64_t g = 0; g < groups; ++g)
            pool_group(idx + g * patches * k, coef + g * patches * k, patches, k, n, os + g * n);
        });
  });
  return {indices, coefficients, recon, error, pooled};
}

// The coder's patches of reduced image pairs in one pass (aectorch.coding.patches._cut): images
// [2B, H, W], first images at even rows; the g x g grid of p x p patches with the given stride,
// from (offset, offset); each half centred twice (the second pass removes the first one's rounding),
// divided by its norm, or 0 when it is flat (norm <= eps + rounding * max |pixel|). Output
// [B, g g, 2 p p]: for each patch the first image's half, then the second's. Rows are split over
// the threads; each patch is computed alone.
at::Tensor pair_patches(const at::Tensor& images, int64_t offset, int64_t p, int64_t stride, int64_t g,
                        double eps, double rounding) {
  TORCH_CHECK(images.dim() == 3 && images.size(0) % 2 == 0,
              "aectorch::pair_patches expects images [2B, H, W]");
  TORCH_CHECK(p >= 1 && stride >= 1 && g >= 1 && offset >= 0 &&
                  offset + (g - 1) * stride + p <= std::min(images.size(1), images.size(2)),
              "aectorch::pair_patches: the grid does not fit the images");
  const auto x = images.detach().contiguous();
  const int64_t b = x.size(0) / 2, h = x.size(1), w = x.size(2), n = p * p, cells = g * g;
  auto out = at::empty({b, cells, 2 * n}, x.options());
  const int64_t rows = b * cells;
  const int threads = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(aectorch_kernel_threads(), rows / 16 + 1)));
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "aectorch_pair_patches", [&] {
    const scalar_t* xs = x.const_data_ptr<scalar_t>();
    scalar_t* os = out.data_ptr<scalar_t>();
    const scalar_t e = static_cast<scalar_t>(eps), rnd = static_cast<scalar_t>(rounding);
    _Pragma("omp parallel for num_threads(threads) schedule(static)")
    for (int64_t row = 0; row < rows; ++row) {
      const int64_t pair = row / cells, cell = row % cells, gy = cell / g, gx = cell % g;
      for (int64_t half = 0; half < 2; ++half) {
        const scalar_t* img = xs + (2 * pair + half) * h * w + (offset + gy * stride) * w + offset + gx * stride;
        scalar_t* __restrict o = os + row * 2 * n + half * n;
        for (int64_t r = 0; r < p; ++r) std::memcpy(o + r * p, img + r * w, p * sizeof(scalar_t));
        scalar_t amax;
        const scalar_t mean = row_sum_max_abs(o, n, &amax) / static_cast<scalar_t>(n);
        const scalar_t mean2 = subtract_sum<scalar_t, false>(o, n, mean) / static_cast<scalar_t>(n);
        const scalar_t norm = std::sqrt(subtract_sum<scalar_t, true>(o, n, mean2));
        if (norm <= e + rnd * amax) {
          std::fill(o, o + n, scalar_t(0));
        } else {
          for (int64_t q = 0; q < n; ++q) o[q] /= norm;
        }
      }
    }
  });
  return out;
}

// One dictionary step in place on atoms d [P, N] (row-major: atom n is column n): D <- D - lr G (the
// gradient given as gs [N, P]), then, with a mirror (ms [P], ps [N], checked), the mirror pairs'
// projection D <- (D + D[mirror][:, partner]) / 2, then every column scaled to unit norm (a zero
// column stays zero). The column norms sum over the rows in order, for all columns at once.
template <typename T>
void step_atoms(T* d, const T* gs, T rate, int64_t p, int64_t n, const int64_t* ms, const int64_t* ps) {
  for (int64_t r = 0; r < p; ++r)
    for (int64_t c = 0; c < n; ++c) d[r * n + c] -= rate * gs[c * p + r];
  if (ms != nullptr) {
    std::vector<T> work(d, d + p * n);
    for (int64_t r = 0; r < p; ++r) {
      const T* other = work.data() + ms[r] * n;
      for (int64_t c = 0; c < n; ++c) d[r * n + c] = (work[r * n + c] + other[ps[c]]) * T(0.5);
    }
  }
  std::vector<T> sq(n, T(0));
  for (int64_t r = 0; r < p; ++r)
    for (int64_t c = 0; c < n; ++c) sq[c] += d[r * n + c] * d[r * n + c];
  for (int64_t c = 0; c < n; ++c) sq[c] = std::max(std::sqrt(sq[c]), std::numeric_limits<T>::min());
  for (int64_t r = 0; r < p; ++r)
    for (int64_t c = 0; c < n; ++c) d[r * n + c] /= sq[c];
}

// A mirror [P] and partner [N] as contiguous int64, checked to lie in range (undefined tensors
// without a mirror).
std::pair<at::Tensor, at::Tensor> mirror_pair(const char* op, const std::optional<at::Tensor>& mirror,
                                              const std::optional<at::Tensor>& partner, int64_t p, int64_t n) {
  TORCH_CHECK(mirror.has_value() == partner.has_value(), op, ": mirror and partner go together");
  if (!mirror.has_value()) return {};
  auto mir = mirror->to(at::kLong).contiguous();
  auto par = partner->to(at::kLong).contiguous();
  TORCH_CHECK(mir.numel() == p && par.numel() == n, op, ": mirror [P] and partner [N]");
  const int64_t* ms = mir.const_data_ptr<int64_t>();
  const int64_t* ps = par.const_data_ptr<int64_t>();
  for (int64_t r = 0; r < p; ++r) TORCH_CHECK(ms[r] >= 0 && ms[r] < p, op, ": bad mirror");
  for (int64_t c = 0; c < n; ++c) TORCH_CHECK(ps[c] >= 0 && ps[c] < n, op, ": bad partner");
  return {mir, par};
}

// One dictionary step in place, atoms [P, N] (row-major: atom n is column n), the gradient given as
// grad_t [N, P] (what sparse_gradient returns): `step_atoms`.
void dictionary_step_(at::Tensor& atoms, const at::Tensor& grad_t, double lr, const std::optional<at::Tensor>& mirror,
                      const std::optional<at::Tensor>& partner) {
  TORCH_CHECK(atoms.dim() == 2 && atoms.is_contiguous(), "aectorch::dictionary_step_ expects contiguous atoms [P, N]");
  TORCH_CHECK(grad_t.dim() == 2 && grad_t.size(0) == atoms.size(1) && grad_t.size(1) == atoms.size(0) &&
                  grad_t.scalar_type() == atoms.scalar_type(),
              "aectorch::dictionary_step_: grad_t must be [N, P] of the atoms' dtype");
  const int64_t p = atoms.size(0), n = atoms.size(1);
  const auto g = grad_t.contiguous();
  const auto [mir, par] = mirror_pair("aectorch::dictionary_step_", mirror, partner, p, n);
  AT_DISPATCH_FLOATING_TYPES(atoms.scalar_type(), "aectorch_dictionary_step", [&] {
    step_atoms(atoms.data_ptr<scalar_t>(), g.const_data_ptr<scalar_t>(), static_cast<scalar_t>(lr), p, n,
               mir.defined() ? mir.const_data_ptr<int64_t>() : nullptr,
               par.defined() ? par.const_data_ptr<int64_t>() : nullptr);
  });
}

// The dictionary steps of several dictionaries (a coder's scales) in one OpenMP region: for each, the
// sparse gradient of its M signals on one thread (sparse_gradient's arithmetic: the weighted
// residuals, then each entry added in order), scaled by -2 / M (as torch's `grad * (-2 / M)` rounds),
// then `step_atoms`: the same bits as sparse_gradient, the scaling and dictionary_step_ one after
// the other. The dictionaries are spread over the kernels' threads, the largest first, each to the
// thread with the least work so far. Every gradient is computed, and its indices checked, before
// any dictionary changes.
void learn_steps_(at::TensorList atoms, at::TensorList signals, at::TensorList reconstructions, at::TensorList indices,
                  at::TensorList coefficients, double lr, const c10::List<std::optional<at::Tensor>>& mirrors,
                  const c10::List<std::optional<at::Tensor>>& partners) {
  const int64_t count = static_cast<int64_t>(atoms.size());
  TORCH_CHECK(signals.size() == atoms.size() && reconstructions.size() == atoms.size() &&
                  indices.size() == atoms.size() && coefficients.size() == atoms.size() &&
                  mirrors.size() == atoms.size() && partners.size() == atoms.size(),
              "aectorch::learn_steps_: one signals, reconstructions, indices, coefficients, mirrors and partners "
              "entry per dictionary");
  if (count == 0) return;
  const auto dtype = atoms[0].scalar_type();
  std::vector<at::Tensor> xs(count), recs(count), idxs(count), coefs(count), mirs(count), pars(count), grads(count),
      weighted(count);
  std::vector<int64_t> work(count);
  for (int64_t i = 0; i < count; ++i) {
    const auto& a = atoms[i];
    TORCH_CHECK(a.dim() == 2 && a.is_contiguous() && a.scalar_type() == dtype,
                "aectorch::learn_steps_ expects contiguous atoms [P, N] of one dtype");
    const int64_t p = a.size(0), n = a.size(1);
    const auto& x = signals[i];
    TORCH_CHECK(x.dim() == 2 && x.size(1) == p && x.size(0) >= 1 && reconstructions[i].sizes() == x.sizes() &&
                    indices[i].dim() == 2 && coefficients[i].sizes() == indices[i].sizes() &&
                    indices[i].size(0) == x.size(0),
                "aectorch::learn_steps_ expects signals and reconstructions [M, P], indices and coefficients [M, k] "
                "for atoms [P, N]");
    TORCH_CHECK(x.scalar_type() == dtype && reconstructions[i].scalar_type() == dtype &&
                    coefficients[i].scalar_type() == dtype && indices[i].scalar_type() == at::kLong,
                "aectorch::learn_steps_: signals, reconstructions and coefficients of the atoms' dtype, int64 indices");
    xs[i] = x.detach().contiguous();
    recs[i] = reconstructions[i].detach().contiguous();
    idxs[i] = indices[i].contiguous();
    coefs[i] = coefficients[i].detach().contiguous();
    std::tie(mirs[i], pars[i]) = mirror_pair("aectorch::learn_steps_", mirrors.get(i), partners.get(i), p, n);
    grads[i] = at::zeros({n, p}, a.options());
    weighted[i] = at::empty({x.size(0), p}, a.options());
    work[i] = x.size(0) * (idxs[i].size(1) + 1) * p;
  }
  const int threads = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(aectorch_kernel_threads(), count)));
  std::vector<int> owner(count, 0);
  {
    std::vector<int64_t> order(count), load(threads, 0);
    for (int64_t i = 0; i < count; ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(), [&](int64_t a, int64_t b) { return work[a] > work[b]; });
    for (const int64_t i : order) {
      const int t = static_cast<int>(std::min_element(load.begin(), load.end()) - load.begin());
      owner[i] = t;
      load[t] += work[i];
    }
  }
  std::atomic<bool> bad{false};
  AT_DISPATCH_FLOATING_TYPES(dtype, "aectorch_learn_steps", [&] {
    _Pragma("omp parallel num_threads(threads)")
    {
      int me = 0;
#ifdef _OPENMP
      me = omp_get_thread_num();
#endif
      for (int64_t i = 0; i < count; ++i) {
        if (owner[i] != me) continue;
        const int64_t m = xs[i].size(0), p = xs[i].size(1), k = idxs[i].size(1), n = grads[i].size(0);
        const scalar_t* x = xs[i].const_data_ptr<scalar_t>();
        const scalar_t* r = recs[i].const_data_ptr<scalar_t>();
        const int64_t* is = idxs[i].const_data_ptr<int64_t>();
        const scalar_t* cs = coefs[i].const_data_ptr<scalar_t>();
        scalar_t* ws = weighted[i].data_ptr<scalar_t>();
        scalar_t* gs = grads[i].data_ptr<scalar_t>();
        for (int64_t row = 0; row < m; ++row) weighted_residual(x + row * p, r + row * p, ws + row * p, p);
        for (int64_t e = 0; e < m * k; ++e) {
          const int64_t atom = is[e];
          if (atom < 0 || atom >= n) {
            bad = true;
            continue;
          }
          if (e + kPrefetchAhead < m * k) prefetch_row(gs, is[e + kPrefetchAhead], n, p);
          axpy(gs + atom * p, ws + (e / k) * p, cs[e], p);
        }
        const scalar_t scale = static_cast<scalar_t>(-2.0 / static_cast<double>(m));
        for (int64_t q = 0; q < n * p; ++q) gs[q] *= scale;
      }
      _Pragma("omp barrier")
      if (!bad.load()) {
        for (int64_t i = 0; i < count; ++i) {
          if (owner[i] != me) continue;
          step_atoms(atoms[i].data_ptr<scalar_t>(), grads[i].const_data_ptr<scalar_t>(), static_cast<scalar_t>(lr),
                     atoms[i].size(0), atoms[i].size(1), mirs[i].defined() ? mirs[i].const_data_ptr<int64_t>() : nullptr,
                     pars[i].defined() ? pars[i].const_data_ptr<int64_t>() : nullptr);
        }
      }
    }
  });
  TORCH_CHECK(!bad.load(), "aectorch::learn_steps_: an index lies outside [0, num_atoms); no dictionary was changed");
}

}  // namespace

void set_kernel_threads(int64_t threads) {
  TORCH_CHECK(threads >= 1, "aectorch::set_kernel_threads: threads must be >= 1");
  g_kernel_threads.store(static_cast<int>(threads));
}

int64_t kernel_threads() { return aectorch_kernel_threads(); }

TORCH_LIBRARY(aectorch, m) {
  m.def("sparse_code(Tensor signals, Tensor dictionary, Tensor gram, int k, bool orthogonal, int block)"
        " -> (Tensor, Tensor)");
  m.def("encode(Tensor signals, Tensor dictionary, Tensor? gram, int k, bool orthogonal, int block, int groups)"
        " -> (Tensor, Tensor, Tensor, Tensor, Tensor)");
  m.def("reconstruct_error(Tensor signals, Tensor atoms_t, Tensor indices, Tensor coefficients) -> (Tensor, Tensor)");
  m.def("sparse_gradient(Tensor signals, Tensor reconstruction, Tensor indices, Tensor coefficients, int num_atoms)"
        " -> Tensor");
  m.def("gram(Tensor atoms) -> Tensor");
  m.def("pooled_power(Tensor indices, Tensor coefficients, int num_atoms) -> Tensor");
  m.def("pair_patches(Tensor images, int offset, int p, int stride, int g, float eps, float rounding) -> Tensor");
  m.def("dictionary_step_(Tensor(a!) atoms, Tensor grad_t, float lr, Tensor? mirror, Tensor? partner) -> ()");
  m.def("learn_steps_(Tensor(a!)[] atoms, Tensor[] signals, Tensor[] reconstructions, Tensor[] indices,"
        " Tensor[] coefficients, float lr, Tensor?[] mirrors, Tensor?[] partners) -> ()");
  m.def("set_kernel_threads(int threads) -> ()", &set_kernel_threads);
  m.def("kernel_threads() -> int", &kernel_threads);
}

TORCH_LIBRARY_IMPL(aectorch, CPU, m) {
  m.impl("sparse_code", &sparse_code);
  m.impl("encode", &encode);
  m.impl("reconstruct_error", &reconstruct_error);
  m.impl("sparse_gradient", &sparse_gradient);
  m.impl("gram", &gram);
  m.impl("pooled_power", &pooled_power);
  m.impl("pair_patches", &pair_patches);
  m.impl("dictionary_step_", &dictionary_step_);
  m.impl("learn_steps_", &learn_steps_);
}
