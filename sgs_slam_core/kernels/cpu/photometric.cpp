// The SLAM's image losses on the CPU, each value and gradient in one call: the photometric term of the
// mapping loss (below), the whole mapping loss (mapping_loss) and tracking's masked L1 sums (tracking_l1).
//
//   L = (1 - w) mean|x - y| + w (1 - mean SSIM(x, y))
//
// Same maths as sgs_slam_core/slam/photometric.py (metrics/image.py `ssim` with
// padding="same"): x, y are [H, W, C] images (channels last), SSIM uses a normalised Gaussian window
// of `size` taps, zero padding ("same" output), C1 = 0.01^2, C2 = 0.03^2:
//   mu = blur(x), E_xx = blur(x^2), E_xy = blur(x y), ...
//   A1 = 2 mu_x mu_y + C1, A2 = 2 (E_xy - mu_x mu_y) + C2, B1 = mu_x^2 + mu_y^2 + C1,
//   B2 = (E_xx - mu_x^2) + (E_yy - mu_y^2) + C2, S = A1 A2 / (B1 B2)
// y is a constant target. The loss is a scalar, so its gradient with respect to x is computed here
// (when asked) and the autograd backward only scales it:
//   dS/dmu_x = 2 mu_y (A2 - A1) / (B1 B2) - 2 mu_x S (1/B1 - 1/B2),  dS/dE_xx = -S / B2,
//   dS/dE_xy = 2 A1 / (B1 B2)
//   dL/dx = -(w/n) [blur(dS/dmu_x) + 2 x blur(dS/dE_xx) + y blur(dS/dE_xy)] + ((1 - w)/n) sign(x - y)
// (a zero-padded "same" blur with a symmetric window is its own transpose).
//
// The blur is separable: per output row, a vertical pass sums the window's rows into zero-padded
// row buffers, then a horizontal pass reads them at offsets of C, both in 64-byte vectors whose sums
// stay in registers over the taps (faster than a per-tap read-modify-write, same results). OpenMP
// over rows; per-row partial sums are added in row order, so the result does not depend on the
// thread count.

#include <torch/extension.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

namespace {

constexpr double kC1 = 0.01 * 0.01;
constexpr double kC2 = 0.03 * 0.03;

template <typename T>
std::vector<T> gaussian_taps(int size, double sigma) {
  std::vector<double> g(size);
  double sum = 0.0;
  for (int i = 0; i < size; ++i) {
    const double x = i - (size - 1) / 2.0;
    g[i] = std::exp(-(x * x) / (2.0 * sigma * sigma));
    sum += g[i];
  }
  std::vector<T> taps(size);
  for (int i = 0; i < size; ++i) taps[i] = static_cast<T>(g[i] / sum);
  return taps;
}

// Both blurs run in chunks of one 64-byte vector (16 floats or 8 doubles, GCC vector extensions)
// whose accumulators stay in registers over all taps: one load per tap and input and one store per
// output, instead of a read-modify-write of each output per tap. Same sums in the same order.
template <typename T>
struct Vec;
template <>
struct Vec<float> {
  typedef float V __attribute__((vector_size(64)));
};
template <>
struct Vec<double> {
  typedef double V __attribute__((vector_size(64)));
};
template <typename T>
using V = typename Vec<T>::V;
template <typename T>
constexpr int64_t kLanes = 64 / sizeof(T);
template <typename T>
inline V<T> vload(const T* p) {
  V<T> v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}
template <typename T>
inline void vstore(T* p, V<T> v) {
  std::memcpy(p, &v, sizeof(v));
}

// out[k][j] = sum_t taps[t] * pad[k][j + t*C] for the K row buffers (zero-padded by half*C each side).
template <typename T, int K>
inline void horizontal(T* const* pad, T* const* out, const std::vector<T>& taps, int64_t len, int64_t c) {
  const int64_t nt = static_cast<int64_t>(taps.size()), L = kLanes<T>;
  int64_t j0 = 0;
  for (; j0 + L <= len; j0 += L)
    for (int k = 0; k < K; ++k) {
      V<T> acc = {};
      for (int64_t t = 0; t < nt; ++t) acc += taps[t] * vload(pad[k] + j0 + t * c);
      vstore(out[k] + j0, acc);
    }
  for (int k = 0; k < K; ++k)
    for (int64_t j = j0; j < len; ++j) {
      T acc = 0;
      for (int64_t t = 0; t < nt; ++t) acc += taps[t] * pad[k][j + t * c];
      out[k][j] = acc;
    }
}

template <typename T>
struct Images {
  const T* x;
  const T* y;
  int64_t h, w, c;
  int64_t row() const { return w * c; }
};

// Pass 1: SSIM per value, the partial sums of S and |x - y| per row, and (with grad) the three
// derivative maps dS/dmu_x, dS/dE_xx, dS/dE_xy.
template <typename T>
void ssim_pass(const Images<T>& im, const std::vector<T>& taps, bool grad, std::vector<double>& row_s,
               std::vector<double>& row_l1, T* d_mu, T* d_xx, T* d_xy, int threads) {
  const int64_t len = im.row(), half = static_cast<int64_t>(taps.size() / 2), off = half * im.c;
  const int64_t padded = len + 2 * off;
#pragma omp parallel num_threads(threads)
  {
    std::vector<T> buf(5 * padded + 5 * len);  // zeros: the padding is never written, only [off, off + len)
    T* pad[5];
    T* mom[5];
    for (int k = 0; k < 5; ++k) {
      pad[k] = buf.data() + k * padded;
      mom[k] = buf.data() + 5 * padded + k * len;
    }
#pragma omp for schedule(static)
    for (int64_t h = 0; h < im.h; ++h) {
      const int64_t r0 = std::max<int64_t>(h - half, 0), r1 = std::min<int64_t>(h + half, im.h - 1);
      const int64_t L = kLanes<T>;
      int64_t j0 = 0;
      for (; j0 + L <= len; j0 += L) {
        V<T> s0 = {}, s1 = {}, s2 = {}, s3 = {}, s4 = {};
        for (int64_t r = r0; r <= r1; ++r) {
          const T g = taps[r - h + half];
          const V<T> a = vload(im.x + r * len + j0), b = vload(im.y + r * len + j0);
          s0 += g * a;
          s1 += g * b;
          s2 += g * a * a;
          s3 += g * b * b;
          s4 += g * a * b;
        }
        vstore(pad[0] + off + j0, s0);
        vstore(pad[1] + off + j0, s1);
        vstore(pad[2] + off + j0, s2);
        vstore(pad[3] + off + j0, s3);
        vstore(pad[4] + off + j0, s4);
      }
      for (int64_t j = j0; j < len; ++j) {
        T s0 = 0, s1 = 0, s2 = 0, s3 = 0, s4 = 0;
        for (int64_t r = r0; r <= r1; ++r) {
          const T g = taps[r - h + half], a = im.x[r * len + j], b = im.y[r * len + j];
          s0 += g * a;
          s1 += g * b;
          s2 += g * a * a;
          s3 += g * b * b;
          s4 += g * a * b;
        }
        pad[0][off + j] = s0, pad[1][off + j] = s1, pad[2][off + j] = s2, pad[3][off + j] = s3, pad[4][off + j] = s4;
      }
      horizontal<T, 5>(pad, mom, taps, len, im.c);
      const T* __restrict xr = im.x + h * len;
      const T* __restrict yr = im.y + h * len;
      const T* __restrict m0 = mom[0];
      const T* __restrict m1 = mom[1];
      const T* __restrict m2 = mom[2];
      const T* __restrict m3 = mom[3];
      const T* __restrict m4 = mom[4];
      // The vertical sums are consumed: their buffers take S and, without grad, the unused derivatives.
      T* __restrict srow = pad[0] + off;  // (the data parts, so the zero padding stays zero)
      T* __restrict dm = grad ? d_mu + h * len : pad[1] + off;
      T* __restrict dxx = grad ? d_xx + h * len : pad[2] + off;
      T* __restrict dxy = grad ? d_xy + h * len : pad[3] + off;
      // No reduction and no branch inside: the compiler vectorises the whole formula.
#pragma omp simd
      for (int64_t j = 0; j < len; ++j) {
        const T mx = m0[j], my = m1[j];
        const T a1 = 2 * mx * my + T(kC1);
        const T a2 = 2 * (m4[j] - mx * my) + T(kC2);
        const T b1 = mx * mx + my * my + T(kC1);
        const T b2 = (m2[j] - mx * mx) + (m3[j] - my * my) + T(kC2);
        const T inv1 = T(1) / b1, inv2 = T(1) / b2;
        const T inv = inv1 * inv2;
        const T s = a1 * a2 * inv;
        srow[j] = s;
        dm[j] = 2 * my * (a2 - a1) * inv - 2 * mx * s * (inv1 - inv2);
        dxx[j] = -s * inv2;
        dxy[j] = 2 * a1 * inv;
      }
      double sum_s = 0.0, sum_l1 = 0.0;
      for (int64_t j = 0; j < len; ++j) {
        sum_s += srow[j];
        sum_l1 += std::abs(xr[j] - yr[j]);
      }
      row_s[h] = sum_s;
      row_l1[h] = sum_l1;
    }
  }
}

// Pass 2: blur the derivative maps and assemble dL/dx.
template <typename T>
void gradient_pass(const Images<T>& im, const std::vector<T>& taps, const T* d_mu, const T* d_xx, const T* d_xy,
                   T scale_ssim, T scale_l1, T* out, int threads) {
  const int64_t len = im.row(), half = static_cast<int64_t>(taps.size() / 2), off = half * im.c;
  const int64_t padded = len + 2 * off;
  const T* maps[3] = {d_mu, d_xx, d_xy};
#pragma omp parallel num_threads(threads)
  {
    std::vector<T> buf(3 * padded + 3 * len);  // zeros: the padding is never written, only [off, off + len)
    T* pad[3];
    T* blurred[3];
    for (int k = 0; k < 3; ++k) {
      pad[k] = buf.data() + k * padded;
      blurred[k] = buf.data() + 3 * padded + k * len;
    }
#pragma omp for schedule(static)
    for (int64_t h = 0; h < im.h; ++h) {
      const int64_t r0 = std::max<int64_t>(h - half, 0), r1 = std::min<int64_t>(h + half, im.h - 1);
      const int64_t L = kLanes<T>;
      int64_t j0 = 0;
      for (; j0 + L <= len; j0 += L) {
        V<T> s0 = {}, s1 = {}, s2 = {};
        for (int64_t r = r0; r <= r1; ++r) {
          const T g = taps[r - h + half];
          s0 += g * vload(maps[0] + r * len + j0);
          s1 += g * vload(maps[1] + r * len + j0);
          s2 += g * vload(maps[2] + r * len + j0);
        }
        vstore(pad[0] + off + j0, s0);
        vstore(pad[1] + off + j0, s1);
        vstore(pad[2] + off + j0, s2);
      }
      for (int64_t j = j0; j < len; ++j)
        for (int k = 0; k < 3; ++k) {
          T acc = 0;
          for (int64_t r = r0; r <= r1; ++r) acc += taps[r - h + half] * maps[k][r * len + j];
          pad[k][off + j] = acc;
        }
      horizontal<T, 3>(pad, blurred, taps, len, im.c);
      const T* __restrict xr = im.x + h * len;
      const T* __restrict yr = im.y + h * len;
      T* __restrict o = out + h * len;
      const T* __restrict e0 = blurred[0];
      const T* __restrict e1 = blurred[1];
      const T* __restrict e2 = blurred[2];
#pragma omp simd
      for (int64_t j = 0; j < len; ++j) {
        const T diff = xr[j] - yr[j];
        const T sign = static_cast<T>((diff > 0) - (diff < 0));
        o[j] = scale_ssim * (e0[j] + 2 * xr[j] * e1[j] + yr[j] * e2[j]) + scale_l1 * sign;
      }
    }
  }
}

template <typename T>
struct L1Inputs {
  const T *color, *semantic, *depth, *silhouette, *rgb, *sem_target, *depth_target;
  const bool* valid;
  int64_t h, w, ns;
};

struct L1Sums {
  double depth = 0, color = 0, semantic = 0;
  int64_t pixels = 0;
};

template <typename T>
L1Sums tracking_l1_sums(const L1Inputs<T>& in, T thr, T wd, T wc, T ws, T* gc, T* gs, T* gd, int threads) {
  auto sign = [](T x) { return static_cast<T>((x > 0) - (x < 0)); };
  std::vector<L1Sums> rows(static_cast<size_t>(in.h));
  const int64_t ns = in.ns;
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t y = 0; y < in.h; ++y) {
    L1Sums r;
    for (int64_t x = 0; x < in.w; ++x) {
      const int64_t i = y * in.w + x;
      const bool inside = in.valid[i] && in.silhouette[i] > thr && std::isfinite(in.depth[i]);
      r.pixels += inside;
      const T dd = inside ? in.depth[i] - in.depth_target[i] : T(0);
      r.depth += std::abs(dd);
      gd[i] = wd * sign(dd);
      for (int64_t k = 0; k < 3; ++k) {
        const T e = inside ? in.color[3 * i + k] - in.rgb[3 * i + k] : T(0);
        r.color += std::abs(e);
        gc[3 * i + k] = wc * sign(e);
      }
      for (int64_t k = 0; k < ns; ++k) {
        const T e = inside ? in.semantic[ns * i + k] - in.sem_target[ns * i + k] : T(0);
        r.semantic += std::abs(e);
        gs[ns * i + k] = ws * sign(e);
      }
    }
    rows[y] = r;
  }
  L1Sums total;
  for (const L1Sums& r : rows) {
    total.depth += r.depth, total.color += r.color, total.semantic += r.semantic;
    total.pixels += r.pixels;
  }
  return total;
}

// (1 - w) mean|x - y| + w (1 - mean SSIM) of im, and (grad != nullptr) its gradient times grad_scale
// written to grad [H, W, C]. `options` makes the derivative maps' scratch tensor.
template <typename T>
double photometric_value(const Images<T>& im, double ssim_weight, int64_t window, double sigma, T* grad,
                         double grad_scale, const torch::TensorOptions& options, int threads) {
  const int64_t h = im.h, w = im.w, c = im.c, n = h * w * c;
  if (n == 0) return 0.0;
  const auto taps = gaussian_taps<T>(static_cast<int>(window), sigma);
  std::vector<double> row_s(h, 0.0), row_l1(h, 0.0);
  const bool ssim = ssim_weight > 0, need_grad = grad != nullptr;
  torch::Tensor maps = (ssim && need_grad) ? torch::empty({3, h, w, c}, options) : torch::Tensor();
  T* d = maps.defined() ? maps.data_ptr<T>() : nullptr;
  if (ssim) {
    ssim_pass<T>(im, taps, need_grad, row_s, row_l1, d, d ? d + n : nullptr, d ? d + 2 * n : nullptr, threads);
  } else {
    for (int64_t r = 0; r < h; ++r) {
      double acc = 0.0;
      for (int64_t j = 0; j < w * c; ++j) acc += std::abs(im.x[r * w * c + j] - im.y[r * w * c + j]);
      row_l1[r] = acc;
    }
  }
  double sum_s = 0.0, sum_l1 = 0.0;
  for (int64_t r = 0; r < h; ++r) {
    sum_s += row_s[r];
    sum_l1 += row_l1[r];
  }
  if (need_grad) {
    const T scale_l1 = static_cast<T>((1.0 - ssim_weight) / n);
    if (ssim) {
      gradient_pass<T>(im, taps, d, d + n, d + 2 * n, static_cast<T>(-ssim_weight / n), scale_l1, grad, threads);
    } else {
      for (int64_t j = 0; j < n; ++j) {
        const T diff = im.x[j] - im.y[j];
        grad[j] = scale_l1 * static_cast<T>((diff > 0) - (diff < 0));
      }
    }
    if (grad_scale != 1.0) {  // after the pass, as a separate product (the rounding of the two-step form)
      const T g = static_cast<T>(grad_scale);
      for (int64_t j = 0; j < n; ++j) grad[j] *= g;
    }
  }
  return (1.0 - ssim_weight) * (sum_l1 / n) + (ssim ? ssim_weight * (1.0 - sum_s / n) : 0.0);
}

// Mapping's depth term: sum|D - D_gt| and the pixel count over valid & isfinite(D) (sums in double per
// row, then in row order), and the gradient sign(D - D_gt) * grad_scale / max(count, 1) there, 0 elsewhere.
template <typename T>
std::pair<double, int64_t> depth_l1(const T* depth, const T* target, const bool* valid, int64_t h, int64_t w,
                                    double grad_scale, T* grad, int threads) {
  std::vector<double> row_sum(h, 0.0);
  std::vector<int64_t> row_count(h, 0);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t y = 0; y < h; ++y) {
    double acc = 0.0;
    int64_t count = 0;
    for (int64_t i = y * w; i < (y + 1) * w; ++i) {
      const bool ok = valid[i] && std::isfinite(depth[i]);
      const T diff = ok ? depth[i] - target[i] : T(0);
      acc += std::abs(diff);
      count += ok;
      grad[i] = static_cast<T>((diff > 0) - (diff < 0));  // scaled below, once the count is known
    }
    row_sum[y] = acc;
    row_count[y] = count;
  }
  double sum = 0.0;
  int64_t count = 0;
  for (int64_t y = 0; y < h; ++y) sum += row_sum[y], count += row_count[y];
  // (1 / count) * scale in the working precision: the rounding of the tensor form it replaced
  const T scale = T(1) / static_cast<T>(std::max<int64_t>(count, 1)) * static_cast<T>(grad_scale);
  for (int64_t i = 0; i < h * w; ++i) grad[i] *= scale;
  return {sum, count};
}

}  // namespace

// (loss [], gradient [H, W, C] or an empty tensor) of (1 - w) mean|x - y| + w (1 - mean SSIM).
std::vector<torch::Tensor> photometric_loss(torch::Tensor pred, torch::Tensor target, double ssim_weight,
                                            int64_t window, double sigma, bool need_grad, int64_t threads) {
  TORCH_CHECK(pred.dim() == 3 && pred.sizes() == target.sizes(), "pred and target must both be [H, W, C]");
  TORCH_CHECK(pred.scalar_type() == target.scalar_type(), "pred and target must share a dtype");
  TORCH_CHECK(window >= 1 && window % 2 == 1 && window <= 63, "window must be odd, 1..63");
  pred = pred.contiguous();
  target = target.contiguous();
  auto loss = torch::zeros({}, pred.options());
  torch::Tensor grad = need_grad ? torch::empty_like(pred) : torch::empty({0}, pred.options());
  AT_DISPATCH_FLOATING_TYPES(pred.scalar_type(), "photometric_loss", [&] {
    using T = scalar_t;
    const Images<T> im{pred.data_ptr<T>(), target.data_ptr<T>(), pred.size(0), pred.size(1), pred.size(2)};
    loss.fill_(photometric_value<T>(im, ssim_weight, window, sigma, need_grad ? grad.data_ptr<T>() : nullptr, 1.0,
                                    pred.options(), static_cast<int>(threads)));
  });
  return {loss, grad};
}

// The whole mapping loss of slam/losses.py's mapping_loss_reference, times `scale`, and its gradients:
//   scale (w_d mean|D - D_gt| over valid & isfinite(D) + w_c photometric(C) + w_s photometric(S)).
// S = 0 channels leaves the semantic term out; need_grad = false skips the colour and semantic
// gradients (empty tensors). Returns (loss [], d colour [H, W, 3], d semantics [H, W, S], d depth [H, W]).
std::vector<torch::Tensor> mapping_loss(torch::Tensor color, torch::Tensor semantic, torch::Tensor depth,
                                        torch::Tensor valid, torch::Tensor rgb, torch::Tensor sem_target,
                                        torch::Tensor depth_target, double w_depth, double w_color, double w_semantic,
                                        double ssim_weight, double scale, bool need_grad, int64_t window,
                                        double sigma, int64_t threads) {
  const int64_t h = depth.size(0), w = depth.size(1), ns = semantic.size(2);
  TORCH_CHECK(depth.dim() == 2 && color.dim() == 3 && color.sizes() == rgb.sizes() && color.size(0) == h &&
                  color.size(1) == w && color.size(2) == 3 && semantic.sizes() == sem_target.sizes() &&
                  semantic.size(0) == h && semantic.size(1) == w && depth_target.sizes() == depth.sizes() &&
                  valid.sizes() == depth.sizes() && valid.scalar_type() == torch::kBool,
              "mapping_loss: inconsistent shapes");
  TORCH_CHECK(window >= 1 && window % 2 == 1 && window <= 63, "window must be odd, 1..63");
  for (auto* t : {&color, &semantic, &depth, &rgb, &sem_target, &depth_target, &valid}) *t = t->contiguous();
  auto empty = torch::empty({0}, color.options());
  auto g_color = need_grad ? torch::empty_like(color) : empty;
  auto g_sem = need_grad && ns > 0 ? torch::empty_like(semantic) : empty;
  auto g_depth = torch::empty_like(depth);
  auto loss = torch::empty({}, depth.options());
  AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "mapping_loss", [&] {
    using T = scalar_t;
    const int th = static_cast<int>(threads);
    const auto [sum, count] = depth_l1<T>(depth.data_ptr<T>(), depth_target.data_ptr<T>(), valid.data_ptr<bool>(), h, w,
                                          scale * w_depth, g_depth.data_ptr<T>(), th);
    double total = w_depth * sum / static_cast<double>(std::max<int64_t>(count, 1));
    const Images<T> im_c{color.data_ptr<T>(), rgb.data_ptr<T>(), h, w, 3};
    total += w_color * photometric_value<T>(im_c, ssim_weight, window, sigma,
                                            need_grad ? g_color.data_ptr<T>() : nullptr, scale * w_color,
                                            color.options(), th);
    if (ns > 0) {
      const Images<T> im_s{semantic.data_ptr<T>(), sem_target.data_ptr<T>(), h, w, ns};
      total += w_semantic * photometric_value<T>(im_s, ssim_weight, window, sigma,
                                                 need_grad ? g_sem.data_ptr<T>() : nullptr, scale * w_semantic,
                                                 semantic.options(), th);
    }
    loss.fill_(scale * total);
  });
  return {loss, g_color, g_sem, g_depth};
}

// Tracking's masked L1 sums and their gradients (slam/losses.py's tracking_loss_reference):
//   mask = valid & (silhouette > threshold) & isfinite(depth)
//   total = w_d sum|D - D_gt| + w_c sum|C - C_gt| + w_s sum|S - S_gt| over the mask,
// gradients w sign(x - y) inside the mask, 0 outside. Sums in double per row, then in row order (the
// same for any thread count). Returns (total [], pixels [] int64, sum|D - D_gt| [], d colour [H, W, 3],
// d semantics [H, W, S], d depth [H, W]); S = 0 leaves the semantic term out.
std::vector<torch::Tensor> tracking_l1(torch::Tensor color, torch::Tensor semantic, torch::Tensor depth,
                                       torch::Tensor silhouette, torch::Tensor rgb, torch::Tensor sem_target,
                                       torch::Tensor depth_target, torch::Tensor valid, double sil_threshold,
                                       double w_depth, double w_color, double w_semantic, int64_t threads) {
  const int64_t h = depth.size(0), w = depth.size(1), ns = semantic.size(2);
  TORCH_CHECK(depth.dim() == 2 && color.sizes() == rgb.sizes() && color.size(0) == h && color.size(1) == w &&
                  color.size(2) == 3 && semantic.sizes() == sem_target.sizes() && semantic.size(0) == h &&
                  semantic.size(1) == w && silhouette.sizes() == depth.sizes() &&
                  depth_target.sizes() == depth.sizes() && valid.sizes() == depth.sizes() &&
                  valid.scalar_type() == torch::kBool,
              "tracking_l1: inconsistent shapes");
  for (auto* t : {&color, &semantic, &depth, &silhouette, &rgb, &sem_target, &depth_target, &valid}) *t = t->contiguous();
  auto g_color = torch::empty_like(color), g_sem = torch::empty_like(semantic), g_depth = torch::empty_like(depth);
  auto total = torch::empty({}, depth.options()), depth_sum = torch::empty({}, depth.options());
  auto pixels = torch::empty({}, depth.options().dtype(torch::kInt64));
  AT_DISPATCH_FLOATING_TYPES(depth.scalar_type(), "tracking_l1", [&] {
    using T = scalar_t;
    const L1Inputs<T> in{color.data_ptr<T>(), semantic.data_ptr<T>(), depth.data_ptr<T>(), silhouette.data_ptr<T>(),
                         rgb.data_ptr<T>(), sem_target.data_ptr<T>(), depth_target.data_ptr<T>(),
                         valid.data_ptr<bool>(), h, w, ns};
    const L1Sums sums = tracking_l1_sums<T>(in, static_cast<T>(sil_threshold), static_cast<T>(w_depth),
                                            static_cast<T>(w_color), static_cast<T>(w_semantic), g_color.data_ptr<T>(),
                                            g_sem.data_ptr<T>(), g_depth.data_ptr<T>(), static_cast<int>(threads));
    total.fill_(w_depth * sums.depth + w_color * sums.color + (ns > 0 ? w_semantic * sums.semantic : 0.0));
    depth_sum.fill_(sums.depth);
    pixels.fill_(sums.pixels);
  });
  return {total, pixels, depth_sum, g_color, g_sem, g_depth};
}

// The GIL is released while the kernels run, so tracking and mapping threads overlap.
PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("photometric_loss", &photometric_loss, py::call_guard<py::gil_scoped_release>(),
        "(1 - w) L1 + w (1 - SSIM) of [H, W, C] images and its gradient");
  m.def("mapping_loss", &mapping_loss, py::call_guard<py::gil_scoped_release>(),
        "the mapping loss (depth L1, colour and semantic L1/SSIM) and its gradients");
  m.def("tracking_l1", &tracking_l1, py::call_guard<py::gil_scoped_release>(),
        "tracking's masked L1 sums and their gradients");
}
