// Fused CPU kernel of the torch renderer's trilinear (mipmapped) path, render_torch.render_rays.
//
// In eager torch every pixel of a coarse scale costs ~80 tensor ops (the ray, both planes, the
// footprint's derivatives, the level of detail, the sub-samples, two bilinear lookups each), each
// a pass over memory plus dispatch. Here one loop per pixel does the same arithmetic in the same
// order, so the two agree to float rounding (tests/test_sim.py). Only power-of-two textures (the
// levels' sizes and packing in closed form, as in render_torch._trilinear).
//
// Registered as aectorch::render_trilinear (built with the pursuit kernel by
// aectorch.coding.native; its fake implementation for torch.compile lives there too).

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include <algorithm>
#include <cmath>
#include <vector>

int aectorch_kernel_threads();  // pursuit_cpu.cpp

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

template <typename T>
void render(const at::Tensor& poses, const at::Tensor& plane_x, const at::Tensor& texture_index,
            const at::Tensor& atlas, const at::Tensor& xs_t, const at::Tensor& ys_t,
            const at::Tensor& steps_t, const std::vector<double>& scene, int64_t tex_h, int64_t tex_w,
            int64_t levels, double lod_bias, int64_t samples, at::Tensor& out) {
  const int64_t batch = poses.size(0), cams = poses.size(1), pixels = xs_t.size(0);
  const int64_t layers = atlas.size(0), rows = atlas.size(1), cols = atlas.size(2);
  const T* pose = poses.data_ptr<T>();
  const T* px = plane_x.data_ptr<T>();
  const int64_t* index = texture_index.data_ptr<int64_t>();
  const T* tex = atlas.data_ptr<T>();
  const T* xs = xs_t.data_ptr<T>();
  const T* ys = ys_t.data_ptr<T>();
  const T* steps = steps_t.data_ptr<T>();
  T* result = out.data_ptr<T>();
  const T obj_cy = scene[0], obj_cz = scene[1], obj_w = scene[2], obj_h = scene[3];
  const T bg_x = scene[4], bg_cy = scene[5], bg_cz = scene[6], bg_w = scene[7], bg_h = scene[8];
  const T th = T(tex_h), tw = T(tex_w);
  const int64_t top_level = levels - 1;
  const T bias = T(lod_bias - std::log2(double(samples)));
  const int64_t n_sub = samples * samples;
  std::vector<T> offsets(samples);
  for (int64_t i = 0; i < samples; ++i) offsets[i] = (T(i) + T(0.5)) / T(samples) - T(0.5);
  const int64_t layer_size = rows * cols;
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

  const int64_t rows_total = batch * cams;
  const int threads = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(aectorch_kernel_threads(), rows_total)));
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t bc = 0; bc < rows_total; ++bc) {
    {
      const int64_t b = bc / cams;
      const T* m = pose + bc * 16;  // row-major 4 x 4 camera-to-world
      const T r00 = m[0], r01 = m[1], r02 = m[2], o0 = m[3];
      const T r10 = m[4], r11 = m[5], r12 = m[6], o1 = m[7];
      const T r20 = m[8], r21 = m[9], r22 = m[10], o2 = m[11];
      const T reach_o = px[b] - o0, reach_b = bg_x - o0;
      const T uo0 = (obj_cy + T(0.5) * obj_w - o1) / obj_w, vo0 = (obj_cz + T(0.5) * obj_h - o2) / obj_h;
      const T ub0 = (bg_cy + T(0.5) * bg_w - o1) / bg_w, vb0 = (bg_cz + T(0.5) * bg_h - o2) / bg_h;
      const T ro_w = reach_o / obj_w, ro_h = reach_o / obj_h, rb_w = reach_b / bg_w, rb_h = reach_b / bg_h;
      const int64_t object_layer = index[b];
      T* dst = result + bc * pixels;
      for (int64_t p = 0; p < pixels; ++p) {
        const T x = xs[p], y = ys[p];
        const T d0 = r00 * x - (r01 * y + r02);
        const T d1 = r10 * x - (r11 * y + r12);
        const T d2 = r20 * x - (r21 * y + r22);
        const bool ahead = d0 > T(1e-12);
        const T inv = T(1) / (ahead ? d0 : T(1));
        const T ry = d1 * inv, rz = d2 * inv;
        const T uo = uo0 - ro_w * ry, vo = vo0 - ro_h * rz;
        const T ub = ub0 - rb_w * ry, vb = vb0 - rb_h * rz;
        const bool on_object = ahead && reach_o > 0 && uo >= 0 && uo <= 1 && vo >= 0 && vo <= 1;
        const bool on_background = ahead && reach_b > 0 && ub >= 0 && ub <= 1 && vb >= 0 && vb <= 1;
        if (!(on_object || on_background)) {
          dst[p] = T(0);
          continue;
        }
        const T u = (on_object ? uo : ub) * tw, v = (on_object ? vo : vb) * th;
        const T ku = (on_object ? reach_o * (tw / obj_w) : reach_b * (tw / bg_w)) * steps[p];
        const T kv = (on_object ? reach_o * (th / obj_h) : reach_b * (th / bg_h)) * steps[p];
        const T du_c = ku * (r10 - ry * r00) * inv, dv_c = kv * (r20 - rz * r00) * inv;
        const T du_r = ku * (ry * r01 - r11) * inv, dv_r = kv * (rz * r01 - r21) * inv;
        const T rho2 = std::max(du_c * du_c + dv_c * dv_c, du_r * du_r + dv_r * dv_r);
        T lod = T(0.5) * std::log2(std::max(rho2, T(1e-30))) + bias;
        lod = std::min(std::max(lod, T(0)), T(top_level));
        const T low = std::floor(lod);
        const T fraction = lod - low;
        const T high = std::min(low + T(1), T(top_level));
        const T* layer = tex + (on_object ? object_layer : layers - 1) * layer_size;
        const int64_t level_of[2] = {static_cast<int64_t>(low), static_cast<int64_t>(high)};
        // One level when the other has no weight (magnification, or the last level).
        const int levels_read = (fraction == T(0) || high == low) ? 1 : 2;
        T sum = 0;
        // Sub-sample s = row * samples + column, in that order (no integer division per sample).
        for (int64_t srow = 0; srow < samples; ++srow) {
          const T orow = offsets[srow];
          for (int64_t scol = 0; scol < samples; ++scol) {
            const T oc = offsets[scol];
            const T us = samples > 1 ? u + du_c * oc + du_r * orow : u;
            const T vs = samples > 1 ? v + dv_c * oc + dv_r * orow : v;
            T value[2];
            for (int k = 0; k < levels_read; ++k) {
              const int64_t l = level_of[k];
              const T sx = std::min(std::max(us * level_scale[l], T(0.5)), level_w[l] - T(0.5)) + level_col[l];
              const T sy = std::min(std::max(vs * level_scale[l], T(0.5)), level_h[l] - T(0.5)) + level_row[l];
              value[k] = lookup(layer, rows, cols, sx, sy);
            }
            sum += levels_read == 1 ? value[0] : value[0] + fraction * (value[1] - value[0]);
          }
        }
        dst[p] = samples > 1 ? sum / T(n_sub) : sum;
      }
    }
  }
}

at::Tensor render_trilinear(const at::Tensor& poses, const at::Tensor& plane_x, const at::Tensor& texture_index,
                            const at::Tensor& atlas, const at::Tensor& xs, const at::Tensor& ys,
                            const at::Tensor& steps, at::ArrayRef<double> scene, int64_t tex_h, int64_t tex_w,
                            int64_t levels, double lod_bias, int64_t samples) {
  TORCH_CHECK(poses.dim() == 4 && poses.size(2) == 4 && poses.size(3) == 4, "poses must be [B, C, 4, 4]");
  TORCH_CHECK(atlas.dim() == 3, "atlas must be [L, H, W]");
  TORCH_CHECK(scene.size() == 9, "scene must hold 9 numbers");
  TORCH_CHECK(samples >= 1, "samples must be >= 1");
  auto dtype = poses.scalar_type();
  auto p = poses.contiguous();
  auto x = plane_x.to(dtype).contiguous();
  auto idx = texture_index.to(at::kLong).contiguous();
  auto a = atlas.to(dtype).contiguous();
  auto cx = xs.to(dtype).contiguous(), cy = ys.to(dtype).contiguous(), st = steps.to(dtype).contiguous();
  auto out = at::empty({poses.size(0), poses.size(1), xs.size(0)}, poses.options());
  std::vector<double> sc(scene.begin(), scene.end());
  AT_DISPATCH_FLOATING_TYPES(dtype, "render_trilinear", [&] {
    render<scalar_t>(p, x, idx, a, cx, cy, st, sc, tex_h, tex_w, levels, lod_bias, samples, out);
  });
  return out;
}

}  // namespace

TORCH_LIBRARY_FRAGMENT(aectorch, m) {
  m.def("render_trilinear(Tensor poses, Tensor plane_x, Tensor texture_index, Tensor atlas, Tensor xs, "
        "Tensor ys, Tensor steps, float[] scene, int tex_h, int tex_w, int levels, float lod_bias, int samples)"
        " -> Tensor");
}

TORCH_LIBRARY_IMPL(aectorch, CPU, m) { m.impl("render_trilinear", &render_trilinear); }
