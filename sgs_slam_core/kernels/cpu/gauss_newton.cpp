// One Gauss-Newton step's normal equations of projective point-to-plane ICP with photometric
// channels, in one pass over the source points: the same maths as geometry/icp.py's
// `_gauss_newton_step` (its pure-PyTorch reference, which tests compare against).
//
// For each source point s with depth: p = R s + t in the reference camera, projected to its
// nearest reference pixel; a geometric correspondence when that pixel's vertex v and normal n are
// valid and |p - v| < max_distance. Its residual r = (p - v) . n has the row
//   [n, p x n | r]   (d r / d (rho, phi) for a left perturbation, then r)
// with the Huber weight w = min(1, huber / |r|). With depth-noise weights (one per source point) the
// row and r are first scaled by the point's weight, and the Huber weight and the truncated cost see
// the scaled r. Each of the C channels adds, where the reference
// pixel's channels are valid, r_c = I(nearest) + dI/du du + dI/dv dv - I_src (du, dv: the projection's
// sub-pixel offset) with the row [J, p x J | r_c], J = dI/du fx/z (1, 0, -x/z) + dI/dv fy/z (0, 1, -y/z).
// The matrix is summed in float32 over blocks of rows (as the reference sums every row in float32),
// the blocks' sums and the statistics in double per thread, added in thread order (deterministic
// for a thread count).
//
// Returns 53 doubles: the 7x7 matrix sum(w row^T row) (its [6, 6] block is J^T W J, its last column
// J^T W r), the truncated cost sum(min(r^2, (3 huber)^2)) over geometric correspondences plus the cap
// for every other source point with depth plus the same for usable channel values (0 cap there),
// the number of correspondences, their sum of r^2 (unscaled, m^2), and the number of source points
// with depth.

#include <torch/extension.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

constexpr int kUpper = 28;  // entries i <= j of a symmetric 7x7 matrix
constexpr int kStats = 4;   // truncated cost, correspondences, their sum of r^2, source points with depth

// A block of rows, summed with SIMD once full: a scalar double update per row was most of a step's
// time. The Huber weights are computed per block too, a vector division instead of one per row.
constexpr int kBlock = 128;

struct RowBlock {
  alignas(64) float col[7][kBlock];  // the rows; col[6] is the residual
  int size = 0;

  void push(double* acc, const float* row, float huber) {
    for (int i = 0; i < 7; ++i) col[i][size] = row[i];
    if (++size == kBlock) flush(acc, huber);
  }

  // acc[k] += sum_b w_b col[i][b] col[j][b] for the k-th pair i <= j, w_b = min(1, huber / |r_b|)
  void flush(double* acc, float huber) {
    const int n = size;
    alignas(64) float weight[kBlock];
    alignas(64) float wi[kBlock];
#pragma omp simd
    for (int b = 0; b < n; ++b) weight[b] = std::min(1.0f, huber / std::max(std::fabs(col[6][b]), 1e-12f));
    int k = 0;
    for (int i = 0; i < 7; ++i) {
#pragma omp simd
      for (int b = 0; b < n; ++b) wi[b] = weight[b] * col[i][b];
      for (int j = i; j < 7; ++j) {
        float sum = 0.0f;
#pragma omp simd reduction(+ : sum)
        for (int b = 0; b < n; ++b) sum += wi[b] * col[j][b];
        acc[k++] += sum;
      }
    }
    size = 0;
  }
};

inline void cross_row(float* row, float px, float py, float pz) {
  // row[0..2] = J (d r / d p); row[3..5] = p x J
  row[3] = py * row[2] - pz * row[1];
  row[4] = pz * row[0] - px * row[2];
  row[5] = px * row[1] - py * row[0];
}

}  // namespace

torch::Tensor gauss_newton_terms(torch::Tensor pose, torch::Tensor points, torch::Tensor values,
                                 torch::Tensor weights, torch::Tensor packed, double fx, double fy, double cx,
                                 double cy, int64_t width, int64_t height, double max_distance, double huber,
                                 int64_t threads) {
  TORCH_CHECK(pose.sizes() == torch::IntArrayRef({4, 4}), "pose must be [4, 4]");
  TORCH_CHECK(points.dim() == 2 && points.size(1) == 3 && points.scalar_type() == torch::kFloat32,
              "points must be [N, 3] float32");
  TORCH_CHECK(packed.dim() == 2 && packed.scalar_type() == torch::kFloat32, "packed must be [H * W, P] float32");
  TORCH_CHECK(packed.size(0) == width * height, "packed rows must be width * height");
  const int64_t n = points.size(0);
  const int64_t c = values.numel() ? values.size(1) : 0;
  const int64_t stride = packed.size(1);
  TORCH_CHECK(stride == 7 + (c ? 3 * c + 1 : 0) || (c == 0 && stride >= 7), "packed has the wrong column count");
  TORCH_CHECK(c == 0 || (values.size(0) == n && values.scalar_type() == torch::kFloat32),
              "values must be [N, C] float32");
  const bool weighted = weights.numel() > 0;
  TORCH_CHECK(!weighted || (weights.numel() == n && weights.scalar_type() == torch::kFloat32),
              "weights must be [N] float32 or empty");
  const auto pose_f = pose.to(torch::kFloat32).contiguous();  // the reference transforms in float32
  const float* m = pose_f.data_ptr<float>();
  const float r00 = m[0], r01 = m[1], r02 = m[2], t0 = m[3];
  const float r10 = m[4], r11 = m[5], r12 = m[6], t1 = m[7];
  const float r20 = m[8], r21 = m[9], r22 = m[10], t2 = m[11];
  const auto pts_c = points.contiguous();
  const auto val_c = values.contiguous();
  const auto tab_c = packed.contiguous();
  const float* pts = pts_c.data_ptr<float>();
  const float* val = c ? val_c.data_ptr<float>() : nullptr;
  const float* tab = tab_c.data_ptr<float>();
  const float ffx = static_cast<float>(fx), ffy = static_cast<float>(fy);
  const float cxh = static_cast<float>(cx + 0.5), cyh = static_cast<float>(cy + 0.5);
  const float fcx = static_cast<float>(cx), fcy = static_cast<float>(cy);
  const float max_d2 = static_cast<float>(max_distance * max_distance);
  const float hub = static_cast<float>(huber);
  const double cap = 9.0 * huber * huber;
  const auto wts_c = weights.contiguous();
  const float* wts = weighted ? wts_c.data_ptr<float>() : nullptr;
  const int nthreads = static_cast<int>(std::max<int64_t>(1, threads));
  std::vector<double> partial(static_cast<size_t>(nthreads) * (kUpper + kStats), 0.0);

#pragma omp parallel num_threads(nthreads)
  {
    double* acc = partial.data() + static_cast<size_t>(omp_get_thread_num()) * (kUpper + kStats);
    double* st = acc + kUpper;
    float row[7];
    RowBlock block;
#pragma omp for schedule(static)
    for (int64_t i = 0; i < n; ++i) {
      const float* s = pts + 3 * i;
      if (!(s[2] > 0.0f)) continue;
      st[3] += 1.0;
      const float px = s[0] * r00 + s[1] * r01 + s[2] * r02 + t0;
      const float py = s[0] * r10 + s[1] * r11 + s[2] * r12 + t1;
      const float pz = s[0] * r20 + s[1] * r21 + s[2] * r22 + t2;
      if (!(pz > 1e-6f)) {
        st[0] += cap;
        continue;
      }
      const float uc = px / pz * ffx, vc = py / pz * ffy;
      const float u = std::floor(uc + cxh), v = std::floor(vc + cyh);
      if (!(u >= 0.0f && u <= static_cast<float>(width - 1) && v >= 0.0f && v <= static_cast<float>(height - 1))) {
        st[0] += cap;
        continue;
      }
      const float* t = tab + (static_cast<int64_t>(v) * width + static_cast<int64_t>(u)) * stride;
      const float dx = px - t[0], dy = py - t[1], dz = pz - t[2];
      if (!(t[6] > 0.0f) || !(dx * dx + dy * dy + dz * dz < max_d2)) {
        st[0] += cap;
        continue;
      }
      const float r = dx * t[3] + dy * t[4] + dz * t[5];
      row[0] = t[3], row[1] = t[4], row[2] = t[5], row[6] = r;
      cross_row(row, px, py, pz);
      if (weighted)
        for (float& x : row) x *= wts[i];
      block.push(acc, row, hub);
      const double r2 = static_cast<double>(r) * r;
      st[0] += std::min(static_cast<double>(row[6]) * row[6], cap);
      st[1] += 1.0;
      st[2] += r2;
      if (c == 0 || !(t[7 + 3 * c] > 0.0f)) continue;
      const float du = uc + fcx - u, dv = vc + fcy - v, inv_z = 1.0f / pz;
      for (int64_t k = 0; k < c; ++k) {
        const float gu = t[7 + c + k], gv = t[7 + 2 * c + k];
        const float rc = t[7 + k] + gu * du + gv * dv - val[i * c + k];
        const float ju = gu * (ffx * inv_z), jv = gv * (ffy * inv_z);
        row[0] = ju, row[1] = jv, row[2] = -(ju * px + jv * py) * inv_z, row[6] = rc;
        cross_row(row, px, py, pz);
        block.push(acc, row, hub);
        st[0] += std::min(static_cast<double>(rc) * rc, cap);
      }
    }
    block.flush(acc, hub);
  }
  auto out = torch::zeros({49 + kStats}, torch::kFloat64);
  double* o = out.data_ptr<double>();
  for (int th = 0; th < nthreads; ++th) {
    const double* acc = partial.data() + static_cast<size_t>(th) * (kUpper + kStats);
    int k = 0;
    for (int i = 0; i < 7; ++i)
      for (int j = i; j < 7; ++j, ++k) {
        o[i * 7 + j] += acc[k];
        if (j != i) o[j * 7 + i] += acc[k];
      }
    for (int s = 0; s < kStats; ++s) o[49 + s] += acc[kUpper + s];
  }
  return out;
}

namespace {

// x = A^-1 b for a 6x6 system by Gaussian elimination with partial pivoting (as LU solves it).
void solve6(double a[6][6], double b[6], double x[6]) {
  for (int col = 0; col < 6; ++col) {
    int pivot = col;
    for (int r = col + 1; r < 6; ++r)
      if (std::fabs(a[r][col]) > std::fabs(a[pivot][col])) pivot = r;
    if (pivot != col) {
      for (int k = 0; k < 6; ++k) std::swap(a[col][k], a[pivot][k]);
      std::swap(b[col], b[pivot]);
    }
    for (int r = col + 1; r < 6; ++r) {
      const double f = a[r][col] / a[col][col];
      for (int k = col; k < 6; ++k) a[r][k] -= f * a[col][k];
      b[r] -= f * b[col];
    }
  }
  for (int r = 5; r >= 0; --r) {
    double acc = b[r];
    for (int k = r + 1; k < 6; ++k) acc -= a[r][k] * x[k];
    x[r] = acc / a[r][r];
  }
}

// out = exp(xi) @ pose for xi = (rho, phi), as geometry/se3.py's se3_exp (Taylor below t^2 = 1e-8).
void left_update(const double xi[6], const double* pose, double* out) {
  const double w0 = xi[3], w1 = xi[4], w2 = xi[5];
  const double t2 = w0 * w0 + w1 * w1 + w2 * w2;
  double a, b, c;
  if (t2 < 1e-8) {
    a = 1.0 - t2 / 6.0, b = 0.5 - t2 / 24.0, c = 1.0 / 6.0 - t2 / 120.0;
  } else {
    const double t = std::sqrt(t2);
    a = std::sin(t) / t, b = (1.0 - std::cos(t)) / t2, c = (t - std::sin(t)) / (t2 * t);
  }
  const double k[3][3] = {{0.0, -w2, w1}, {w2, 0.0, -w0}, {-w1, w0, 0.0}};
  double kk[3][3], rot[3][3], v[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      kk[i][j] = k[i][0] * k[0][j] + k[i][1] * k[1][j] + k[i][2] * k[2][j];
      const double eye = i == j ? 1.0 : 0.0;
      rot[i][j] = eye + a * k[i][j] + b * kk[i][j];
      v[i][j] = eye + b * k[i][j] + c * kk[i][j];
    }
  double m[4][4] = {};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m[i][j] = rot[i][j];
    m[i][3] = v[i][0] * xi[0] + v[i][1] * xi[1] + v[i][2] * xi[2];
  }
  m[3][3] = 1.0;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j)
      out[i * 4 + j] = m[i][0] * pose[j] + m[i][1] * pose[4 + j] + m[i][2] * pose[8 + j] + m[i][3] * pose[12 + j];
}

}  // namespace

// `steps` damped Gauss-Newton updates of `pose` at one pyramid level, as geometry/icp.py's `_solve`
// makes them from these terms: (J^T W J + (damping mean(diag) + 1e-12) I) xi = -J^T W r, then
// pose <- exp(xi) pose. Returns the pose [4, 4] float64.
torch::Tensor gauss_newton_steps(torch::Tensor pose, torch::Tensor points, torch::Tensor values,
                                 torch::Tensor weights, torch::Tensor packed, double fx, double fy, double cx,
                                 double cy, int64_t width, int64_t height, double max_distance, double huber,
                                 double damping, int64_t steps, int64_t threads) {
  auto current = pose.to(torch::kFloat64).contiguous().clone();
  for (int64_t step = 0; step < steps; ++step) {
    const auto terms = gauss_newton_terms(current, points, values, weights, packed, fx, fy, cx, cy, width, height,
                                          max_distance, huber, threads);
    const double* t = terms.data_ptr<double>();
    double h[6][6], g[6], xi[6];
    double mean_diag = 0.0;
    for (int i = 0; i < 6; ++i) mean_diag += t[i * 7 + i] / 6.0;
    for (int i = 0; i < 6; ++i) {
      for (int j = 0; j < 6; ++j) h[i][j] = t[i * 7 + j];
      h[i][i] += damping * mean_diag + 1e-12;
      g[i] = -t[i * 7 + 6];
    }
    solve6(h, g, xi);
    auto next = torch::empty({4, 4}, torch::kFloat64);
    left_update(xi, current.data_ptr<double>(), next.data_ptr<double>());
    current = next;
  }
  return current;
}

// One reference pyramid level, as geometry/icp.py's `_level` packs it (its pure-PyTorch reference):
// per pixel the camera-frame vertex, the unit normal facing the camera from central differences
// inside a one-pixel border (every neighbour valid, |cos| to the viewing ray above min_cos), and
// its validity. One thread: a level is a few thousand pixels.
torch::Tensor vertex_normal_level(torch::Tensor depth, double fx, double fy, double cx, double cy,
                                  double min_cos) {
  TORCH_CHECK(depth.dim() == 2 && depth.scalar_type() == torch::kFloat32, "depth must be [H, W] float32");
  depth = depth.contiguous();
  const int64_t h = depth.size(0), w = depth.size(1);
  auto out = torch::zeros({h * w, 7}, depth.options());
  const float* d = depth.data_ptr<float>();
  float* o = out.data_ptr<float>();
  const float ffx = static_cast<float>(fx), ffy = static_cast<float>(fy);
  const float fcx = static_cast<float>(cx), fcy = static_cast<float>(cy);
  for (int64_t v = 0; v < h; ++v)
    for (int64_t u = 0; u < w; ++u) {
      const float z = d[v * w + u];
      float* row = o + (v * w + u) * 7;
      if (!(std::isfinite(z) && z > 0.0f)) continue;
      row[0] = (static_cast<float>(u) - fcx) / ffx * z;
      row[1] = (static_cast<float>(v) - fcy) / ffy * z;
      row[2] = z;
    }
  for (int64_t v = 1; v + 1 < h; ++v)
    for (int64_t u = 1; u + 1 < w; ++u) {
      const float* c = o + (v * w + u) * 7;
      const float* l = c - 7;
      const float* r = c + 7;
      const float* t = c - 7 * w;
      const float* b = c + 7 * w;
      if (!(c[2] > 0 && l[2] > 0 && r[2] > 0 && t[2] > 0 && b[2] > 0)) continue;
      const float dx[3] = {r[0] - l[0], r[1] - l[1], r[2] - l[2]};
      const float dy[3] = {b[0] - t[0], b[1] - t[1], b[2] - t[2]};
      float n[3] = {dx[1] * dy[2] - dx[2] * dy[1], dx[2] * dy[0] - dx[0] * dy[2], dx[0] * dy[1] - dx[1] * dy[0]};
      const float norm = std::max(std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), 1e-12f);
      for (float& x : n) x /= norm;
      const float dist = std::max(std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), 1e-12f);
      const float cos = (n[0] * c[0] + n[1] * c[1] + n[2] * c[2]) / dist;
      if (!(std::fabs(cos) > static_cast<float>(min_cos))) continue;
      const float flip = cos > 0 ? -1.0f : 1.0f;  // towards the camera
      float* row = o + (v * w + u) * 7;
      row[3] = n[0] * flip;
      row[4] = n[1] * flip;
      row[5] = n[2] * flip;
      row[6] = 1.0f;
    }
  return out;
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("gauss_newton_terms", &gauss_newton_terms, py::call_guard<py::gil_scoped_release>(),
        "Normal equations and truncated cost of one Gauss-Newton step (see the file's header)");
  m.def("gauss_newton_steps", &gauss_newton_steps, py::call_guard<py::gil_scoped_release>(),
        "Damped Gauss-Newton steps at one pyramid level: the updated pose");
  m.def("vertex_normal_level", &vertex_normal_level, py::call_guard<py::gil_scoped_release>(),
        "One ICP reference level's packed vertex, normal and validity rows");
}
