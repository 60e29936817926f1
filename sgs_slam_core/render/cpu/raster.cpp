// Compiled CPU backend of the tiled Gaussian compositor: binning, forward and backward.
//
// Same maths as sgs_slam_core/render/composite.py (the reference):
//   q = A dx^2 + 2 B dx dy + C dy^2, dx = pixel_x - u (pixel centres at integer coordinates)
//   alpha = min(alpha_max, o exp(-q/2)), zero unless q < extent^2 and o exp(-q/2) > alpha_min
//   a pixel stops ("done") at the first Gaussian that would take its transmittance below
//   max(t_min, 1e-30); that Gaussian and all later ones are skipped (3DGS's early termination)
//   w_i = alpha_i T_i, image = sum_i w_i f_i, silhouette = 1 - T_final
//
// Parallelism: OpenMP over tiles; each tile is processed by one thread, sequentially over its
// depth-sorted Gaussians, with the tile's pixels in explicit SIMD vectors (GCC vector extensions,
// lowered to AVX-512, AVX2 or SSE by -march=native). The forward runs pack by pack with the sums in
// registers; the backward runs Gaussian by Gaussian over the packs. Backward writes one gradient row per
// (tile, Gaussian) intersection, then sums each Gaussian's rows in intersection order; nothing is
// accumulated across threads, so results do not depend on the thread count or scheduling.

#include <torch/extension.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <vector>

namespace {

constexpr int kGeomGrads = 6;  // u, v, A, B, C, opacity

// ---------------------------------------------------------------------------------------------
// SIMD packs: 16 floats with AVX-512 (measured 20-25% faster than 8 on an AVX-512 Xeon), else 8;
// 4 doubles.
template <typename T>
struct Pack;
#if defined(__AVX512F__)
template <>
struct Pack<float> {
  static constexpr int W = 16;
  typedef float V __attribute__((vector_size(64)));
  typedef int32_t I __attribute__((vector_size(64)));
};
#else
template <>
struct Pack<float> {
  static constexpr int W = 8;
  typedef float V __attribute__((vector_size(32)));
  typedef int32_t I __attribute__((vector_size(32)));
};
#endif
template <>
struct Pack<double> {
  static constexpr int W = 4;
  typedef double V __attribute__((vector_size(32)));
  typedef int64_t I __attribute__((vector_size(32)));
};

template <typename T>
using V = typename Pack<T>::V;

template <typename T>
inline V<T> load(const T* p) {
  V<T> v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}
template <typename T>
inline void store(T* p, V<T> v) {
  std::memcpy(p, &v, sizeof(v));
}
template <typename T>
inline V<T> splat(T x) {
  return V<T>{} + x;
}
// Horizontal sums by a shuffle tree (a fixed order, so results are deterministic).
#if defined(__AVX512F__)
inline float hsum(V<float> v) {
  v += __builtin_shufflevector(v, v, 8, 9, 10, 11, 12, 13, 14, 15, 0, 1, 2, 3, 4, 5, 6, 7);
  v += __builtin_shufflevector(v, v, 4, 5, 6, 7, 0, 1, 2, 3, 12, 13, 14, 15, 8, 9, 10, 11);
  v += __builtin_shufflevector(v, v, 2, 3, 0, 1, 6, 7, 4, 5, 10, 11, 8, 9, 14, 15, 12, 13);
  v += __builtin_shufflevector(v, v, 1, 0, 3, 2, 5, 4, 7, 6, 9, 8, 11, 10, 13, 12, 15, 14);
  return v[0];
}
#else
inline float hsum(V<float> v) {
  v += __builtin_shufflevector(v, v, 4, 5, 6, 7, 0, 1, 2, 3);
  v += __builtin_shufflevector(v, v, 2, 3, 0, 1, 6, 7, 4, 5);
  v += __builtin_shufflevector(v, v, 1, 0, 3, 2, 5, 4, 7, 6);
  return v[0];
}
#endif
inline double hsum(V<double> v) {
  v += __builtin_shufflevector(v, v, 2, 3, 0, 1);
  v += __builtin_shufflevector(v, v, 1, 0, 3, 2);
  return v[0];
}

// exp(x) for x <= 0 (Cephes expf polynomial, relative error ~2e-7); arguments below -87 give a
// tiny normal number. Rounding to nearest uses the 1.5 * 2^23 trick, so no floor() is needed.
inline V<float> exp_neg(V<float> x) {
  using F = V<float>;
  x = x < -87.0f ? splat(-87.0f) : x;
  const F n = (x * 1.44269504088896341f + 12582912.0f) - 12582912.0f;
  const F r = x - n * 0.693145751953125f - n * 1.428606765330187045e-06f;
  F p = splat(1.9875691500e-4f);
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * r * r + r + 1.0f;
  const Pack<float>::I bits = (__builtin_convertvector(n, Pack<float>::I) + 127) << 23;
  return p * (F)bits;  // GCC: a cast between equally sized vectors reinterprets the bits
}
inline V<double> exp_neg(V<double> x) {
  V<double> out;
  for (int l = 0; l < Pack<double>::W; ++l) out[l] = std::exp(x[l]);
  return out;
}

// ---------------------------------------------------------------------------------------------
struct Settings {
  int width, height, tile, tiles_x, tiles_y, channels;
  double alpha_min, alpha_max, extent2, t_min;
};

struct TileView {
  int x0, y0;
  int64_t begin, end;
};

inline TileView tile_view(const Settings& s, int tile, const int64_t* offsets) {
  return {(tile % s.tiles_x) * s.tile, (tile / s.tiles_x) * s.tile, offsets[tile], offsets[tile + 1]};
}

// Per-Gaussian constants of one slot.
template <typename T>
struct Splat {
  T u, v, A, B2, C, o;
};

template <typename T>
inline Splat<T> splat_of(int64_t g, const TileView& view, const T* m2d, const T* con, const T* op) {
  return {m2d[2 * g] - view.x0, m2d[2 * g + 1] - view.y0, con[3 * g], T(2) * con[3 * g + 1], con[3 * g + 2], op[g]};
}

// Which pixels of the tile each pack (W consecutive pixels, row-major) covers.
struct PackBox {
  float row_lo, row_hi, col_lo, col_hi;
};

template <typename T>
std::vector<PackBox> pack_boxes(int ts) {
  constexpr int W = Pack<T>::W;
  std::vector<PackBox> boxes;
  for (int b = 0; b < ts * ts; b += W) {
    const int r0 = b / ts, r1 = (b + W - 1) / ts;
    const bool one_row = r0 == r1;
    boxes.push_back({float(r0), float(r1), one_row ? float(b % ts) : 0.f, one_row ? float((b + W - 1) % ts) : float(ts - 1)});
  }
  return boxes;
}

// True when a pack can hold a pixel of the footprint box [u - r, u + r] x [v - r, v + r]; outside
// the box alpha is exactly 0 (the radius bounds both the 3-sigma and the alpha_min cut).
inline bool pack_hit(const PackBox& p, float u, float v, float r) {
  return p.row_hi >= v - r && p.row_lo <= v + r && p.col_hi >= u - r && p.col_lo <= u + r;
}

// Alpha of one Gaussian on W pixels after the footprint and alpha cuts (not the early stop), and q.
template <typename T>
inline V<T> raw_alpha(const Settings& s, const Splat<T>& g, V<T> px, V<T> py, V<T>& dx, V<T>& dy) {
  const T e2 = static_cast<T>(s.extent2);
  dx = px - g.u;
  dy = py - g.v;
  const V<T> q = g.A * dx * dx + g.B2 * dx * dy + g.C * dy * dy;
  V<T> a = g.o * exp_neg(T(-0.5) * (q < e2 + T(1) ? q : splat(e2 + T(1))));
  a = a < T(s.alpha_max) ? a : splat(T(s.alpha_max));
  return (q < e2) & (a > T(s.alpha_min)) ? a : splat(T(0));
}

template <typename T>
struct Scratch {
  std::vector<T> data;
  T* take(size_t n) {
    T* p = data.data() + used;
    used += n;
    return p;
  }
  void reset(size_t total) {
    data.assign(total, T(0));
    used = 0;
  }
  size_t used = 0;
};

template <typename T>
void pixel_grid(int ts, T* px, T* py) {
  for (int p = 0; p < ts * ts; ++p) {
    px[p] = static_cast<T>(p % ts);
    py[p] = static_cast<T>(p / ts);
  }
}

// Forward of one tile, pack by pack: each pack of W pixels runs through the tile's depth-sorted
// Gaussians with its accumulators in registers (the channel count DC is a template argument for the
// common 4 = colour + depth and 7 = colour + 3 semantics + depth; 0 = any, read at run time). The
// splat constants are gathered once per tile. Per pixel the blending order is the same as a
// Gaussian-major loop, so results do not depend on the loop order.
template <typename T, int DC>
void forward_tile(const Settings& s, int tile, const int64_t* offsets, const int32_t* gids, const T* m2d, const T* con,
                  const T* op, const T* rad, const T* feat, T* img, T* sil, T* t_final, int32_t* count, Scratch<T>& sc) {
  constexpr int W = Pack<T>::W;
  const int ts = s.tile, npix = ts * ts, D = DC > 0 ? DC : s.channels, npack = npix / W;
  const TileView view = tile_view(s, tile, offsets);
  const int64_t K = view.end - view.begin;
  sc.reset(static_cast<size_t>(K) * 7 + static_cast<size_t>(npix) * 2);
  T* su = sc.take(K);
  T* sv = sc.take(K);
  T* sa = sc.take(K);
  T* sb2 = sc.take(K);
  T* scc = sc.take(K);
  T* so = sc.take(K);
  T* sr = sc.take(K);
  for (int64_t k = 0; k < K; ++k) {
    const int64_t g = gids[view.begin + k];
    const Splat<T> sp = splat_of(g, view, m2d, con, op);
    su[k] = sp.u, sv[k] = sp.v, sa[k] = sp.A, sb2[k] = sp.B2, scc[k] = sp.C, so[k] = sp.o, sr[k] = rad[g];
  }
  T* px = sc.take(npix);
  T* py = sc.take(npix);
  pixel_grid(ts, px, py);
  const T never = T(1e30);
  const T floor_t = static_cast<T>(std::max(s.t_min, 1e-30));
  const std::vector<PackBox> boxes = pack_boxes<T>(ts);
  V<T> acc_fixed[DC > 0 ? DC : 1];
  std::vector<V<T>> acc_any(DC > 0 ? 0 : D);
  V<T>* acc = DC > 0 ? acc_fixed : acc_any.data();
  for (int pack = 0; pack < npack; ++pack) {
    const int b = pack * W;
    const PackBox box = boxes[pack];
    const V<T> x = load(px + b), y = load(py + b);
    for (int c = 0; c < D; ++c) acc[c] = V<T>{};
    V<T> t = splat(T(1)), stopped = splat(never);
    for (int64_t k = 0; k < K; ++k) {
      if (!pack_hit(box, float(su[k]), float(sv[k]), float(sr[k]))) continue;
      const Splat<T> sp{su[k], sv[k], sa[k], sb2[k], scc[k], so[k]};
      V<T> dx, dy;
      V<T> a = raw_alpha(s, sp, x, y, dx, dy);
      const auto was = stopped < never;
      const auto now = (t * (T(1) - a) < floor_t) | was;
      a = now ? splat(T(0)) : a;
      stopped = (now & ~was) ? splat(static_cast<T>(k)) : stopped;
      const V<T> w = a * t;
      const T* f = feat + static_cast<int64_t>(gids[view.begin + k]) * D;
      for (int c = 0; c < D; ++c) acc[c] += w * f[c];
      t = t * (T(1) - a);
      if ((k & 15) == 15 && hsum(now ? splat(T(0)) : splat(T(1))) == T(0)) break;  // every pixel has stopped
    }
    const T total = static_cast<T>(K);
    for (int l = 0; l < W; ++l) {
      const int p = b + l, px_ = view.x0 + p % ts, py_ = view.y0 + p / ts;
      if (px_ >= s.width || py_ >= s.height) continue;
      const int64_t pix = static_cast<int64_t>(py_) * s.width + px_;
      for (int c = 0; c < D; ++c) img[pix * D + c] = acc[c][l];
      sil[pix] = T(1) - t[l];
      t_final[pix] = t[l];
      count[pix] = static_cast<int32_t>(stopped[l] < total ? stopped[l] : total);
    }
  }
}

// One back-to-front pass (3DGS-style): the forward saved each pixel's final transmittance and how
// many slots it blended; T_i is recovered as T_{i+1} / (1 - alpha_i) and the suffix sum
// S_i = sum_{j>i} w_j c_j grows as we go, so dL/dalpha_i = T_i c_i - S_i / (1 - alpha_i).
template <typename T, int DC>
void backward_tile(const Settings& s, int tile, const int64_t* offsets, const int32_t* gids, const T* m2d, const T* con,
                   const T* op, const T* rad, const T* feat, const T* g_img, const T* g_sil, const T* t_final,
                   const int32_t* count, T* out, Scratch<T>& sc) {
  constexpr int W = Pack<T>::W;
  const int ts = s.tile, npix = ts * ts, D = DC > 0 ? DC : s.channels, stride = kGeomGrads + D;
  const TileView view = tile_view(s, tile, offsets);
  sc.reset(static_cast<size_t>(npix) * (D + 7));
  T* gp = sc.take(static_cast<size_t>(D) * npix);  // [D, npix] upstream gradient of the features
  T* gs = sc.take(npix);                            // upstream gradient of the silhouette
  T* trans = sc.take(npix);                         // T after the current slot (starts at T_final)
  T* nblend = sc.take(npix);
  T* suffix = sc.take(npix);
  T* px = sc.take(npix);
  T* py = sc.take(npix);
  pixel_grid(ts, px, py);
  int32_t max_count = 0;
  for (int p = 0; p < npix; ++p) {
    const int x = view.x0 + p % ts, y = view.y0 + p / ts;
    const bool inside = x < s.width && y < s.height;
    const int64_t pix = static_cast<int64_t>(y) * s.width + x;
    for (int c = 0; c < D; ++c) gp[c * npix + p] = inside ? g_img[pix * D + c] : T(0);
    gs[p] = inside ? g_sil[pix] : T(0);
    trans[p] = inside ? t_final[pix] : T(1);
    const int32_t n = inside ? count[pix] : 0;
    nblend[p] = static_cast<T>(n);
    max_count = std::max(max_count, n);
  }
  const T amax = static_cast<T>(s.alpha_max);
  const std::vector<PackBox> boxes = pack_boxes<T>(ts);
  std::vector<int32_t> pack_count(npix / W, 0);  // slots blended by the pack's longest-blending pixel
  for (int p = 0; p < npix; ++p) pack_count[p / W] = std::max(pack_count[p / W], static_cast<int32_t>(nblend[p]));
  V<T> gf_fixed[DC > 0 ? DC : 1];  // per-Gaussian feature gradients; in registers when DC is known
  std::vector<V<T>> gf_any(DC > 0 ? 0 : D);
  V<T>* gf = DC > 0 ? gf_fixed : gf_any.data();
  // Slots past every pixel's stop contribute nothing; their rows are zeroed here (rows are not pre-filled).
  std::fill(out + (view.begin + max_count) * stride, out + view.end * stride, T(0));
  for (int64_t k = max_count - 1; k >= 0; --k) {
    const int64_t i = view.begin + k;
    const int64_t g = gids[i];
    const Splat<T> sp = splat_of(g, view, m2d, con, op);
    const T* f = feat + g * D;
    const T slot = static_cast<T>(k);
    V<T> vsx{}, vsy{}, vsxx{}, vsxy{}, vsyy{}, vsa{};
    for (int c = 0; c < D; ++c) gf[c] = V<T>{};
    for (int pack = 0; pack < npix / W; ++pack) {
      // Past every pixel's stop, or outside the footprint: alpha is 0 and nothing changes.
      if (k >= pack_count[pack] || !pack_hit(boxes[pack], float(sp.u), float(sp.v), float(rad[g]))) continue;
      const int b = pack * W;
      V<T> dx, dy;
      V<T> a = raw_alpha(s, sp, load(px + b), load(py + b), dx, dy);
      a = slot < load(nblend + b) ? a : splat(T(0));
      const V<T> inv = T(1) / (T(1) - a);
      const V<T> t = load(trans + b) * inv;  // transmittance before this slot
      const V<T> w = a * t;
      V<T> ck = load(gs + b);  // g . f_k + g_sil, and the feature gradients, from one read of g
      for (int c = 0; c < D; ++c) {
        const V<T> gpc = load(gp + c * npix + b);
        ck += gpc * f[c];
        gf[c] += w * gpc;
      }
      const V<T> suf = load(suffix + b);
      const V<T> g_alpha = t * ck - suf * inv;
      store(suffix + b, suf + w * ck);
      store(trans + b, t);
      const V<T> free = (a > T(0)) & (a < amax) ? a : splat(T(0));  // clamped or cut alphas pass no gradient
      const V<T> gq = T(-0.5) * g_alpha * free;                     // dL/dq
      vsx += gq * dx;
      vsy += gq * dy;
      vsxx += gq * dx * dx;
      vsxy += gq * dx * dy;
      vsyy += gq * dy * dy;
      vsa += g_alpha * free;  // o dL/do
    }
    const T sx = hsum(vsx), sy = hsum(vsy), B = T(0.5) * sp.B2;
    T* row = out + i * stride;
    row[0] = T(-2) * (sp.A * sx + B * sy);
    row[1] = T(-2) * (B * sx + sp.C * sy);
    row[2] = hsum(vsxx);
    row[3] = T(2) * hsum(vsxy);
    row[4] = hsum(vsyy);
    row[5] = sp.o > T(0) ? hsum(vsa) / sp.o : T(0);
    for (int c = 0; c < D; ++c) row[kGeomGrads + c] = hsum(gf[c]);
  }
}

// Calls fn(std::integral_constant<int, DC>) with DC = 7 (colour, 3 semantics, depth), 4 (colour,
// depth) or 0 (any count, read at run time): the kernels keep per-channel sums in registers when DC > 0.
template <typename F>
void with_channels(int channels, F&& fn) {
  if (channels == 7)
    fn(std::integral_constant<int, 7>{});
  else if (channels == 4)
    fn(std::integral_constant<int, 4>{});
  else
    fn(std::integral_constant<int, 0>{});
}

template <typename T>
void forward_all(const Settings& s, const int64_t* off, const int32_t* gid, const T* m, const T* c, const T* o,
                 const T* r, const T* f, T* img, T* sil, T* t_final, int32_t* count, int threads) {
  const int num_tiles = s.tiles_x * s.tiles_y;
#pragma omp parallel num_threads(threads)
  {
    Scratch<T> scratch;
#pragma omp for schedule(dynamic, 4)
    for (int t = 0; t < num_tiles; ++t) {
      if (off[t + 1] == off[t]) continue;
      with_channels(s.channels, [&](auto dc) {
        forward_tile<T, decltype(dc)::value>(s, t, off, gid, m, c, o, r, f, img, sil, t_final, count, scratch);
      });
    }
  }
}

template <typename T>
void backward_all(const Settings& s, const int64_t* off, const int32_t* gid, const T* m, const T* c, const T* o,
                  const T* r, const T* f, const T* gi, const T* gs, const T* t_final, const int32_t* count, T* out,
                  int threads) {
  const int num_tiles = s.tiles_x * s.tiles_y;
#pragma omp parallel num_threads(threads)
  {
    Scratch<T> scratch;
#pragma omp for schedule(dynamic, 4)
    for (int t = 0; t < num_tiles; ++t) {
      if (off[t + 1] == off[t]) continue;
      with_channels(s.channels, [&](auto dc) {
        backward_tile<T, decltype(dc)::value>(s, t, off, gid, m, c, o, r, f, gi, gs, t_final, count, out, scratch);
      });
    }
  }
}

// Per-Gaussian sums of per-intersection rows, each Gaussian summing its rows in intersection order
// (deterministic for any thread count). Rows are read in storage order (streaming, no gather); each
// thread owns a range of Gaussian ids and skips the rows of the others.
template <typename T>
void reduce_rows(const T* rows, const int32_t* gids, int64_t num_isects, int64_t stride, int64_t n, T* out,
                 int threads) {
#pragma omp parallel num_threads(threads)
  {
    const int64_t parts = omp_get_num_threads(), part = omp_get_thread_num();
    const int64_t lo = n * part / parts, hi = n * (part + 1) / parts;
    for (int64_t i = 0; i < num_isects; ++i) {
      const int64_t g = gids[i];
      if (g < lo || g >= hi) continue;
      T* dst = out + g * stride;
      const T* src = rows + i * stride;
      for (int64_t c = 0; c < stride; ++c) dst[c] += src[c];
    }
  }
}

Settings make_settings(int64_t width, int64_t height, int64_t tile, int64_t channels, double alpha_min,
                       double alpha_max, double extent2, double t_min) {
  TORCH_CHECK(tile == 4 || tile == 8 || tile == 16, "the cpu backend supports tile sizes 4, 8 and 16, got ", tile);
  Settings s{};
  s.width = static_cast<int>(width);
  s.height = static_cast<int>(height);
  s.tile = static_cast<int>(tile);
  s.tiles_x = static_cast<int>((width + tile - 1) / tile);
  s.tiles_y = static_cast<int>((height + tile - 1) / tile);
  s.channels = static_cast<int>(channels);
  s.alpha_min = alpha_min;
  s.alpha_max = alpha_max;
  s.extent2 = extent2;
  s.t_min = t_min;
  return s;
}

void check_inputs(const torch::Tensor& m2d, const torch::Tensor& con, const torch::Tensor& op, const torch::Tensor& rad,
                  const torch::Tensor& feat) {
  TORCH_CHECK(rad.dim() == 1 && rad.size(0) == m2d.size(0), "radii must be [N]");
  for (const auto* t : {&m2d, &con, &op, &rad, &feat}) {
    TORCH_CHECK(t->device().is_cpu(), "the cpu backend takes CPU tensors");
    TORCH_CHECK(t->is_contiguous(), "inputs must be contiguous");
    TORCH_CHECK(t->scalar_type() == m2d.scalar_type(), "inputs must share one floating dtype");
  }
  const auto n = m2d.size(0);
  TORCH_CHECK(m2d.dim() == 2 && m2d.size(1) == 2, "means2d must be [N, 2]");
  TORCH_CHECK(con.dim() == 2 && con.size(0) == n && con.size(1) == 3, "conics must be [N, 3]");
  TORCH_CHECK(op.dim() == 1 && op.size(0) == n, "opacities must be [N]");
  TORCH_CHECK(feat.dim() == 2 && feat.size(0) == n, "features must be [N, D]");
}


// ---------------------------------------------------------------------------------------------
// Isotropic EWA projection (same formulas, in the same order, as render/projection.py).
struct Camera {
  double fx, fy, cx, cy;
  int64_t width, height;
  double near, eps2d, alpha_min, extent_sigma;
};

template <typename T>
void project_one(const Camera& k, const T* mc, T scale, T opacity, T* m2d, T* con, T* radius, T* depth) {
  const T x = mc[0], y = mc[1], z = mc[2];
  const bool front = z > T(k.near);
  const T zs = front ? z : T(1);
  const T xz = x / zs, yz = y / zs;
  m2d[0] = T(k.fx) * xz + T(k.cx);
  m2d[1] = T(k.fy) * yz + T(k.cy);
  const T tan_x = T(0.5) * T(k.width) / T(k.fx), tan_y = T(0.5) * T(k.height) / T(k.fy);
  const T lx0 = -(T(k.cx) + T(0.5)) / T(k.fx) - T(0.3) * tan_x, lx1 = (T(k.width) - T(k.cx) - T(0.5)) / T(k.fx) + T(0.3) * tan_x;
  const T ly0 = -(T(k.cy) + T(0.5)) / T(k.fy) - T(0.3) * tan_y, ly1 = (T(k.height) - T(k.cy) - T(0.5)) / T(k.fy) + T(0.3) * tan_y;
  const T tx = std::min(std::max(xz, lx0), lx1), ty = std::min(std::max(yz, ly0), ly1);
  const T iz = T(1) / zs;
  const T s2 = (scale * iz) * (scale * iz);
  const T a = s2 * T(k.fx) * T(k.fx) * (T(1) + tx * tx) + T(k.eps2d);
  const T b = s2 * T(k.fx) * T(k.fy) * tx * ty;
  const T c = s2 * T(k.fy) * T(k.fy) * (T(1) + ty * ty) + T(k.eps2d);
  const T det = std::max(a * c - b * b, T(1e-12));
  con[0] = c / det;
  con[1] = -b / det;
  con[2] = a / det;
  depth[0] = z;
  const T lam = T(0.5) * (a + c) + std::sqrt((T(0.5) * (a - c)) * (T(0.5) * (a - c)) + b * b);
  const T ratio = std::max(opacity / T(k.alpha_min), T(1));
  const T extent2 = std::min(T(2) * std::log(ratio), T(k.extent_sigma * k.extent_sigma));
  const T r = std::sqrt(extent2 * lam);
  const bool visible = front && opacity >= T(k.alpha_min) && std::isfinite(r);
  radius[0] = visible ? r : T(0);
}

// Gradients of project_one with respect to the camera-frame mean and the scale.
template <typename T>
void project_one_backward(const Camera& k, const T* mc, T scale, const T* g_m2d, const T* g_con, T g_depth, T* g_mc,
                          T* g_scale) {
  const T x = mc[0], y = mc[1], z = mc[2];
  if (!(z > T(k.near))) {
    g_mc[0] = g_mc[1] = g_mc[2] = T(0);
    *g_scale = T(0);
    return;
  }
  const T fx = T(k.fx), fy = T(k.fy);
  const T xz = x / z, yz = y / z, iz = T(1) / z;
  const T tan_x = T(0.5) * T(k.width) / fx, tan_y = T(0.5) * T(k.height) / fy;
  const T lx0 = -(T(k.cx) + T(0.5)) / fx - T(0.3) * tan_x, lx1 = (T(k.width) - T(k.cx) - T(0.5)) / fx + T(0.3) * tan_x;
  const T ly0 = -(T(k.cy) + T(0.5)) / fy - T(0.3) * tan_y, ly1 = (T(k.height) - T(k.cy) - T(0.5)) / fy + T(0.3) * tan_y;
  const T tx = std::min(std::max(xz, lx0), lx1), ty = std::min(std::max(yz, ly0), ly1);
  const bool free_x = xz > lx0 && xz < lx1, free_y = yz > ly0 && yz < ly1;
  const T s2 = (scale * iz) * (scale * iz);
  const T a = s2 * fx * fx * (T(1) + tx * tx) + T(k.eps2d);
  const T b = s2 * fx * fy * tx * ty;
  const T c = s2 * fy * fy * (T(1) + ty * ty) + T(k.eps2d);
  const T det = a * c - b * b;
  const T id2 = T(1) / (det * det);
  const T gA = g_con[0], gB = g_con[1], gC = g_con[2];
  // conic = (c, -b, a) / det
  const T g_a = (-c * c * gA + b * c * gB - b * b * gC) * id2;
  const T g_b = (T(2) * b * c * gA + (-det - T(2) * b * b) * gB + T(2) * a * b * gC) * id2;
  const T g_c = (-b * b * gA + a * b * gB - a * a * gC) * id2;
  const T g_s2 = g_a * fx * fx * (T(1) + tx * tx) + g_b * fx * fy * tx * ty + g_c * fy * fy * (T(1) + ty * ty);
  T g_tx = g_a * s2 * fx * fx * T(2) * tx + g_b * s2 * fx * fy * ty;
  T g_ty = g_b * s2 * fx * fy * tx + g_c * s2 * fy * fy * T(2) * ty;
  g_tx = free_x ? g_tx : T(0);
  g_ty = free_y ? g_ty : T(0);
  // x/z and y/z feed both the pixel position and (when not clamped) the Jacobian
  const T g_xz = g_m2d[0] * fx + g_tx, g_yz = g_m2d[1] * fy + g_ty;
  g_mc[0] = g_xz * iz;
  g_mc[1] = g_yz * iz;
  g_mc[2] = -(g_xz * xz + g_yz * yz) * iz - T(2) * s2 * iz * g_s2 + g_depth;
  *g_scale = g_s2 * T(2) * scale * iz * iz;
}

template <typename T>
void project_all(const Camera& k, int64_t n, const T* mc, const T* sc, const T* op, T* m2d, T* con, T* rad, T* dep,
                 int threads) {
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t g = 0; g < n; ++g) project_one(k, mc + 3 * g, sc[g], op[g], m2d + 2 * g, con + 3 * g, rad + g, dep + g);
}

template <typename T>
void project_backward_all(const Camera& k, int64_t n, const T* mc, const T* sc, const T* g_m2d, const T* g_con,
                          const T* g_dep, int64_t dep_stride, T* g_mc, T* g_sc, int threads) {
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t g = 0; g < n; ++g)
    project_one_backward(k, mc + 3 * g, sc[g], g_m2d + 2 * g, g_con + 3 * g, g_dep[g * dep_stride], g_mc + 3 * g,
                         g_sc + g);
}

}  // namespace

// Tile lists: Gaussians sorted by depth (ties by index, as a stable sort), appended to every tile
// their footprint box touches. Returns (gaussian ids [I] int32, tile offsets [T + 1] int64).
// Stable LSD radix sort of (depth bits << 32 | id) keys on their upper 32 bits: the ids are pushed in
// ascending order, so the result equals sorting the whole keys (about 10x faster than std::sort).
void sort_by_depth(std::vector<uint64_t>& keys) {
  std::vector<uint64_t> tmp(keys.size());
  for (int shift = 32; shift < 64; shift += 8) {
    size_t start[257] = {0};
    for (const uint64_t k : keys) ++start[((k >> shift) & 0xffu) + 1];
    for (int b = 0; b < 256; ++b) start[b + 1] += start[b];
    for (const uint64_t k : keys) tmp[start[(k >> shift) & 0xffu]++] = k;
    keys.swap(tmp);
  }
}

template <typename T>
std::vector<torch::Tensor> bin_impl(const T* mp, const T* rp, const T* dp, int64_t n, int64_t width, int64_t height,
                                    int64_t tile) {
  const int64_t tiles_x = (width + tile - 1) / tile, tiles_y = (height + tile - 1) / tile;
  std::vector<int32_t> rect(4 * static_cast<size_t>(n));
  std::vector<uint64_t> keys;
  keys.reserve(static_cast<size_t>(n));
  for (int64_t g = 0; g < n; ++g) {
    const double u = mp[2 * g], v = mp[2 * g + 1], rad = rp[g];
    if (!(rad > 0) || !std::isfinite(u) || !std::isfinite(v)) continue;
    const double xl = std::ceil(u - rad), xh = std::floor(u + rad), yl = std::ceil(v - rad), yh = std::floor(v + rad);
    if (xl > width - 1 || xh < 0 || yl > height - 1 || yh < 0 || xl > xh || yl > yh) continue;
    auto clampi = [](double x, double hi) { return static_cast<int32_t>(std::min(std::max(x, 0.0), hi)); };
    rect[4 * g + 0] = clampi(xl, width - 1) / static_cast<int32_t>(tile);
    rect[4 * g + 1] = clampi(xh, width - 1) / static_cast<int32_t>(tile);
    rect[4 * g + 2] = clampi(yl, height - 1) / static_cast<int32_t>(tile);
    rect[4 * g + 3] = clampi(yh, height - 1) / static_cast<int32_t>(tile);
    // Visible Gaussians have depth > near > 0, so the float bits sort like the values.
    const float depth = static_cast<float>(dp[g]);
    uint32_t bits;
    std::memcpy(&bits, &depth, sizeof(bits));
    keys.push_back((static_cast<uint64_t>(bits) << 32) | static_cast<uint64_t>(g));
  }
  sort_by_depth(keys);
  auto offsets = torch::zeros({tiles_x * tiles_y + 1}, torch::kInt64);
  int64_t* off = offsets.data_ptr<int64_t>();
  for (uint64_t key : keys) {
    const int32_t* r = &rect[4 * (key & 0xffffffffu)];
    for (int64_t ty = r[2]; ty <= r[3]; ++ty)
      for (int64_t tx = r[0]; tx <= r[1]; ++tx) off[ty * tiles_x + tx + 1] += 1;
  }
  for (int64_t t = 0; t < tiles_x * tiles_y; ++t) off[t + 1] += off[t];
  auto gids = torch::empty({off[tiles_x * tiles_y]}, torch::kInt32);
  int32_t* gp = gids.data_ptr<int32_t>();
  std::vector<int64_t> cursor(off, off + tiles_x * tiles_y);
  for (uint64_t key : keys) {
    const int32_t g = static_cast<int32_t>(key & 0xffffffffu);
    const int32_t* r = &rect[4 * g];
    for (int64_t ty = r[2]; ty <= r[3]; ++ty)
      for (int64_t tx = r[0]; tx <= r[1]; ++tx) gp[cursor[ty * tiles_x + tx]++] = g;
  }
  return {gids, offsets};
}

std::vector<torch::Tensor> bin_gaussians(torch::Tensor means2d, torch::Tensor radii, torch::Tensor depths, int64_t width,
                                         int64_t height, int64_t tile) {
  TORCH_CHECK(means2d.device().is_cpu() && radii.device().is_cpu() && depths.device().is_cpu(), "CPU tensors only");
  auto m = means2d.contiguous();
  auto r = radii.contiguous().to(m.scalar_type());
  auto d = depths.contiguous().to(m.scalar_type());
  std::vector<torch::Tensor> out;
  AT_DISPATCH_FLOATING_TYPES(m.scalar_type(), "bin_gaussians", [&] {
    out = bin_impl<scalar_t>(m.data_ptr<scalar_t>(), r.data_ptr<scalar_t>(), d.data_ptr<scalar_t>(), m.size(0), width,
                             height, tile);
  });
  return out;
}

// (image [H, W, D], silhouette [H, W], final transmittance [H, W], blended slots [H, W] int32)
std::vector<torch::Tensor> composite_forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                             torch::Tensor radii, torch::Tensor features, torch::Tensor gids,
                                             torch::Tensor offsets,
                                             int64_t width, int64_t height, int64_t tile, double alpha_min,
                                             double alpha_max, double extent2, double t_min, int64_t threads) {
  check_inputs(means2d, conics, opacities, radii, features);
  const auto s = make_settings(width, height, tile, features.size(1), alpha_min, alpha_max, extent2, t_min);
  auto img = torch::zeros({height, width, features.size(1)}, features.options());
  auto sil = torch::zeros({height, width}, features.options());
  auto t_final = torch::ones({height, width}, features.options());
  auto count = torch::zeros({height, width}, torch::kInt32);
  const int64_t* off = offsets.data_ptr<int64_t>();
  const int32_t* gid = gids.data_ptr<int32_t>();
  AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "composite_forward", [&] {
    forward_all<scalar_t>(s, off, gid, means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(),
                          opacities.data_ptr<scalar_t>(), radii.data_ptr<scalar_t>(), features.data_ptr<scalar_t>(),
                          img.data_ptr<scalar_t>(),
                          sil.data_ptr<scalar_t>(), t_final.data_ptr<scalar_t>(), count.data_ptr<int32_t>(),
                          static_cast<int>(threads));
  });
  return {img, sil, t_final, count};
}

// Per-Gaussian gradients [N, 6 + D]: (u, v, A, B, C, opacity, features...).
torch::Tensor composite_backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                 torch::Tensor radii, torch::Tensor features, torch::Tensor gids, torch::Tensor offsets,
                                 torch::Tensor t_final,
                                 torch::Tensor count, torch::Tensor grad_img, torch::Tensor grad_sil, int64_t width,
                                 int64_t height, int64_t tile, double alpha_min, double alpha_max, double extent2,
                                 double t_min, int64_t threads) {
  check_inputs(means2d, conics, opacities, radii, features);
  const auto s = make_settings(width, height, tile, features.size(1), alpha_min, alpha_max, extent2, t_min);
  grad_img = grad_img.contiguous().to(features.scalar_type());
  grad_sil = grad_sil.contiguous().to(features.scalar_type());
  const int64_t stride = kGeomGrads + features.size(1);
  auto rows = torch::empty({gids.size(0), stride}, features.options());  // every row written by its tile
  auto out = torch::zeros({means2d.size(0), stride}, features.options());
  const int64_t* off = offsets.data_ptr<int64_t>();
  const int32_t* gid = gids.data_ptr<int32_t>();
  AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "composite_backward", [&] {
    backward_all<scalar_t>(s, off, gid, means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(),
                           opacities.data_ptr<scalar_t>(), radii.data_ptr<scalar_t>(), features.data_ptr<scalar_t>(),
                           grad_img.data_ptr<scalar_t>(),
                           grad_sil.data_ptr<scalar_t>(), t_final.data_ptr<scalar_t>(), count.data_ptr<int32_t>(),
                           rows.data_ptr<scalar_t>(), static_cast<int>(threads));
    reduce_rows<scalar_t>(rows.data_ptr<scalar_t>(), gid, gids.size(0), stride, means2d.size(0),
                          out.data_ptr<scalar_t>(), static_cast<int>(threads));
  });
  return out;
}

// (means2d [N, 2], conics [N, 3], radii [N], depths [N]) of isotropic camera-frame Gaussians.
std::vector<torch::Tensor> project_isotropic(torch::Tensor means_cam, torch::Tensor scales, torch::Tensor opacities,
                                             double fx, double fy, double cx, double cy, int64_t width, int64_t height,
                                             double near, double eps2d, double alpha_min, double extent_sigma,
                                             int64_t threads) {
  TORCH_CHECK(means_cam.is_contiguous() && scales.is_contiguous() && opacities.is_contiguous(), "contiguous inputs");
  const int64_t n = means_cam.size(0);
  const Camera k{fx, fy, cx, cy, width, height, near, eps2d, alpha_min, extent_sigma};
  auto m2d = torch::empty({n, 2}, means_cam.options());
  auto con = torch::empty({n, 3}, means_cam.options());
  auto rad = torch::empty({n}, means_cam.options());
  auto dep = torch::empty({n}, means_cam.options());
  AT_DISPATCH_FLOATING_TYPES(means_cam.scalar_type(), "project_isotropic", [&] {
    project_all<scalar_t>(k, n, means_cam.data_ptr<scalar_t>(), scales.data_ptr<scalar_t>(),
                          opacities.data_ptr<scalar_t>(), m2d.data_ptr<scalar_t>(), con.data_ptr<scalar_t>(),
                          rad.data_ptr<scalar_t>(), dep.data_ptr<scalar_t>(), static_cast<int>(threads));
  });
  return {m2d, con, rad, dep};
}

// (d means_cam [N, 3], d scales [N]) from the gradients of means2d, conics and depths.
std::vector<torch::Tensor> project_isotropic_backward(torch::Tensor means_cam, torch::Tensor scales,
                                                      torch::Tensor g_means2d, torch::Tensor g_conics,
                                                      torch::Tensor g_depths, double fx, double fy, double cx,
                                                      double cy, int64_t width, int64_t height, double near,
                                                      double eps2d, int64_t threads) {
  const int64_t n = means_cam.size(0);
  const Camera k{fx, fy, cx, cy, width, height, near, eps2d, 0.0, 0.0};
  g_means2d = g_means2d.contiguous();
  g_conics = g_conics.contiguous();
  TORCH_CHECK(g_depths.dim() == 1, "depth gradients must be [N]");
  auto g_mc = torch::empty({n, 3}, means_cam.options());
  auto g_sc = torch::empty({n}, means_cam.options());
  AT_DISPATCH_FLOATING_TYPES(means_cam.scalar_type(), "project_isotropic_backward", [&] {
    project_backward_all<scalar_t>(k, n, means_cam.data_ptr<scalar_t>(), scales.data_ptr<scalar_t>(),
                                   g_means2d.data_ptr<scalar_t>(), g_conics.data_ptr<scalar_t>(),
                                   g_depths.data_ptr<scalar_t>(), g_depths.stride(0), g_mc.data_ptr<scalar_t>(),
                                   g_sc.data_ptr<scalar_t>(), static_cast<int>(threads));
  });
  return {g_mc, g_sc};
}

// The GIL is released while the kernels run, so tracking, mapping and rendering threads overlap.
PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  using release = py::call_guard<py::gil_scoped_release>;
  m.def("project_isotropic", &project_isotropic, release(), "EWA projection of isotropic Gaussians");
  m.def("project_isotropic_backward", &project_isotropic_backward, release(), "gradients of project_isotropic");
  m.def("bin_gaussians", &bin_gaussians, release(), "tile lists sorted by depth");
  m.def("composite_forward", &composite_forward, release(), "front-to-back compositing");
  m.def("composite_backward", &composite_backward, release(), "gradients of composite_forward per Gaussian");
}
