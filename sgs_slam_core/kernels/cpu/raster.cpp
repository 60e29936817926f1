// Compiled CPU backend of the tiled Gaussian compositor: binning, forward and backward.
//
// Same maths as sgs_slam_core/render/composite.py (the reference):
//   q = A dx^2 + 2 B dx dy + C dy^2, dx = pixel_x - u (pixel centres at integer coordinates)
//   alpha = min(alpha_max, o exp(-q/2)), zero unless q < extent^2 and o exp(-q/2) > alpha_min
//   a pixel stops ("done") at the first Gaussian that would take its transmittance below
//   max(t_min, 1e-30); that Gaussian and all later ones are skipped (3DGS's early termination)
//   w_i = alpha_i T_i, image = sum_i w_i f_i, silhouette = 1 - T_final
//
// Parallelism: OpenMP over tiles, heaviest first; each tile is processed by one thread, sequentially
// over its depth-sorted Gaussians, with the tile's pixels in packs of W lanes (compact pixel blocks) in
// explicit SIMD vectors (GCC vector extensions, lowered to AVX-512, AVX2 or SSE by -march=native).
// Each Gaussian visits only the packs its footprint box meets (a 64-bit mask per Gaussian and tile).
// The forward runs pack by pack with the sums in registers; the backward runs Gaussian by Gaussian
// over its packs. Backward writes one gradient row per (tile, Gaussian) intersection, then sums each
// Gaussian's rows in intersection order; nothing is accumulated across threads, so results do not
// depend on the thread count or scheduling.

#include <torch/extension.h>
#include <omp.h>
#if defined(__AVX__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <type_traits>
#include <vector>

namespace {

constexpr int kGeomGrads = 6;  // u, v, A, B, C, opacity

// ---------------------------------------------------------------------------------------------
// SIMD packs: 16 floats with AVX-512 (faster there than 8), else 8; 4 doubles.
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
using Mask = typename Pack<T>::I;  // lane masks: all bits set = true

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

// Horizontal sums of n vectors: with AVX-512, 16 at a time by a shuffle tree that halves the lanes
// of pairs of vectors at each level (15 shuffle pairs for 16 vectors instead of 4 per vector). Each
// sum adds the same lane pairs in the same order as hsum(), so results are equal bit for bit and
// deterministic. Other widths sum vector by vector.
#if defined(__AVX512F__)
inline V<float> fold8(V<float> a, V<float> b) {
  return __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23) +
         __builtin_shufflevector(a, b, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31);
}
inline V<float> fold4(V<float> a, V<float> b) {
  return __builtin_shufflevector(a, b, 0, 1, 2, 3, 16, 17, 18, 19, 8, 9, 10, 11, 24, 25, 26, 27) +
         __builtin_shufflevector(a, b, 4, 5, 6, 7, 20, 21, 22, 23, 12, 13, 14, 15, 28, 29, 30, 31);
}
inline V<float> fold2(V<float> a, V<float> b) {
  return __builtin_shufflevector(a, b, 0, 1, 16, 17, 4, 5, 20, 21, 8, 9, 24, 25, 12, 13, 28, 29) +
         __builtin_shufflevector(a, b, 2, 3, 18, 19, 6, 7, 22, 23, 10, 11, 26, 27, 14, 15, 30, 31);
}
inline V<float> fold1(V<float> a, V<float> b) {
  return __builtin_shufflevector(a, b, 0, 16, 2, 18, 4, 20, 6, 22, 8, 24, 10, 26, 12, 28, 14, 30) +
         __builtin_shufflevector(a, b, 1, 17, 3, 19, 5, 21, 7, 23, 9, 25, 11, 27, 13, 29, 15, 31);
}
inline V<float> fold_tree(const V<float>* v) {  // v[16] -> lane l holds the sum of v[tree_lanes()[l]]
  V<float> a[8], b[4], c[2];
  for (int i = 0; i < 8; ++i) a[i] = fold8(v[2 * i], v[2 * i + 1]);
  for (int i = 0; i < 4; ++i) b[i] = fold4(a[2 * i], a[2 * i + 1]);
  for (int i = 0; i < 2; ++i) c[i] = fold2(b[2 * i], b[2 * i + 1]);
  return fold1(c[0], c[1]);
}
inline const std::array<int, 16>& tree_lanes() {
  static const std::array<int, 16> lanes = [] {
    V<float> v[16];
    for (int i = 0; i < 16; ++i) v[i] = V<float>{} + float(i);
    const V<float> r = fold_tree(v);
    std::array<int, 16> out{};
    for (int l = 0; l < 16; ++l) out[l] = static_cast<int>(r[l] / 16.0f);
    return out;
  }();
  return lanes;
}
inline void hsum_many(const V<float>* v, int n, float* out) {
  const std::array<int, 16>& lanes = tree_lanes();
  for (int first = 0; first < n; first += 16, v += 16, out += 16) {
    const int m = std::min(n - first, 16);
    V<float> padded[16];
    for (int i = 0; i < 16; ++i) padded[i] = i < m ? v[i] : V<float>{};
    const V<float> r = fold_tree(padded);
    for (int l = 0; l < 16; ++l)
      if (lanes[l] < m) out[lanes[l]] = r[l];
  }
}
#else
inline void hsum_many(const V<float>* v, int n, float* out) {
  for (int i = 0; i < n; ++i) out[i] = hsum(v[i]);
}
#endif
inline void hsum_many(const V<double>* v, int n, double* out) {
  for (int i = 0; i < n; ++i) out[i] = hsum(v[i]);
}


// exp(x) for x <= 0 (Cephes expf polynomial, relative error ~2e-7); arguments below -87 give a
// tiny normal number. With AVX-512 the power of two is applied by vscalefps and n is rounded by
// vrndscaleps; otherwise by the 1.5 * 2^23 rounding trick and an exponent-bits multiply.
inline V<float> exp_poly(V<float> r) {  // exp(r) for |r| <= ln(2) / 2
  V<float> p = splat(1.9875691500e-4f);
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  return (p * r + 1.0f) * r + 1.0f;  // 1 + r + r^2 p as two fused multiply-adds
}
#if defined(__AVX512F__)
inline V<float> exp_neg(V<float> x) {
  x = (V<float>)_mm512_max_ps((__m512)x, _mm512_set1_ps(-87.0f));
  const V<float> n = (V<float>)_mm512_roundscale_ps((__m512)(x * 1.44269504088896341f), _MM_FROUND_TO_NEAREST_INT);
  const V<float> r = x - n * 0.693145751953125f - n * 1.428606765330187045e-06f;
  return (V<float>)_mm512_scalef_ps((__m512)exp_poly(r), (__m512)n);
}
inline V<float> vmin(V<float> a, V<float> b) { return (V<float>)_mm512_min_ps((__m512)a, (__m512)b); }
#else
inline V<float> exp_neg(V<float> x) {
  using F = V<float>;
  x = x < -87.0f ? splat(-87.0f) : x;
  const F n = (x * 1.44269504088896341f + 12582912.0f) - 12582912.0f;
  const F r = x - n * 0.693145751953125f - n * 1.428606765330187045e-06f;
  const Pack<float>::I bits = (__builtin_convertvector(n, Pack<float>::I) + 127) << 23;
  return exp_poly(r) * (F)bits;  // GCC: a cast between equally sized vectors reinterprets the bits
}
inline V<float> vmin(V<float> a, V<float> b) { return a < b ? a : b; }
#endif
inline V<double> vmin(V<double> a, V<double> b) { return a < b ? a : b; }
inline V<float> vmax(V<float> a, V<float> b) { return a > b ? a : b; }
#if defined(__AVX512F__)
inline V<float> vsqrt(V<float> x) { return (V<float>)_mm512_sqrt_ps((__m512)x); }
#elif defined(__AVX__)
inline V<float> vsqrt(V<float> x) { return (V<float>)_mm256_sqrt_ps((__m256)x); }
#else
inline V<float> vsqrt(V<float> x) {
  for (int l = 0; l < Pack<float>::W; ++l) x[l] = std::sqrt(x[l]);
  return x;
}
#endif
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

// Per-channel views of images stored as channel groups ([H, W, g] tensors side by side): channel c of
// pixel i is at ptr[c][i * stride[c]]; a null pointer reads as zero (a group without gradient).
template <typename P>
struct Planes {
  std::vector<P*> ptr;
  std::vector<int64_t> stride;
};

// The forward's per-pixel outputs.
template <typename T>
struct FrameOut {
  Planes<T> feat;
  T *sil, *t_final;
  int32_t* count;
};

inline TileView tile_view(const Settings& s, int tile, const int64_t* offsets) {
  return {(tile % s.tiles_x) * s.tile, (tile / s.tiles_x) * s.tile, offsets[tile], offsets[tile + 1]};
}

// Per-Gaussian constants of one slot: centre (u, v) in tile pixels, the exponent
// -q/2 = a dx^2 + b dx dy + c dy^2 (a = -A/2, b = -B, c = -C/2 for the conic (A, B, C)), opacity o.
template <typename T>
struct Splat {
  T u, v, a, b, c, o;
};

// The same constants in image pixels plus the footprint radius r, one record per Gaussian (one
// cache line read per tile it meets, instead of one from each input array).
template <typename T>
struct SplatRecord {
  Splat<T> sp;
  T r, pad;
};

// The kernels' view of the Gaussians: records and feature rows [N, D].
template <typename T>
struct SplatScene {
  const SplatRecord<T>* rec;
  const T* feat;
  int channels;
};

// Records of the Gaussians with a footprint (radius > 0) only: binning lists no other, so the rest
// are never read and stay uninitialised (no pass over memory that nothing uses).
template <typename T>
std::unique_ptr<SplatRecord<T>[]> splat_records(int64_t n, const T* m2d, const T* con, const T* op, const T* rad,
                                                int threads) {
  std::unique_ptr<SplatRecord<T>[]> rec(new SplatRecord<T>[static_cast<size_t>(n)]);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t g = 0; g < n; ++g)
    if (rad[g] > T(0))
      rec[g] = {{m2d[2 * g], m2d[2 * g + 1], T(-0.5) * con[3 * g], -con[3 * g + 1], T(-0.5) * con[3 * g + 2], op[g]},
                rad[g], T(0)};
  return rec;
}

// How a tile's pixels are grouped into packs: a pack is a block of bw x bh = W pixels (4 x 4 for 16
// lanes, 4 x 2 for 8, 2 x 2 for 4), blocks in row-major order, lanes row-major within a block.
// Compact blocks waste fewer lanes on footprints that cover part of a tile than pixel rows do.
struct PackLayout {
  int ts, npack, bw, bh, per_row;  // per_row: blocks per row of blocks
  int bw_shift, bh_shift;          // log2 of bw and bh
  std::array<uint64_t, 33> block_rows;  // [n]: bit i * per_row set for i < n (n block rows from the first)

  // Tile pixel (y * ts + x) of lane l of pack p.
  int pixel(int p, int l) const {
    const int x = (p % per_row) * bw + l % bw, y = (p / per_row) * bh + l / bw;
    return y * ts + x;
  }
};

template <typename T>
PackLayout pack_layout(int ts) {
  constexpr int W = Pack<T>::W;
  constexpr int bw = W >= 16 ? 4 : (W == 8 ? 4 : 2), bh = W / bw;
  PackLayout L{ts, ts * ts / W, bw, bh, ts / bw, __builtin_ctz(bw), __builtin_ctz(bh), {}};
  for (int n = 1; n <= ts / bh && n < 33; ++n) L.block_rows[n] = L.block_rows[n - 1] | uint64_t(1) << ((n - 1) * L.per_row);
  return L;
}

// Bits lo..hi (0 <= lo <= hi <= 63).
inline uint64_t bit_range(int lo, int hi) {
  const uint64_t upto = hi >= 63 ? ~uint64_t(0) : (uint64_t(1) << (hi + 1)) - 1;
  return upto & ~((uint64_t(1) << lo) - 1);
}

// Bit p set when pack p holds a pixel centre of the footprint box [u - r, u + r] x [v - r, v + r]
// (tile coordinates). Outside that box alpha is exactly 0 (the radius bounds both the 3-sigma and
// the alpha_min cut), so the kernels visit only these packs: no data-dependent branch per pack.
inline uint64_t pack_mask(const PackLayout& L, float u, float v, float r) {
  const float last = static_cast<float>(L.ts - 1);
  const float rl = std::max(std::ceil(v - r), 0.f), rh = std::min(std::floor(v + r), last);
  const float cl = std::max(std::ceil(u - r), 0.f), ch = std::min(std::floor(u + r), last);
  if (!(rl <= rh && cl <= ch)) return 0;
  const int b0 = static_cast<int>(rl) >> L.bh_shift, b1 = static_cast<int>(rh) >> L.bh_shift;  // block rows
  const uint64_t cols = bit_range(static_cast<int>(cl) >> L.bw_shift, static_cast<int>(ch) >> L.bw_shift);
  return (L.block_rows[b1 - b0 + 1] * cols) << (b0 * L.per_row);
}

// The tile's Gaussians in slot (depth) order: splat constants, feature rows and the packs each can
// touch, gathered once per tile into thread-owned buffers (reused across tiles).
template <typename T>
struct TileSplats {
  std::vector<T> u, v, a, b, c, o;
  std::vector<uint64_t> packs;
  std::vector<const T*> feat;  // feature row of each slot
  std::vector<T> zero_row;

  // Slots 0..K-1 of the view, then one inert slot K (opacity 0, zero features) that pads loops.
  void gather(const PackLayout& L, const TileView& view, const int32_t* gids, const SplatScene<T>& scene) {
    const size_t K = static_cast<size_t>(view.end - view.begin);
    const int D = scene.channels;
    for (auto* x : {&u, &v, &a, &b, &c, &o}) x->resize(K + 1);
    packs.resize(K + 1);
    feat.resize(K + 1);
    zero_row.assign(D, T(0));
    for (size_t k = 0; k < K; ++k) {
      const int32_t g = gids[view.begin + k];
      const SplatRecord<T>& rec = scene.rec[g];
      u[k] = rec.sp.u - view.x0, v[k] = rec.sp.v - view.y0, a[k] = rec.sp.a, b[k] = rec.sp.b, c[k] = rec.sp.c;
      o[k] = rec.sp.o;
      feat[k] = scene.feat + static_cast<int64_t>(g) * D;
      packs[k] = pack_mask(L, float(u[k]), float(v[k]), float(rec.r));
    }
    u[K] = v[K] = a[K] = b[K] = c[K] = o[K] = T(0);
    feat[K] = zero_row.data();
    packs[K] = 0;
  }
  Splat<T> operator[](size_t k) const { return {u[k], v[k], a[k], b[k], c[k], o[k]}; }
};

// Per-thread buffers of the tile kernels.
template <typename T>
struct Scratch {
  TileSplats<T> splats;
  std::vector<int32_t> slots;  // forward: [npack, K] slots meeting each pack, in depth order
  std::vector<int32_t> nslots;
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

// The alpha cuts in the working precision, held in locals so they stay in registers; the
// footprint cut q < extent^2 is tested as -q/2 > -extent^2/2.
template <typename T>
struct AlphaCut {
  T neg_half_extent2, alpha_min, alpha_max;
};

template <typename T>
inline AlphaCut<T> alpha_cut(const Settings& s) {
  return {static_cast<T>(-0.5 * s.extent2), static_cast<T>(s.alpha_min), static_cast<T>(s.alpha_max)};
}

// Alpha of one Gaussian on W pixels after the footprint and alpha cuts (not the early stop), and the
// offsets dx, dy. exp_neg clamps its argument, so far pixels (huge q) need no clamp of their own.
template <typename T>
inline V<T> raw_alpha(const AlphaCut<T>& cut, const Splat<T>& g, V<T> px, V<T> py, V<T>& dx, V<T>& dy) {
  dx = px - g.u;
  dy = py - g.v;
  const V<T> e = dx * (g.a * dx + g.b * dy) + g.c * dy * dy;  // -q/2
  const V<T> a = vmin(g.o * exp_neg(e), splat(cut.alpha_max));
  return (e > cut.neg_half_extent2) & (a > cut.alpha_min) ? a : splat(T(0));
}

// Tile coordinates of every lane, in pack order: px[p * W + l], py[p * W + l].
template <typename T>
void pixel_grid(const PackLayout& L, T* px, T* py) {
  constexpr int W = Pack<T>::W;
  for (int p = 0; p < L.npack; ++p)
    for (int l = 0; l < W; ++l) {
      const int pix = L.pixel(p, l);
      px[p * W + l] = static_cast<T>(pix % L.ts);
      py[p * W + l] = static_cast<T>(pix / L.ts);
    }
}

// Forward of one tile, pack by pack: each pack of W pixels runs through the depth-sorted Gaussians
// that can touch it, with its accumulators in registers (the channel count DC is a template argument
// for the common 4 = colour + depth and 7 = colour + 3 semantics + depth; 0 = any, read at run
// time). Per pixel the blending order is the same as a Gaussian-major loop over all slots, so
// results do not depend on the loop order.
template <typename T, int DC>
void forward_tile(const Settings& s, int tile, const int64_t* offsets, const int32_t* gids, const SplatScene<T>& scene,
                  const FrameOut<T>& out, Scratch<T>& sc) {
  constexpr int W = Pack<T>::W;
  const int ts = s.tile, npix = ts * ts, D = DC > 0 ? DC : s.channels;
  const PackLayout layout = pack_layout<T>(ts);
  const TileView view = tile_view(s, tile, offsets);
  const int64_t K = view.end - view.begin;
  TileSplats<T>& sp = sc.splats;
  sp.gather(layout, view, gids, scene);
  // Slots meeting each pack, in depth order, padded with the inert slot K to an even count.
  const int64_t cap = K + 2;
  sc.slots.resize(static_cast<size_t>(layout.npack) * cap);
  sc.nslots.assign(layout.npack, 0);
  for (int64_t k = 0; k < K; ++k)
    for (uint64_t m = sp.packs[k]; m; m &= m - 1) {
      const int p = __builtin_ctzll(m);
      sc.slots[p * cap + sc.nslots[p]++] = static_cast<int32_t>(k);
    }
  for (int p = 0; p < layout.npack; ++p) sc.slots[p * cap + sc.nslots[p]] = static_cast<int32_t>(K);
  sc.reset(static_cast<size_t>(npix) * 2);
  T* px = sc.take(npix);
  T* py = sc.take(npix);
  pixel_grid(layout, px, py);
  const T never = T(1e30);
  const T floor_t = static_cast<T>(std::max(s.t_min, 1e-30));
  const AlphaCut<T> cut = alpha_cut<T>(s);
  V<T> acc_fixed[DC > 0 ? DC : 1];
  std::vector<V<T>> acc_any(DC > 0 ? 0 : D);
  V<T>* acc = DC > 0 ? acc_fixed : acc_any.data();
  for (int pack = 0; pack < layout.npack; ++pack) {
    const int b = pack * W;
    const V<T> x = load(px + b), y = load(py + b);
    for (int c = 0; c < D; ++c) acc[c] = V<T>{};
    V<T> t = splat(T(1)), stopped = splat(never);  // stopped: slot of the lane's stop, or never
    // Blending is sequential through t; the alphas are not, so two slots' alphas are computed
    // together (two independent exp chains) before both are blended in order.
    auto blend = [&](int32_t k, V<T> a) {
      const V<T> t_next = t * (T(1) - a);
      const auto live = stopped == never;
      const auto low = t_next < floor_t;
      stopped = (live & low) ? splat(static_cast<T>(k)) : stopped;
      const auto keep = live & ~low;
      const V<T> w = keep ? a * t : splat(T(0));
      t = keep ? t_next : t;
      const T* f = sp.feat[k];
      for (int c = 0; c < D; ++c) acc[c] += w * f[c];
    };
    const int32_t* slots = sc.slots.data() + pack * cap;
    for (int j = 0, n = sc.nslots[pack]; j < n; j += 2) {
      const int32_t k0 = slots[j], k1 = slots[j + 1];
      V<T> dx, dy;
      const V<T> a0 = raw_alpha(cut, sp[k0], x, y, dx, dy);
      const V<T> a1 = raw_alpha(cut, sp[k1], x, y, dx, dy);
      blend(k0, a0);
      blend(k1, a1);
      if ((j & 15) == 14 && hsum(stopped == never ? splat(T(1)) : splat(T(0))) == T(0)) break;  // every pixel has stopped
    }
    const T total = static_cast<T>(K);
    for (int l = 0; l < W; ++l) {
      const int p = layout.pixel(pack, l), px_ = view.x0 + p % ts, py_ = view.y0 + p / ts;
      if (px_ >= s.width || py_ >= s.height) continue;
      const int64_t pix = static_cast<int64_t>(py_) * s.width + px_;
      for (int c = 0; c < D; ++c) out.feat.ptr[c][pix * out.feat.stride[c]] = acc[c][l];
      out.sil[pix] = T(1) - t[l];
      out.t_final[pix] = t[l];
      out.count[pix] = static_cast<int32_t>(stopped[l] < total ? stopped[l] : total);
    }
  }
}

// One back-to-front pass (3DGS-style): the forward saved each pixel's final transmittance and how
// many slots it blended; T_i is recovered as T_{i+1} / (1 - alpha_i) and the suffix sum
// S_i = sum_{j>i} w_j c_j grows as we go, so dL/dalpha_i = T_i c_i - S_i / (1 - alpha_i).
// Each Gaussian visits only the packs its footprint meets and in which some pixel blended it.
template <typename T, int DC>
void backward_tile(const Settings& s, int tile, const int64_t* offsets, const int32_t* gids, const SplatScene<T>& scene,
                   const Planes<const T>& g_img, const T* g_sil, const T* t_final, const int32_t* count, T* out,
                   Scratch<T>& sc) {
  constexpr int W = Pack<T>::W;
  const int ts = s.tile, npix = ts * ts, D = DC > 0 ? DC : s.channels, stride = kGeomGrads + D;
  const PackLayout layout = pack_layout<T>(ts);
  const TileView view = tile_view(s, tile, offsets);
  sc.reset(static_cast<size_t>(npix) * (D + 7));
  T* gp = sc.take(static_cast<size_t>(D) * npix);  // [D, npix] upstream gradient of the features
  T* gs = sc.take(npix);                            // upstream gradient of the silhouette
  T* trans = sc.take(npix);                         // T after the current slot (starts at T_final)
  T* nblend = sc.take(npix);
  T* suffix = sc.take(npix);
  T* px = sc.take(npix);
  T* py = sc.take(npix);
  pixel_grid(layout, px, py);
  // Per pack, the slots its longest-blending pixel blended; 0 for packs without upstream gradient
  // (they pass none on, which tracking's masked losses make common).
  std::vector<std::pair<int32_t, int>> by_count(layout.npack, {0, 0});
  int32_t max_count = 0;
  for (int pack = 0; pack < layout.npack; ++pack) {
    int32_t most = 0;
    bool any_grad = false;
    for (int p = pack * W; p < (pack + 1) * W; ++p) {  // p: lane index in pack order
      const int tp = layout.pixel(pack, p % W), x = view.x0 + tp % ts, y = view.y0 + tp / ts;
      const bool inside = x < s.width && y < s.height;
      const int64_t pix = static_cast<int64_t>(y) * s.width + x;
      for (int c = 0; c < D; ++c) {
        gp[c * npix + p] = inside && g_img.ptr[c] ? g_img.ptr[c][pix * g_img.stride[c]] : T(0);
        any_grad |= gp[c * npix + p] != T(0);
      }
      gs[p] = inside && g_sil ? g_sil[pix] : T(0);
      any_grad |= gs[p] != T(0);
      trans[p] = inside ? t_final[pix] : T(1);
      const int32_t n = inside ? count[pix] : 0;
      nblend[p] = static_cast<T>(n);
      most = std::max(most, n);
    }
    by_count[pack] = {any_grad ? most : 0, pack};
    max_count = std::max(max_count, by_count[pack].first);
  }
  // Slots past every pixel's stop contribute nothing; their rows are zeroed here (rows are not pre-filled).
  std::fill(out + (view.begin + max_count) * stride, out + view.end * stride, T(0));
  const TileView blended{view.x0, view.y0, view.begin, view.begin + max_count};
  TileSplats<T>& sp = sc.splats;
  sp.gather(layout, blended, gids, scene);
  // Packs in decreasing order of that count: slot k is live in the packs of the first entries.
  std::sort(by_count.begin(), by_count.end(), [](auto a, auto b) { return a.first > b.first; });
  uint64_t live_packs = 0;
  size_t next = 0;
  const AlphaCut<T> cut = alpha_cut<T>(s);
  // Per-Gaussian sums over the packs, in registers when DC is known: 6 geometric partials
  // (dL/dq x dx, x dy, x dx^2, x dx dy, x dy^2; o dL/do), then the D feature gradients.
  constexpr int kSums = DC > 0 ? kGeomGrads + DC : 1;
  V<T> sums_fixed[kSums];
  std::vector<V<T>> sums_any(DC > 0 ? 0 : kGeomGrads + D);
  V<T>* sums = DC > 0 ? sums_fixed : sums_any.data();
  V<T>* gf = sums + kGeomGrads;
  T tot_fixed[kSums];
  std::vector<T> tot_any(DC > 0 ? 0 : kGeomGrads + D);
  T* tot = DC > 0 ? tot_fixed : tot_any.data();
  for (int64_t k = max_count - 1; k >= 0; --k) {
    while (next < by_count.size() && by_count[next].first > k) live_packs |= uint64_t(1) << by_count[next++].second;
    const Splat<T> g = sp[k];
    const T* f = sp.feat[k];
    const T slot = static_cast<T>(k);
    for (int c = 0; c < kGeomGrads + D; ++c) sums[c] = V<T>{};
    for (uint64_t m = sp.packs[k] & live_packs; m; m &= m - 1) {
      const int b = __builtin_ctzll(m) * W;
      V<T> dx, dy;
      V<T> a = raw_alpha(cut, g, load(px + b), load(py + b), dx, dy);
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
      const V<T> free = (a > T(0)) & (a < cut.alpha_max) ? a : splat(T(0));  // clamped or cut alphas pass no gradient
      const V<T> gq = T(-0.5) * g_alpha * free;                              // dL/dq
      sums[0] += gq * dx;
      sums[1] += gq * dy;
      sums[2] += gq * dx * dx;
      sums[3] += gq * dx * dy;
      sums[4] += gq * dy * dy;
      sums[5] += g_alpha * free;  // o dL/do
    }
    hsum_many(sums, kGeomGrads + D, tot);
    const T sx = tot[0], sy = tot[1], A = T(-2) * g.a, B = -g.b, C = T(-2) * g.c;
    T* row = out + (view.begin + k) * stride;
    row[0] = T(-2) * (A * sx + B * sy);
    row[1] = T(-2) * (B * sx + C * sy);
    row[2] = tot[2];
    row[3] = T(2) * tot[3];
    row[4] = tot[4];
    row[5] = g.o > T(0) ? tot[5] / g.o : T(0);
    for (int c = 0; c < D; ++c) row[kGeomGrads + c] = tot[kGeomGrads + c];
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

// Pixels of a tile no Gaussian touches: features 0, silhouette 0, transmittance 1, no slots.
template <typename T>
void clear_tile(const Settings& s, int tile, const FrameOut<T>& out) {
  const int x0 = (tile % s.tiles_x) * s.tile, y0 = (tile / s.tiles_x) * s.tile;
  for (int y = y0; y < std::min(y0 + s.tile, s.height); ++y)
    for (int x = x0; x < std::min(x0 + s.tile, s.width); ++x) {
      const int64_t pix = static_cast<int64_t>(y) * s.width + x;
      for (int c = 0; c < s.channels; ++c) out.feat.ptr[c][pix * out.feat.stride[c]] = T(0);
      out.sil[pix] = T(0);
      out.t_final[pix] = T(1);
      out.count[pix] = 0;
    }
}

// Tiles in decreasing order of their Gaussian counts (ties by index), so the threads take the
// heaviest tiles first and finish together (longest-processing-time-first); each tile's result is
// the same in any order.
inline std::vector<int> heavy_first(const Settings& s, const int64_t* off) {
  std::vector<int> order(static_cast<size_t>(s.tiles_x * s.tiles_y));
  for (size_t t = 0; t < order.size(); ++t) order[t] = static_cast<int>(t);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return off[a + 1] - off[a] > off[b + 1] - off[b]; });
  return order;
}

template <typename T>
void forward_all(const Settings& s, const int64_t* off, const int32_t* gid, const SplatScene<T>& scene,
                 const FrameOut<T>& out, int threads) {
  const int num_tiles = s.tiles_x * s.tiles_y;
  const std::vector<int> order = heavy_first(s, off);
#pragma omp parallel num_threads(threads)
  {
    Scratch<T> scratch;
#pragma omp for schedule(dynamic, 1)
    for (int i = 0; i < num_tiles; ++i) {
      const int t = order[i];
      if (off[t + 1] == off[t]) {
        clear_tile(s, t, out);
        continue;
      }
      with_channels(s.channels, [&](auto dc) {
        forward_tile<T, decltype(dc)::value>(s, t, off, gid, scene, out, scratch);
      });
    }
  }
}

template <typename T>
void backward_all(const Settings& s, const int64_t* off, const int32_t* gid, const SplatScene<T>& scene,
                  const Planes<const T>& gi, const T* gs, const T* t_final, const int32_t* count, T* out,
                  int threads) {
  const int num_tiles = s.tiles_x * s.tiles_y;
  const std::vector<int> order = heavy_first(s, off);
#pragma omp parallel num_threads(threads)
  {
    Scratch<T> scratch;
#pragma omp for schedule(dynamic, 1)
    for (int i = 0; i < num_tiles; ++i) {
      const int t = order[i];
      if (off[t + 1] == off[t]) continue;
      with_channels(s.channels, [&](auto dc) {
        backward_tile<T, decltype(dc)::value>(s, t, off, gid, scene, gi, gs, t_final, count, out, scratch);
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
    std::fill(out + lo * stride, out + hi * stride, T(0));  // each thread zeroes the rows it sums into
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
  TORCH_CHECK(tile == 4 || tile == 8 || tile == 16 || tile == 32, "the cpu backend supports tile sizes 4, 8, 16 and 32, got ",
              tile);
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

// Largest tile side whose packs fit the 64-bit pack masks: (tile^2 / W) <= 64.
template <typename T>
int64_t max_tile_for() {
  int64_t tile = 4;
  while (tile < 32 && (2 * tile) * (2 * tile) / Pack<T>::W <= 64) tile *= 2;
  return tile;
}

int64_t max_tile(bool double_precision) { return double_precision ? max_tile_for<double>() : max_tile_for<float>(); }

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

// The camera's constants in the working precision, computed once per call instead of per Gaussian
// (the same expressions in the same order, so the results are bit for bit those of the per-Gaussian
// form): focal lengths, principal point, the clamp of x/z and y/z to 1.3x the field of view used by
// the projection's Jacobian (as 3DGS/gsplat), near plane, dilation, and the footprint cuts.
template <typename T>
struct Proj {
  T fx, fy, cx, cy, lx0, lx1, ly0, ly1, near, eps2d, alpha_min, extent2;

  explicit Proj(const Camera& k)
      : fx(T(k.fx)), fy(T(k.fy)), cx(T(k.cx)), cy(T(k.cy)), near(T(k.near)), eps2d(T(k.eps2d)),
        alpha_min(T(k.alpha_min)), extent2(T(k.extent_sigma * k.extent_sigma)) {
    const T tan_x = T(0.5) * T(k.width) / fx, tan_y = T(0.5) * T(k.height) / fy;
    lx0 = -(cx + T(0.5)) / fx - T(0.3) * tan_x;
    lx1 = (T(k.width) - cx - T(0.5)) / fx + T(0.3) * tan_x;
    ly0 = -(cy + T(0.5)) / fy - T(0.3) * tan_y;
    ly1 = (T(k.height) - cy - T(0.5)) / fy + T(0.3) * tan_y;
  }
};

template <typename T>
inline void project_one(const Proj<T>& k, const T* mc, T scale, T opacity, T* m2d, T* con, T* radius, T* depth) {
  const T x = mc[0], y = mc[1], z = mc[2];
  const bool front = z > k.near;
  const T zs = front ? z : T(1);
  const T xz = x / zs, yz = y / zs;
  m2d[0] = k.fx * xz + k.cx;
  m2d[1] = k.fy * yz + k.cy;
  const T tx = std::min(std::max(xz, k.lx0), k.lx1), ty = std::min(std::max(yz, k.ly0), k.ly1);
  const T iz = T(1) / zs;
  const T s2 = (scale * iz) * (scale * iz);
  const T a = s2 * k.fx * k.fx * (T(1) + tx * tx) + k.eps2d;
  const T b = s2 * k.fx * k.fy * tx * ty;
  const T c = s2 * k.fy * k.fy * (T(1) + ty * ty) + k.eps2d;
  const T det = std::max(a * c - b * b, T(1e-12));
  con[0] = c / det;
  con[1] = -b / det;
  con[2] = a / det;
  depth[0] = z;
  const T lam = T(0.5) * (a + c) + std::sqrt((T(0.5) * (a - c)) * (T(0.5) * (a - c)) + b * b);
  const T ratio = std::max(opacity / k.alpha_min, T(1));
  const T extent2 = std::min(T(2) * std::log(ratio), k.extent2);
  const T r = std::sqrt(extent2 * lam);
  const bool visible = front && opacity >= k.alpha_min && std::isfinite(r);
  radius[0] = visible ? r : T(0);
}

// Gradients of project_one with respect to the camera-frame mean and the scale.
template <typename T>
inline void project_one_backward(const Proj<T>& k, const T* mc, T scale, const T* g_m2d, const T* g_con, T g_depth,
                                 T* g_mc, T* g_scale) {
  const T x = mc[0], y = mc[1], z = mc[2];
  if (!(z > k.near)) {
    g_mc[0] = g_mc[1] = g_mc[2] = T(0);
    *g_scale = T(0);
    return;
  }
  const T fx = k.fx, fy = k.fy;
  const T xz = x / z, yz = y / z, iz = T(1) / z;
  const T tx = std::min(std::max(xz, k.lx0), k.lx1), ty = std::min(std::max(yz, k.ly0), k.ly1);
  const bool free_x = xz > k.lx0 && xz < k.lx1, free_y = yz > k.ly0 && yz < k.ly1;
  const T s2 = (scale * iz) * (scale * iz);
  const T a = s2 * fx * fx * (T(1) + tx * tx) + k.eps2d;
  const T b = s2 * fx * fy * tx * ty;
  const T c = s2 * fy * fy * (T(1) + ty * ty) + k.eps2d;
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

}  // namespace

// Tile lists: Gaussians sorted by depth (ties by index, as a stable sort), appended to every tile
// their footprint box touches. Returns (gaussian ids [I] int32, tile offsets [T + 1] int64).
// Stable LSD radix sort of (depth bits << 32 | id) keys on their upper 32 bits: the ids are pushed in
// ascending order, so the result equals sorting the whole keys (about 10x faster than std::sort).
void sort_by_depth(std::vector<uint64_t>& keys) {
  // The four digits' histograms in one read; a digit all keys share is not scattered (it would
  // leave the order as it is), which skips most passes of the high exponent bits.
  std::vector<size_t> start(4 * 257, 0);
  for (const uint64_t k : keys)
    for (int d = 0; d < 4; ++d) ++start[d * 257 + ((k >> (32 + 8 * d)) & 0xffu) + 1];
  std::vector<uint64_t> tmp(keys.size());
  for (int d = 0; d < 4; ++d) {
    size_t* s = &start[d * 257];
    if (*std::max_element(s + 1, s + 257) == keys.size()) continue;
    for (int b = 0; b < 256; ++b) s[b + 1] += s[b];
    const int shift = 32 + 8 * d;
    for (const uint64_t k : keys) tmp[s[(k >> shift) & 0xffu]++] = k;
    keys.swap(tmp);
  }
}

// Footprint tile rectangle and sort key of Gaussian g; false when it touches no pixel.
template <typename T>
inline bool tile_rect(const T* mp, const T* rp, const T* dp, int64_t g, int64_t width, int64_t height, int64_t tile,
                      int32_t* rect, uint64_t* key) {
  const double u = mp[2 * g], v = mp[2 * g + 1], rad = rp[g];
  if (!(rad > 0) || !std::isfinite(u) || !std::isfinite(v)) return false;
  const double xl = std::ceil(u - rad), xh = std::floor(u + rad), yl = std::ceil(v - rad), yh = std::floor(v + rad);
  if (xl > width - 1 || xh < 0 || yl > height - 1 || yh < 0 || xl > xh || yl > yh) return false;
  auto clampi = [](double x, double hi) { return static_cast<int32_t>(std::min(std::max(x, 0.0), hi)); };
  rect[0] = clampi(xl, width - 1) / static_cast<int32_t>(tile);
  rect[1] = clampi(xh, width - 1) / static_cast<int32_t>(tile);
  rect[2] = clampi(yl, height - 1) / static_cast<int32_t>(tile);
  rect[3] = clampi(yh, height - 1) / static_cast<int32_t>(tile);
  // Visible Gaussians have depth > near > 0, so the float bits sort like the values.
  const float depth = static_cast<float>(dp[g]);
  uint32_t bits;
  std::memcpy(&bits, &depth, sizeof(bits));
  *key = (static_cast<uint64_t>(bits) << 32) | static_cast<uint64_t>(g);
  return true;
}

template <typename T>
std::vector<torch::Tensor> bin_impl(const T* mp, const T* rp, const T* dp, int64_t n, int64_t width, int64_t height,
                                    int64_t tile, int threads) {
  const int64_t tiles_x = (width + tile - 1) / tile, tiles_y = (height + tile - 1) / tile, num_tiles = tiles_x * tiles_y;
  using Rect = std::array<int32_t, 4>;
  // Pass 1, over `threads` equal id ranges in parallel: the Gaussians that touch the image (ascending
  // ids within a range), their sort keys and tile rectangles, and each range's tile counts. The
  // ranges concatenated in order give the same list for any number of threads the runtime grants.
  std::unique_ptr<uint64_t[]> key_all(new uint64_t[static_cast<size_t>(n)]);
  std::unique_ptr<Rect[]> rect_all(new Rect[static_cast<size_t>(n)]);
  std::vector<int64_t> start(static_cast<size_t>(threads) + 1, 0);
  std::vector<int64_t> counts(static_cast<size_t>(threads * num_tiles), 0);
  auto first = [&](int64_t p) { return n * p / threads; };
#pragma omp parallel for num_threads(threads) schedule(static, 1)
  for (int64_t p = 0; p < threads; ++p) {
    int64_t out = first(p);
    int64_t* count = &counts[p * num_tiles];
    for (int64_t g = first(p); g < first(p + 1); ++g) {
      Rect& r = rect_all[out];
      if (!tile_rect(mp, rp, dp, g, width, height, tile, r.data(), &key_all[out])) continue;
      for (int64_t ty = r[2]; ty <= r[3]; ++ty)
        for (int64_t tx = r[0]; tx <= r[1]; ++tx) ++count[ty * tiles_x + tx];
      ++out;
    }
    start[p + 1] = out - first(p);
  }
  for (int64_t p = 0; p < threads; ++p) start[p + 1] += start[p];
  // Compact lists; a key's low half becomes its position there, which orders ties as the ids do.
  const int64_t kept = start[threads];
  std::vector<uint64_t> keys(static_cast<size_t>(kept));
  std::vector<Rect> rects(static_cast<size_t>(kept));
  std::vector<int32_t> ids(static_cast<size_t>(kept));
#pragma omp parallel for num_threads(threads) schedule(static, 1)
  for (int64_t p = 0; p < threads; ++p)
    for (int64_t i = 0; i < start[p + 1] - start[p]; ++i) {
      const int64_t from = first(p) + i, to = start[p] + i;
      ids[to] = static_cast<int32_t>(key_all[from] & 0xffffffffu);
      keys[to] = (key_all[from] & ~uint64_t(0xffffffffu)) | static_cast<uint64_t>(to);
      rects[to] = rect_all[from];
    }
  sort_by_depth(keys);
  auto offsets = torch::empty({num_tiles + 1}, torch::kInt64);
  int64_t* off = offsets.data_ptr<int64_t>();
  off[0] = 0;
  for (int64_t t = 0; t < num_tiles; ++t) {
    int64_t c = 0;
    for (int64_t p = 0; p < threads; ++p) c += counts[p * num_tiles + t];
    off[t + 1] = off[t] + c;
  }
  auto gids = torch::empty({off[num_tiles]}, torch::kInt32);
  int32_t* gp = gids.data_ptr<int32_t>();
  std::vector<int64_t> cursor(off, off + num_tiles);
  for (const uint64_t key : keys) {
    const int64_t at = static_cast<int64_t>(key & 0xffffffffu);
    const Rect& r = rects[at];
    const int32_t g = ids[at];
    for (int64_t ty = r[2]; ty <= r[3]; ++ty)
      for (int64_t tx = r[0]; tx <= r[1]; ++tx) gp[cursor[ty * tiles_x + tx]++] = g;
  }
  return {gids, offsets};
}

std::vector<torch::Tensor> bin_gaussians(torch::Tensor means2d, torch::Tensor radii, torch::Tensor depths, int64_t width,
                                         int64_t height, int64_t tile, int64_t threads) {
  TORCH_CHECK(means2d.device().is_cpu() && radii.device().is_cpu() && depths.device().is_cpu(), "CPU tensors only");
  auto m = means2d.contiguous();
  auto r = radii.contiguous().to(m.scalar_type());
  auto d = depths.contiguous().to(m.scalar_type());
  std::vector<torch::Tensor> out;
  AT_DISPATCH_FLOATING_TYPES(m.scalar_type(), "bin_gaussians", [&] {
    out = bin_impl<scalar_t>(m.data_ptr<scalar_t>(), r.data_ptr<scalar_t>(), d.data_ptr<scalar_t>(), m.size(0), width,
                             height, tile, static_cast<int>(std::max<int64_t>(threads, 1)));
  });
  return out;
}

template <typename T>
std::unique_ptr<SplatRecord<T>[]> records(const torch::Tensor& m2d, const torch::Tensor& con, const torch::Tensor& op,
                                    const torch::Tensor& rad, int64_t threads) {
  return splat_records<T>(m2d.size(0), m2d.data_ptr<T>(), con.data_ptr<T>(), op.data_ptr<T>(), rad.data_ptr<T>(),
                          static_cast<int>(threads));
}

// Channel c of the groups (sizes summing to the feature count) as a plane of tensor ts[group].
template <typename P>
Planes<P> planes_of(const std::vector<int64_t>& groups, const std::vector<P*>& bases) {
  Planes<P> planes;
  for (size_t g = 0; g < groups.size(); ++g)
    for (int64_t c = 0; c < groups[g]; ++c) {
      planes.ptr.push_back(bases[g] ? bases[g] + c : nullptr);
      planes.stride.push_back(groups[g]);
    }
  return planes;
}

void check_groups(const std::vector<int64_t>& groups, const torch::Tensor& features) {
  int64_t total = 0;
  for (const int64_t g : groups) {
    TORCH_CHECK(g >= 0, "channel group sizes must be >= 0, got ", g);
    total += g;
  }
  TORCH_CHECK(total == features.size(1), "channel groups sum to ", total, " but features have ", features.size(1));
}

// (image groups [H, W, g] for each g in groups..., silhouette [H, W], final transmittance [H, W],
// blended slots [H, W] int32); the groups split the D feature channels in order.
std::vector<torch::Tensor> composite_forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                             torch::Tensor radii, torch::Tensor features, torch::Tensor gids,
                                             torch::Tensor offsets, std::vector<int64_t> groups, int64_t width,
                                             int64_t height, int64_t tile, double alpha_min, double alpha_max,
                                             double extent2, double t_min, int64_t threads) {
  check_inputs(means2d, conics, opacities, radii, features);
  check_groups(groups, features);
  const auto s = make_settings(width, height, tile, features.size(1), alpha_min, alpha_max, extent2, t_min);
  std::vector<torch::Tensor> outs;
  for (const int64_t g : groups) outs.push_back(torch::empty({height, width, g}, features.options()));
  auto sil = torch::empty({height, width}, features.options());  // every pixel written by its tile
  auto t_final = torch::empty({height, width}, features.options());
  auto count = torch::empty({height, width}, torch::kInt32);
  const int64_t* off = offsets.data_ptr<int64_t>();
  const int32_t* gid = gids.data_ptr<int32_t>();
  AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "composite_forward", [&] {
    TORCH_CHECK(tile <= max_tile_for<scalar_t>(), "tile ", tile, " is above this build's maximum ", max_tile_for<scalar_t>());
    std::vector<scalar_t*> bases;
    for (auto& o : outs) bases.push_back(o.data_ptr<scalar_t>());
    const FrameOut<scalar_t> out{planes_of(groups, bases), sil.data_ptr<scalar_t>(), t_final.data_ptr<scalar_t>(),
                                 count.data_ptr<int32_t>()};
    const auto rec = records<scalar_t>(means2d, conics, opacities, radii, threads);
    forward_all<scalar_t>(s, off, gid, {rec.get(), features.data_ptr<scalar_t>(), s.channels}, out,
                          static_cast<int>(threads));
  });
  outs.insert(outs.end(), {sil, t_final, count});
  return outs;
}

// Per-Gaussian gradients [N, 6 + D]: (u, v, A, B, C, opacity, features...), from the gradients of
// the forward's outputs (one per channel group, then the silhouette's; None = zero).
torch::Tensor composite_backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                 torch::Tensor radii, torch::Tensor features, torch::Tensor gids, torch::Tensor offsets,
                                 torch::Tensor t_final, torch::Tensor count, std::vector<int64_t> groups,
                                 std::vector<c10::optional<torch::Tensor>> grad_groups,
                                 c10::optional<torch::Tensor> grad_sil, int64_t width, int64_t height, int64_t tile,
                                 double alpha_min, double alpha_max, double extent2, double t_min, int64_t threads) {
  check_inputs(means2d, conics, opacities, radii, features);
  check_groups(groups, features);
  TORCH_CHECK(grad_groups.size() == groups.size(), "one gradient (or None) per channel group");
  const auto s = make_settings(width, height, tile, features.size(1), alpha_min, alpha_max, extent2, t_min);
  std::vector<torch::Tensor> grads;  // contiguous, in the features' dtype (kept alive here)
  for (size_t g = 0; g < groups.size(); ++g) {
    const auto& t = grad_groups[g];
    TORCH_CHECK(!t || (t->dim() == 3 && t->size(0) == height && t->size(1) == width && t->size(2) == groups[g]),
                "gradient of channel group ", g, " must be [H, W, ", groups[g], "]");
    grads.push_back(t ? t->contiguous().to(features.scalar_type()) : torch::Tensor());
  }
  torch::Tensor g_sil;
  if (grad_sil) {
    TORCH_CHECK(grad_sil->dim() == 2 && grad_sil->size(0) == height && grad_sil->size(1) == width,
                "silhouette gradient must be [H, W]");
    g_sil = grad_sil->contiguous().to(features.scalar_type());
  }
  const int64_t stride = kGeomGrads + features.size(1);
  auto rows = torch::empty({gids.size(0), stride}, features.options());  // every row written by its tile
  auto out = torch::empty({means2d.size(0), stride}, features.options());  // zeroed by reduce_rows
  const int64_t* off = offsets.data_ptr<int64_t>();
  const int32_t* gid = gids.data_ptr<int32_t>();
  AT_DISPATCH_FLOATING_TYPES(features.scalar_type(), "composite_backward", [&] {
    TORCH_CHECK(tile <= max_tile_for<scalar_t>(), "tile ", tile, " is above this build's maximum ", max_tile_for<scalar_t>());
    std::vector<const scalar_t*> bases;
    for (auto& g : grads) bases.push_back(g.defined() ? g.data_ptr<scalar_t>() : nullptr);
    const auto rec = records<scalar_t>(means2d, conics, opacities, radii, threads);
    backward_all<scalar_t>(s, off, gid, {rec.get(), features.data_ptr<scalar_t>(), s.channels},
                           planes_of(groups, bases), g_sil.defined() ? g_sil.data_ptr<scalar_t>() : nullptr,
                           t_final.data_ptr<scalar_t>(), count.data_ptr<int32_t>(), rows.data_ptr<scalar_t>(),
                           static_cast<int>(threads));
    reduce_rows<scalar_t>(rows.data_ptr<scalar_t>(), gid, gids.size(0), stride, means2d.size(0),
                          out.data_ptr<scalar_t>(), static_cast<int>(threads));
  });
  return out;
}

// Per Gaussian: camera transform, activations, feature row (colour, semantics, depth) and projection.
// Output row g is input row rows[g] (rows null: row g).
template <typename T>
void prepare_world_all(const Camera& k, int64_t n, int64_t ns, const T* m, const T* ls, const T* lo, const T* col,
                       const T* sem, const T* P, T* pmc, T* psc, T* pop, T* pf, T* pm2d, T* pcon, T* prad,
                       int threads, const int64_t* rows = nullptr) {
  const int64_t d = 3 + ns + 1;
  const Proj<T> pk(k);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t g = 0; g < n; ++g) {
    const int64_t q = rows ? rows[g] : g;
    const T x = m[3 * q], y = m[3 * q + 1], z = m[3 * q + 2];
    T* c = pmc + 3 * g;
    for (int i = 0; i < 3; ++i) c[i] = P[4 * i] * x + P[4 * i + 1] * y + P[4 * i + 2] * z + P[4 * i + 3];
    psc[g] = std::exp(ls[q]);
    pop[g] = T(1) / (T(1) + std::exp(-lo[q]));
    T* f = pf + d * g;
    f[0] = col[3 * q];
    f[1] = col[3 * q + 1];
    f[2] = col[3 * q + 2];
    for (int64_t j = 0; j < ns; ++j) f[3 + j] = sem[ns * q + j];
    project_one(pk, c, psc[g], pop[g], pm2d + 2 * g, pcon + 3 * g, prad + g, f + d - 1);
  }
}

// prepare_world_all for float, Pack<float>::W Gaussians at a time in SIMD lanes: the same formulas in
// the same order, IEEE divisions and square roots in the lanes and the scalar libm's exp and log per
// lane, so for finite inputs the results are bit for bit the scalar path's (tested); a faster
// polynomial exp would change the rounding, and with it the trajectories of real sequences.
// The tail (n % W Gaussians) takes the scalar path. Output row g is input row rows[g] (rows null: g).
void prepare_world(const Camera& k, int64_t n, int64_t ns, const float* m, const float* ls, const float* lo,
                   const float* col, const float* sem, const float* P, float* pmc, float* psc, float* pop, float* pf,
                   float* pm2d, float* pcon, float* prad, int threads, const int64_t* rows) {
  using F = V<float>;
  constexpr int W = Pack<float>::W;
  const int64_t d = 3 + ns + 1, blocks = n / W;
  const Proj<float> pk(k);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t blk = 0; blk < blocks; ++blk) {
    const int64_t g0 = blk * W;
    alignas(64) float in[5][W];  // x, y, z, log-scale, logit-opacity
    int64_t src[W];              // the input rows
    for (int l = 0; l < W; ++l) {
      const int64_t q = src[l] = rows ? rows[g0 + l] : g0 + l;
      for (int i = 0; i < 3; ++i) in[i][l] = m[3 * q + i];
      in[3][l] = ls[q];
      in[4][l] = lo[q];
    }
    const F x = load(in[0]), y = load(in[1]), z = load(in[2]);
    F c[3];
    for (int i = 0; i < 3; ++i) c[i] = P[4 * i] * x + P[4 * i + 1] * y + P[4 * i + 2] * z + P[4 * i + 3];
    F scale, e_lo;  // the scalar libm's exp per lane (the polynomial's rounding changed TUM's chaotic ATE)
    for (int l = 0; l < W; ++l) scale[l] = std::exp(in[3][l]), e_lo[l] = std::exp(-in[4][l]);
    const F opacity = 1.0f / (1.0f + e_lo);
    // project_one, lane-parallel
    const F cz = c[2];
    const auto front = cz > pk.near;
    const F zs = front ? cz : splat(1.0f);
    const F xz = c[0] / zs, yz = c[1] / zs;
    const F u = pk.fx * xz + pk.cx, v = pk.fy * yz + pk.cy;
    const F tx = vmin(vmax(xz, splat(pk.lx0)), splat(pk.lx1)), ty = vmin(vmax(yz, splat(pk.ly0)), splat(pk.ly1));
    const F iz = 1.0f / zs;
    const F s2 = (scale * iz) * (scale * iz);
    const F a = s2 * pk.fx * pk.fx * (1.0f + tx * tx) + pk.eps2d;
    const F b = s2 * pk.fx * pk.fy * tx * ty;
    const F cc = s2 * pk.fy * pk.fy * (1.0f + ty * ty) + pk.eps2d;
    const F det = vmax(a * cc - b * b, splat(1e-12f));
    const F con0 = cc / det, con1 = -b / det, con2 = a / det;
    const F half = 0.5f * (a - cc);
    const F lam = 0.5f * (a + cc) + vsqrt(half * half + b * b);
    const F ratio = vmax(opacity / pk.alpha_min, splat(1.0f));
    F log_ratio;
    for (int l = 0; l < W; ++l) log_ratio[l] = std::log(ratio[l]);
    const F extent2 = vmin(2.0f * log_ratio, splat(pk.extent2));
    const F r = vsqrt(extent2 * lam);
    const auto visible = front & (opacity >= pk.alpha_min) & (r < std::numeric_limits<float>::infinity());
    const F rad = visible ? r : splat(0.0f);
    for (int l = 0; l < W; ++l) {
      const int64_t g = g0 + l;
      for (int i = 0; i < 3; ++i) pmc[3 * g + i] = c[i][l];
      psc[g] = scale[l];
      pop[g] = opacity[l];
      float* f = pf + d * g;
      for (int i = 0; i < 3; ++i) f[i] = col[3 * src[l] + i];
      for (int64_t j = 0; j < ns; ++j) f[3 + j] = sem[ns * src[l] + j];
      f[d - 1] = cz[l];
      pm2d[2 * g] = u[l];
      pm2d[2 * g + 1] = v[l];
      pcon[3 * g] = con0[l];
      pcon[3 * g + 1] = con1[l];
      pcon[3 * g + 2] = con2[l];
      prad[g] = rad[l];
    }
  }
  const int64_t t0 = blocks * W;  // the tail: the scalar path on the arrays' remaining rows
  if (rows) {  // the inputs stay whole; the rows say where
    prepare_world_all<float>(k, n - t0, ns, m, ls, lo, col, sem, P, pmc + 3 * t0, psc + t0, pop + t0, pf + d * t0,
                             pm2d + 2 * t0, pcon + 3 * t0, prad + t0, 1, rows + t0);
    return;
  }
  prepare_world_all<float>(k, n - t0, ns, m + 3 * t0, ls + t0, lo + t0, col + 3 * t0, sem + ns * t0, P, pmc + 3 * t0,
                           psc + t0, pop + t0, pf + d * t0, pm2d + 2 * t0, pcon + 3 * t0, prad + t0, 1);
}

// Other precisions: the scalar path.
template <typename T>
void prepare_world(const Camera& k, int64_t n, int64_t ns, const T* m, const T* ls, const T* lo, const T* col,
                   const T* sem, const T* P, T* pmc, T* psc, T* pop, T* pf, T* pm2d, T* pcon, T* prad, int threads,
                   const int64_t* rows) {
  prepare_world_all<T>(k, n, ns, m, ls, lo, col, sem, P, pmc, psc, pop, pf, pm2d, pcon, prad, threads, rows);
}

// Per Gaussian: projection backward and the chain through the transform and the activations.
// Gaussians whose row is all zero (culled, or blended by no pixel with a gradient) get exact zeros
// without the arithmetic. Null parameter outputs (pgm == nullptr: tracking, whose map is fixed)
// are not written; pmc (camera-frame mean gradients, for the pose) only when not null.
template <typename T>
void world_backward_all(const Camera& k, int64_t n, int64_t ns, int64_t stride, const T* P, const T* mc, const T* sc,
                        const T* op, const T* r, T* pgm, T* pls, T* plo, T* pcol, T* psem, T* pmc, int threads) {
  const Proj<T> pk(k);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t g = 0; g < n; ++g) {
    const T* row = r + stride * g;
    bool zero = true;
    for (int64_t c = 0; c < stride; ++c) zero &= row[c] == T(0);
    T gc[3] = {T(0), T(0), T(0)}, gs = T(0);
    if (!zero) project_one_backward(pk, mc + 3 * g, sc[g], row, row + 2, row[stride - 1], gc, &gs);
    if (pgm) {
      for (int j = 0; j < 3; ++j) pgm[3 * g + j] = P[j] * gc[0] + P[4 + j] * gc[1] + P[8 + j] * gc[2];  // R^T g
      pls[g] = gs * sc[g];
      plo[g] = row[5] * op[g] * (T(1) - op[g]);
      for (int j = 0; j < 3; ++j) pcol[3 * g + j] = row[kGeomGrads + j];
      for (int64_t j = 0; j < ns; ++j) psem[ns * g + j] = row[kGeomGrads + 3 + j];
    }
    if (pmc) {
      pmc[3 * g] = gc[0];
      pmc[3 * g + 1] = gc[1];
      pmc[3 * g + 2] = gc[2];
    }
  }
}

// ---------------------------------------------------------------------------------------------
// The map's own parameters in, straight to the projection: w2c applied to the world means,
// exp of the log-scales, sigmoid of the logit opacities, and the feature rows (colour, semantics,
// camera depth) gathered in one pass, so no per-Gaussian tensor op runs in PyTorch per render.
// Same maths as render/api.py's to_camera followed by projection.py's isotropic EWA projection.
// Returns (means_cam [N, 3], scales [N], opacities [N], features [N, 3 + S + 1], means2d [N, 2],
// conics [N, 3], radii [N]); the features' last column is the depth. With ``rows`` ([M] int64, e.g.
// frustum_candidates'), only those Gaussians, in that order: every output has M rows.
std::vector<torch::Tensor> prepare_world_rows(torch::Tensor means, torch::Tensor log_scales,
                                              torch::Tensor logit_opacities, torch::Tensor colors,
                                              torch::Tensor semantics, torch::Tensor w2c, double fx, double fy,
                                              double cx, double cy, int64_t width, int64_t height, double near,
                                              double eps2d, double alpha_min, double extent_sigma, int64_t threads,
                                              c10::optional<torch::Tensor> rows) {
  means = means.contiguous();
  log_scales = log_scales.contiguous();
  logit_opacities = logit_opacities.contiguous();
  colors = colors.contiguous();
  semantics = semantics.contiguous();
  w2c = w2c.contiguous();
  const int64_t total = means.size(0), ns = semantics.size(1), d = 3 + ns + 1;
  TORCH_CHECK(log_scales.numel() == total && logit_opacities.numel() == total && colors.size(0) == total &&
                  colors.size(1) == 3 && semantics.size(0) == total && w2c.numel() == 16,
              "prepare_world_rows: inconsistent shapes");
  torch::Tensor picked;
  if (rows) {
    picked = rows->contiguous();
    TORCH_CHECK(picked.scalar_type() == torch::kInt64 && picked.dim() == 1, "prepare_world_rows: rows must be [M] int64");
    if (picked.numel()) {  // one pass for both bounds
      const auto [lo, hi] = torch::aminmax(picked);
      TORCH_CHECK(lo.item<int64_t>() >= 0 && hi.item<int64_t>() < total, "prepare_world_rows: rows must index the ",
                  total, " Gaussians");
    }
  }
  const int64_t n = rows ? picked.size(0) : total;
  const int64_t* pr = rows ? picked.data_ptr<int64_t>() : nullptr;
  const Camera k{fx, fy, cx, cy, width, height, near, eps2d, alpha_min, extent_sigma};
  auto opts = means.options();
  auto mc = torch::empty({n, 3}, opts), sc = torch::empty({n}, opts), op = torch::empty({n}, opts);
  auto feats = torch::empty({n, d}, opts);
  auto m2d = torch::empty({n, 2}, opts), con = torch::empty({n, 3}, opts), rad = torch::empty({n}, opts);
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "prepare_world_rows", [&] {
    using T = scalar_t;
    const T* m = means.data_ptr<T>();
    const T* ls = log_scales.data_ptr<T>();
    const T* lo = logit_opacities.data_ptr<T>();
    const T* col = colors.data_ptr<T>();
    const T* sem = semantics.data_ptr<T>();
    const T* P = w2c.data_ptr<T>();
    T *pmc = mc.data_ptr<T>(), *psc = sc.data_ptr<T>(), *pop = op.data_ptr<T>(), *pf = feats.data_ptr<T>();
    T *pm2d = m2d.data_ptr<T>(), *pcon = con.data_ptr<T>(), *prad = rad.data_ptr<T>();
    prepare_world(k, n, ns, m, ls, lo, col, sem, P, pmc, psc, pop, pf, pm2d, pcon, prad, static_cast<int>(threads), pr);
  });
  return {mc, sc, op, feats, m2d, con, rad};
}

std::vector<torch::Tensor> prepare_world_isotropic(torch::Tensor means, torch::Tensor log_scales,
                                                   torch::Tensor logit_opacities, torch::Tensor colors,
                                                   torch::Tensor semantics, torch::Tensor w2c, double fx, double fy,
                                                   double cx, double cy, int64_t width, int64_t height, double near,
                                                   double eps2d, double alpha_min, double extent_sigma,
                                                   int64_t threads) {
  return prepare_world_rows(means, log_scales, logit_opacities, colors, semantics, w2c, fx, fy, cx, cy, width, height,
                            near, eps2d, alpha_min, extent_sigma, threads, c10::nullopt);
}

// Gradients of the map's parameters from the compositor's per-Gaussian rows [N, 6 + D] (u, v, A,
// B, C, opacity, colour, semantics, depth): (d means [N, 3], d log_scales [N], d logit_opacities [N],
// d colors [N, 3], d semantics [N, S] (those five empty unless need_params), d w2c [4, 4] (zeros unless
// need_pose)). The pose gradient is summed over the Gaussians in index order (deterministic for any
// thread count).
std::vector<torch::Tensor> world_isotropic_backward(torch::Tensor means, torch::Tensor w2c, torch::Tensor means_cam,
                                                    torch::Tensor scales, torch::Tensor opacities, torch::Tensor rows,
                                                    int64_t num_semantic, bool need_params, bool need_pose, double fx,
                                                    double fy,
                                                    double cx, double cy, int64_t width, int64_t height, double near,
                                                    double eps2d, int64_t threads) {
  means = means.contiguous();
  w2c = w2c.contiguous();
  rows = rows.contiguous();
  const int64_t n = means.size(0), ns = num_semantic, stride = rows.size(1), d = stride - kGeomGrads;
  TORCH_CHECK(d == 3 + ns + 1 && rows.size(0) == n, "world_isotropic_backward: rows must be [N, 6 + 3 + S + 1]");
  const Camera k{fx, fy, cx, cy, width, height, near, eps2d, 0.0, 0.0};
  auto opts = means.options();
  const int64_t np = need_params ? n : 0;  // no parameter gradients: empty outputs
  auto g_m = torch::empty({np, 3}, opts), g_ls = torch::empty({np}, opts), g_lo = torch::empty({np}, opts);
  auto g_col = torch::empty({np, 3}, opts), g_sem = torch::empty({np, ns}, opts);
  auto g_w2c = torch::zeros({4, 4}, opts);
  auto g_mc = torch::empty({need_pose ? n : 0, 3}, opts);
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "world_isotropic_backward", [&] {
    using T = scalar_t;
    const T* P = w2c.data_ptr<T>();
    const T* mc = means_cam.data_ptr<T>();
    const T* sc = scales.data_ptr<T>();
    const T* op = opacities.data_ptr<T>();
    const T* r = rows.data_ptr<T>();
    T* pgm = need_params ? g_m.data_ptr<T>() : nullptr;
    T* pls = need_params ? g_ls.data_ptr<T>() : nullptr;
    T* plo = need_params ? g_lo.data_ptr<T>() : nullptr;
    T* pcol = need_params ? g_col.data_ptr<T>() : nullptr;
    T* psem = need_params ? g_sem.data_ptr<T>() : nullptr;
    T* pmc = need_pose ? g_mc.data_ptr<T>() : nullptr;
    world_backward_all<T>(k, n, ns, stride, P, mc, sc, op, r, pgm, pls, plo, pcol, psem, pmc, static_cast<int>(threads));
    if (need_pose) {  // d R_ij = sum_g d mc_i m_j, d t_i = sum_g d mc_i
      const T* m = means.data_ptr<T>();
      double acc[12] = {0};
      for (int64_t g = 0; g < n; ++g) {
        if (pmc[3 * g] == T(0) && pmc[3 * g + 1] == T(0) && pmc[3 * g + 2] == T(0)) continue;  // adds exact zeros
        for (int i = 0; i < 3; ++i) {
          const double gi = pmc[3 * g + i];
          acc[4 * i] += gi * m[3 * g];
          acc[4 * i + 1] += gi * m[3 * g + 1];
          acc[4 * i + 2] += gi * m[3 * g + 2];
          acc[4 * i + 3] += gi;
        }
      }
      T* pw = g_w2c.data_ptr<T>();
      for (int i = 0; i < 12; ++i) pw[i] = static_cast<T>(acc[i]);
    }
  });
  return {g_m, g_ls, g_lo, g_col, g_sem, g_w2c};
}

// Whether a Gaussian with camera-frame centre (x, y, z) and log-scale ls can touch the image: false
// only when it lies at or behind the near plane, or its projected centre lies farther outside the
// image than a bound on its footprint's radius. The bound: project_one's radius is at most
// extent_sigma * sqrt(lam) with lam <= (s / z)^2 * k2 + 2 eps2d (k2 from the clamped tangents), and the
// scale s = exp(ls) at most 2^(floor(ls / ln 2) + 1), built from the float's bits (no libm); 1 % and
// 1 px of slack cover the rounding of u and v here against prepare's. NaNs stay in. Branch-free, so
// the compiler vectorises the loop over Gaussians.
inline bool may_touch(float x, float y, float z, float ls, const Proj<float>& pk, float k2, float last_u,
                      float last_v) {
  float e = std::floor(ls * 1.44269504f) + 1.0f;  // log2(e) * ls, rounded up; NaN -> 2^127
  e = e < 127.0f ? e : 127.0f;
  e = e > -126.0f ? e : -126.0f;
  const int32_t bits = (static_cast<int32_t>(e) + 127) << 23;
  float s_up;
  std::memcpy(&s_up, &bits, sizeof(s_up));
  const float iz = 1.0f / z, rs = s_up * iz;
  const float r = 1.01f * std::sqrt(pk.extent2 * (rs * rs * k2 + 2.0f * pk.eps2d)) + 1.0f;
  const float u = pk.fx * (x * iz) + pk.cx, v = pk.fy * (y * iz) + pk.cy;
  const bool outside = (u + r < 0.0f) | (u - r > last_u) | (v + r < 0.0f) | (v - r > last_v);
  return !(z <= pk.near) & !outside;
}

// Ids (ascending, int64) of the map's Gaussians that may touch the image: every Gaussian whose
// footprint a render would composite is among them (``may_touch``), so rendering only these gives
// the same images and, scattered back, the same gradients. Float maps only.
torch::Tensor frustum_candidates(torch::Tensor means, torch::Tensor log_scales, torch::Tensor w2c, double fx,
                                 double fy, double cx, double cy, int64_t width, int64_t height, double near,
                                 double eps2d, double extent_sigma, int64_t threads) {
  TORCH_CHECK(means.device().is_cpu() && means.scalar_type() == torch::kFloat32, "frustum_candidates: float CPU means");
  means = means.contiguous();
  log_scales = log_scales.contiguous().to(torch::kFloat32);
  const auto pose = w2c.contiguous().to(torch::kFloat32);
  const int64_t n = means.size(0);
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3 && log_scales.numel() == n && pose.numel() == 16,
              "frustum_candidates: means must be [N, 3], log_scales [N], w2c [4, 4]");
  const Camera k{fx, fy, cx, cy, width, height, near, eps2d, 0.0, extent_sigma};
  const Proj<float> pk(k);
  const float tx = std::max(std::abs(pk.lx0), std::abs(pk.lx1)), ty = std::max(std::abs(pk.ly0), std::abs(pk.ly1));
  const float k2 = pk.fx * pk.fx * (1.0f + tx * tx) + pk.fy * pk.fy * (1.0f + ty * ty) + pk.fx * pk.fy * tx * ty;
  const float last_u = static_cast<float>(width - 1), last_v = static_cast<float>(height - 1);
  const float* __restrict m = means.data_ptr<float>();
  const float* __restrict ls = log_scales.data_ptr<float>();
  float P[12];
  std::memcpy(P, pose.data_ptr<float>(), sizeof(P));
  auto ids = torch::empty({n}, torch::kInt64);
  int64_t* out = ids.data_ptr<int64_t>();
  // Each of `threads` equal id ranges writes its kept ids from its own start, a chunk of flags at a
  // time, then the ranges are moved together in order: the same list for any number of threads.
  constexpr int64_t kChunk = 512;
  const int parts = static_cast<int>(std::max<int64_t>(threads, 1));
  std::vector<int64_t> kept(static_cast<size_t>(parts), 0);
  auto first = [&](int64_t p) { return n * p / parts; };
#pragma omp parallel for num_threads(parts) schedule(static, 1)
  for (int64_t p = 0; p < parts; ++p) {
    int64_t at = first(p);
    uint8_t flag[kChunk];
    for (int64_t g0 = first(p); g0 < first(p + 1); g0 += kChunk) {
      const int64_t len = std::min(kChunk, first(p + 1) - g0);
      for (int64_t i = 0; i < len; ++i) {
        const int64_t g = g0 + i;
        const float x = m[3 * g], y = m[3 * g + 1], z = m[3 * g + 2];
        const float cx_ = P[0] * x + P[1] * y + P[2] * z + P[3];
        const float cy_ = P[4] * x + P[5] * y + P[6] * z + P[7];
        const float cz_ = P[8] * x + P[9] * y + P[10] * z + P[11];
        flag[i] = may_touch(cx_, cy_, cz_, ls[g], pk, k2, last_u, last_v);
      }
      for (int64_t i = 0; i < len; ++i) {
        out[at] = g0 + i;
        at += flag[i];
      }
    }
    kept[p] = at - first(p);
  }
  int64_t total = kept[0];
  for (int p = 1; p < parts; ++p) {
    std::memmove(out + total, out + first(p), static_cast<size_t>(kept[p]) * sizeof(int64_t));
    total += kept[p];
  }
  return ids.narrow(0, 0, total);
}

// The GIL is released while the kernels run, so tracking, mapping and rendering threads overlap.
PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  using release = py::call_guard<py::gil_scoped_release>;
  m.def("prepare_world_isotropic", &prepare_world_isotropic, release(),
        "camera transform, activations, feature rows and projection of the map's isotropic Gaussians");
  m.def("world_isotropic_backward", &world_isotropic_backward, release(),
        "gradients of the map's parameters (and the pose) from the compositor's rows");
  m.def("prepare_world_rows", &prepare_world_rows, release(), "prepare_world_isotropic of the given rows only");
  m.def("frustum_candidates", &frustum_candidates, release(), "ids of the Gaussians that may touch the image");
  m.def("max_tile", &max_tile, "largest tile side the compositor takes in float (false) or double (true)");
  m.def("bin_gaussians", &bin_gaussians, release(), "tile lists sorted by depth");
  m.def("composite_forward", &composite_forward, release(), "front-to-back compositing");
  m.def("composite_backward", &composite_backward, release(), "gradients of composite_forward per Gaussian");
}
