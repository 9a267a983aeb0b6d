// The procedural floor: the view (pixels <-> floor millimetres), shapes (stones, flecks, pits,
// scratches), the canvas with its depth buffer, the low-frequency fields, and the surfaces
// built from them. One file of about 1,200 lines on purpose: its inner loops share file-local
// inline helpers, and this file alone is compiled with -O3 and without math errno/traps
// (CMakeLists.txt) so that they vectorise; byte-identical images across machines depend on
// those flags applying to all of it.
#include "ground_texture_bow/eval/synth/floor.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ground_texture_bow/core/enum_names.h"
#include "noise.h"

namespace gtbow {
namespace synth {

namespace {

inline double FloorD(double x) { return static_cast<double>(FloorToInt(x)); }
inline double CeilD(double x) { return -FloorD(-x); }

constexpr int kCoarse = 4;  // the laminate grain distortion is evaluated every kCoarse pixels

// ---------------------------------------------------------------------------------------------
// The view: pixel <-> floor millimetres.

struct View {
  int w = 0;
  int h = 0;
  double m[9];                    // floor_mm_from_pixel
  double inv[9];                  // pixel_from_floor_mm
  double xmin, xmax, ymin, ymax;  // floor bounding box of the view, mm

  int ci0 = 0, cj0 = 0, ci1 = 0, cj1 = 0;  // clip rectangle (inclusive pixel range)

  View(const Homography& floor_from_pixel, int width, int height) : w(width), h(height) {
    for (int k = 0; k < 6; ++k) m[k] = floor_from_pixel[k] * 1000.0;
    for (int k = 6; k < 9; ++k) m[k] = floor_from_pixel[k];
    Invert();
    ci1 = w - 1;
    cj1 = h - 1;
    ComputeBounds();
  }

  // The same view restricted to pixels [i0, i1] x [j0, j1] (inclusive).
  View Tile(int i0, int j0, int i1, int j1) const {
    View t = *this;
    t.ci0 = i0;
    t.cj0 = j0;
    t.ci1 = i1;
    t.cj1 = j1;
    t.ComputeBounds();
    return t;
  }

  void ComputeBounds() {
    xmin = ymin = std::numeric_limits<double>::max();
    xmax = ymax = std::numeric_limits<double>::lowest();
    const double corners[4][2] = {{ci0 - 0.5, cj0 - 0.5},
                                  {ci1 + 0.5, cj0 - 0.5},
                                  {ci0 - 0.5, cj1 + 0.5},
                                  {ci1 + 0.5, cj1 + 0.5}};
    for (const auto& c : corners) {
      double x, y;
      FloorAt(c[0], c[1], &x, &y);
      xmin = std::min(xmin, x);
      xmax = std::max(xmax, x);
      ymin = std::min(ymin, y);
      ymax = std::max(ymax, y);
    }
  }

  // The same floor seen by a grid with one pixel per `f` x `f` block, whose pixel centre ci sits
  // at fine pixel f * ci + (f - 1) / 2 (the convention of cv::resize).
  View Coarsened(int f) const {
    Homography s{};
    const double off = 0.5 * (f - 1);
    // fine = f * coarse + off
    const double a[9] = {static_cast<double>(f), 0, off, 0, static_cast<double>(f), off, 0, 0, 1};
    double r[9];
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        r[3 * i + j] = 0;
        for (int k = 0; k < 3; ++k) r[3 * i + j] += m[3 * i + k] * a[3 * k + j];
      }
    }
    for (int k = 0; k < 6; ++k) s[k] = r[k] / 1000.0;
    for (int k = 6; k < 9; ++k) s[k] = r[k];
    return View(s, (w + f - 1) / f, (h + f - 1) / f);
  }

  inline void FloorAt(double i, double j, double* x, double* y) const {
    const double iw = 1.0 / (m[6] * i + m[7] * j + m[8]);
    *x = (m[0] * i + m[1] * j + m[2]) * iw;
    *y = (m[3] * i + m[4] * j + m[5]) * iw;
  }

  inline void PixelAt(double x, double y, double* i, double* j) const {
    const double iw = 1.0 / (inv[6] * x + inv[7] * y + inv[8]);
    *i = (inv[0] * x + inv[1] * y + inv[2]) * iw;
    *j = (inv[3] * x + inv[4] * y + inv[5]) * iw;
  }

  // Pixel range covering the floor box [x0, x1] x [y0, y1]; false when it misses the view.
  bool PixelBox(double x0, double y0, double x1, double y1, int* i0, int* i1, int* j0,
                int* j1) const {
    if (x1 < xmin || x0 > xmax || y1 < ymin || y0 > ymax) return false;
    double imin = 1e30, imax = -1e30, jmin = 1e30, jmax = -1e30;
    const double cs[4][2] = {{x0, y0}, {x1, y0}, {x0, y1}, {x1, y1}};
    for (const auto& c : cs) {
      double i, j;
      PixelAt(c[0], c[1], &i, &j);
      imin = std::min(imin, i);
      imax = std::max(imax, i);
      jmin = std::min(jmin, j);
      jmax = std::max(jmax, j);
    }
    *i0 = std::max(ci0, static_cast<int>(FloorD(imin)));
    *i1 = std::min(ci1, static_cast<int>(CeilD(imax)));
    *j0 = std::max(cj0, static_cast<int>(FloorD(jmin)));
    *j1 = std::min(cj1, static_cast<int>(CeilD(jmax)));
    return *i0 <= *i1 && *j0 <= *j1;
  }

 private:
  void Invert() {
    const double* a = m;
    const double det = a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) +
                       a[2] * (a[3] * a[7] - a[4] * a[6]);
    if (std::abs(det) < 1e-300) throw std::invalid_argument("floor_from_pixel is singular");
    const double id = 1.0 / det;
    inv[0] = (a[4] * a[8] - a[5] * a[7]) * id;
    inv[1] = (a[2] * a[7] - a[1] * a[8]) * id;
    inv[2] = (a[1] * a[5] - a[2] * a[4]) * id;
    inv[3] = (a[5] * a[6] - a[3] * a[8]) * id;
    inv[4] = (a[0] * a[8] - a[2] * a[6]) * id;
    inv[5] = (a[2] * a[3] - a[0] * a[5]) * id;
    inv[6] = (a[3] * a[7] - a[4] * a[6]) * id;
    inv[7] = (a[1] * a[6] - a[0] * a[7]) * id;
    inv[8] = (a[0] * a[4] - a[1] * a[3]) * id;
  }
};

// Calls f(x_mm, y_mm, index) for every pixel of the view, exact every 16 pixels along a row
// and linearly interpolated in between (see ForEachPixelNear on why that is exact enough).
template <typename F>
void ForEachPixel(const View& v, F&& f) {
  constexpr int kStep = 16;
  for (int j = 0; j < v.h; ++j) {
    size_t idx = static_cast<size_t>(j) * v.w;
    for (int i0 = 0; i0 < v.w; i0 += kStep) {
      const int n = std::min(kStep, v.w - i0);
      double xa, ya, xb, yb;
      v.FloorAt(i0, j, &xa, &ya);
      v.FloorAt(i0 + kStep, j, &xb, &yb);
      const double sx = (xb - xa) / kStep, sy = (yb - ya) / kStep;
      double x = xa, y = ya;
      for (int k = 0; k < n; ++k, ++idx, x += sx, y += sy) f(x, y, idx);
    }
  }
}

// Not under ThreadSanitizer: the clones' ifunc resolvers run during relocation, before the
// TSan runtime is up, and crash once instrumented.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_THREAD__)
#define GTBOW_AVX2_CLONE __attribute__((target_clones("avx2", "default")))
#else
#define GTBOW_AVX2_CLONE
#endif

// Fills n lattice values of row iy from column ix0 on.
GTBOW_AVX2_CLONE
void LatticeRow(int32_t ix0, int32_t iy, uint32_t seed, int n, float* __restrict out) {
  for (int c = 0; c < n; ++c) out[c] = LatticeValue(ix0 + c, iy, seed);
}

// A run of pixels along which lattice coordinates change linearly: point q of the run is at
// lattice coordinates (l0 + q dl, m0 + q dm).
struct LatticeRun {
  float l0, m0, dl, dm;
};

// Bilinear interpolation of the lattice along one image row made of 16-pixel runs; every point
// lies at least one cell inside the lattice.
GTBOW_AVX2_CLONE
void InterpolateRow(const float* __restrict lat, int stride, const LatticeRun* runs, int width,
                    float* __restrict out) {
  for (int i0 = 0, r = 0; i0 < width; i0 += 16, ++r) {
    const LatticeRun run = runs[r];
    const int n = std::min(16, width - i0);
    for (int q = 0; q < n; ++q) {
      const float l = run.l0 + q * run.dl, m = run.m0 + q * run.dm;
      const int c = static_cast<int>(l), rr = static_cast<int>(m);
      const float tx = l - c, ty = m - rr;
      const int at = rr * stride + c;
      const float top = lat[at] + tx * (lat[at + 1] - lat[at]);
      const float bot = lat[at + stride] + tx * (lat[at + stride + 1] - lat[at + stride]);
      out[i0 + q] = top + ty * (bot - top);
    }
  }
}

// Value noise of lattice spacing `cell` mm for every pixel of the view: the lattice values
// are hashed once over the view's floor bounding box, then interpolated bilinearly at every
// pixel's floor point (exact every 16 pixels, linear in between, as ForEachPixel). The
// lattice is anchored to the floor, so the noise is the same floor-fixed field in every view.
cv::Mat LatticeNoise(const View& v, double cell, uint32_t seed) {
  const int64_t ix0 = FloorToInt(v.xmin / cell) - 2;
  const int64_t iy0 = FloorToInt(v.ymin / cell) - 2;
  const int nx = static_cast<int>(FloorToInt(v.xmax / cell) - ix0) + 4;
  const int ny = static_cast<int>(FloorToInt(v.ymax / cell) - iy0) + 4;
  cv::Mat lattice(ny, nx, CV_32F);
  for (int r = 0; r < ny; ++r) {
    LatticeRow(static_cast<int32_t>(ix0), static_cast<int32_t>(iy0 + r), seed, nx,
               lattice.ptr<float>(r));
  }
  cv::Mat out(v.h, v.w, CV_32F);
  const double k = 1.0 / cell;
  constexpr int kStep = 16;
  std::vector<LatticeRun> runs((v.w + kStep - 1) / kStep);
  for (int j = 0; j < v.h; ++j) {
    for (int i0 = 0, r = 0; i0 < v.w; i0 += kStep, ++r) {
      double xa, ya, xb, yb;
      v.FloorAt(i0, j, &xa, &ya);
      v.FloorAt(i0 + kStep, j, &xb, &yb);
      runs[r] = {static_cast<float>(xa * k - static_cast<double>(ix0)),
                 static_cast<float>(ya * k - static_cast<double>(iy0)),
                 static_cast<float>((xb - xa) * k / kStep),
                 static_cast<float>((yb - ya) * k / kStep)};
    }
    InterpolateRow(lattice.ptr<float>(), nx, runs.data(), v.w, out.ptr<float>(j));
  }
  return out;
}

// Calls g(dx0, dy0, step_x, step_y, index, count) for each run of `count` pixels of a row whose
// floor points lie within `radius` mm of (cx, cy); pixel k of the run is at offset
// (dx0 + k step_x, dy0 + k step_y) mm from the centre and has index `index + k`.
// The view is taken as affine over the element: the camera's perspective terms change the
// scale by under 2% across the whole image, so over an element's few dozen pixels the error
// is far below a micrometre.
template <typename G>
void ForEachSpanNear(const View& v, double cx, double cy, double radius, G&& g) {
  int i0, i1, j0, j1;
  if (!v.PixelBox(cx - radius, cy - radius, cx + radius, cy + radius, &i0, &i1, &j0, &j1)) return;
  // Local affine model of the view around the element: d(i, j) = d00 + (i - i0) s + (j - j0) t.
  double x00, y00, x10, y10, x01, y01;
  v.FloorAt(i0, j0, &x00, &y00);
  v.FloorAt(i0 + 1, j0, &x10, &y10);
  v.FloorAt(i0, j0 + 1, &x01, &y01);
  const double sx = x10 - x00, sy = y10 - y00, tx = x01 - x00, ty = y01 - y00;
  const double a = sx * sx + sy * sy;
  if (a <= 0.0) return;
  const double inv_a = 1.0 / a;
  const double r2 = radius * radius;
  const int last = i1 - i0;
  double dx0 = x00 - cx, dy0 = y00 - cy;
  for (int j = j0; j <= j1; ++j, dx0 += tx, dy0 += ty) {
    // The pixels of this row inside the circle: |d0 + k s|^2 <= r^2, solved for k.
    const double b = dx0 * sx + dy0 * sy;
    const double c = dx0 * dx0 + dy0 * dy0 - r2;
    const double disc = b * b - a * c;
    if (disc < 0.0) continue;
    const double root = std::sqrt(disc);
    const int k0 = std::max(0, static_cast<int>(CeilD((-b - root) * inv_a)));
    const int k1 = std::min(last, static_cast<int>(FloorD((-b + root) * inv_a)));
    if (k1 < k0) continue;
    g(static_cast<float>(dx0 + k0 * sx), static_cast<float>(dy0 + k0 * sy), static_cast<float>(sx),
      static_cast<float>(sy), static_cast<size_t>(j) * v.w + i0 + k0, k1 - k0 + 1);
  }
}

// Calls f(dx_mm, dy_mm, index) for pixels whose floor point lies within `radius` mm of (cx, cy).
template <typename F>
void ForEachPixelNear(const View& v, double cx, double cy, double radius, F&& f) {
  ForEachSpanNear(v, cx, cy, radius,
                  [&](float dx0, float dy0, float sx, float sy, size_t idx, int n) {
                    for (int k = 0; k < n; ++k) f(dx0 + k * sx, dy0 + k * sy, idx + k);
                  });
}

// Calls gen(rng, cell_x0_mm, cell_y0_mm) for each cell of a `cell` mm grid that may hold an
// element reaching into the view (elements extend at most `reach` mm beyond their cell).
// Cells are visited in a fixed global order, so overlapping elements compose identically in
// every view.
template <typename G>
void ForEachCell(const View& v, double cell, double reach, uint64_t layer_seed, G&& gen) {
  const int64_t cx0 = static_cast<int64_t>(FloorD((v.xmin - reach) / cell));
  const int64_t cx1 = static_cast<int64_t>(FloorD((v.xmax + reach) / cell));
  const int64_t cy0 = static_cast<int64_t>(FloorD((v.ymin - reach) / cell));
  const int64_t cy1 = static_cast<int64_t>(FloorD((v.ymax + reach) / cell));
  for (int64_t cy = cy0; cy <= cy1; ++cy) {
    for (int64_t cx = cx0; cx <= cx1; ++cx) {
      CellRng rng(HashCell(cx, cy, layer_seed));
      gen(rng, cx * cell, cy * cell);
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Shapes.

// An irregular blob: radius R modulated by harmonics 2, 3 and 5 of the polar angle.
struct Blob {
  double cx, cy, r;
  double a2c, a2s, a3c, a3s, a5c, a5s;
  double rmax;

  void Randomize(CellRng& rng, double irregularity) {
    const double a2 = irregularity * rng.Uniform(0.05, 0.35);
    const double a3 = irregularity * rng.Uniform(0.0, 0.15);
    const double a5 = irregularity * rng.Uniform(0.0, 0.07);
    const double p2 = rng.Uniform(0, 2 * M_PI), p3 = rng.Uniform(0, 2 * M_PI),
                 p5 = rng.Uniform(0, 2 * M_PI);
    a2c = a2 * std::cos(p2);
    a2s = a2 * std::sin(p2);
    a3c = a3 * std::cos(p3);
    a3s = a3 * std::sin(p3);
    a5c = a5 * std::cos(p5);
    a5s = a5 * std::sin(p5);
    rmax = r * (1.0 + a2 + a3 + a5);
    fr = static_cast<float>(r);
    f2c = static_cast<float>(a2c);
    f2s = static_cast<float>(a2s);
    f3c = static_cast<float>(a3c);
    f3s = static_cast<float>(a3s);
    f5c = static_cast<float>(a5c);
    f5s = static_cast<float>(a5s);
  }

  // Normalised radius rho / r(phi) of offset (dx, dy): < 1 inside the blob.
  inline float Normalized(float dx, float dy) const {
    const float rho2 = dx * dx + dy * dy;
    if (rho2 < 1e-12f) return 0.0f;
    const float rho = std::sqrt(rho2);
    const float inv = 1.0f / rho;
    const float c = dx * inv, s = dy * inv;
    const float c2 = c * c - s * s, s2 = 2 * c * s;
    const float c3 = c2 * c - s2 * s, s3 = s2 * c + c2 * s;
    const float c5 = c3 * c2 - s3 * s2, s5 = s3 * c2 + c3 * s2;
    const float rr = fr * (1.0f + f2c * c2 + f2s * s2 + f3c * c3 + f3s * s3 + f5c * c5 + f5s * s5);
    return rho / rr;
  }
  float fr, f2c, f2s, f3c, f3s, f5c, f5s;  // float copies for the per-pixel test
};

// Distance from p to segment ab.
inline double SegmentDistance(double px, double py, double ax, double ay, double bx, double by) {
  const double vx = bx - ax, vy = by - ay;
  const double wx = px - ax, wy = py - ay;
  const double len2 = vx * vx + vy * vy;
  double t = len2 > 0 ? (wx * vx + wy * vy) / len2 : 0.0;
  t = t < 0 ? 0 : (t > 1 ? 1 : t);
  const double dx = wx - t * vx, dy = wy - t * vy;
  return std::sqrt(dx * dx + dy * dy);
}

// A stroke along a polyline of 3 segments (a bent line), `width` mm wide.
struct Stroke {
  double px[4], py[4];
  double width;
  double cx, cy, reach;

  void Make(CellRng& rng, double x, double y, double angle, double length, double bend) {
    double a = angle;
    px[0] = x;
    py[0] = y;
    for (int k = 1; k < 4; ++k) {
      a += bend * rng.Uniform(-1.0, 1.0);
      px[k] = px[k - 1] + std::cos(a) * length / 3.0;
      py[k] = py[k - 1] + std::sin(a) * length / 3.0;
    }
    cx = 0.25 * (px[0] + px[1] + px[2] + px[3]);
    cy = 0.25 * (py[0] + py[1] + py[2] + py[3]);
    reach = 0.0;
    for (int k = 0; k < 4; ++k) reach = std::max(reach, std::hypot(px[k] - cx, py[k] - cy));
    reach += width;
  }

  // Distance from the floor point (cx + dx, cy + dy) to the stroke's centre line.
  inline double Distance(float dx, float dy) const {
    const double x = cx + dx, y = cy + dy;
    double d = SegmentDistance(x, y, px[0], py[0], px[1], py[1]);
    d = std::min(d, SegmentDistance(x, y, px[1], py[1], px[2], py[2]));
    return std::min(d, SegmentDistance(x, y, px[2], py[2], px[3], py[3]));
  }
};

// ---------------------------------------------------------------------------------------------
// Canvas: the fine image, a depth buffer for opaque elements, and the low-frequency fields.

struct Canvas {
  const View& fine;  // the whole supersampled image
  View region;       // the tile that element layers draw into (cache-sized)
  float* value;
  std::vector<float> depth;
  cv::Mat grain_buf;
  float* grain;  // fine floor-fixed noise in [-1, 1], texture inside elements (set by the base)
  std::vector<float> height;  // relief, mm above the binder (0 where a surface has none)

  Canvas(const View& v, float* out)
      : fine(v),
        region(v),
        value(out),
        depth(static_cast<size_t>(v.w) * v.h, -1.0f),
        grain_buf(v.h, v.w, CV_32F),
        grain(grain_buf.ptr<float>()),
        height(static_cast<size_t>(v.w) * v.h, 0.0f) {}

  cv::Mat Noise(double cell, uint32_t seed) const { return LatticeNoise(fine, cell, seed); }

  // Noise whose lattice is several pixels wide: evaluated on a grid 4x coarser, then upsampled.
  cv::Mat SmoothNoise(double cell, uint32_t seed) const {
    constexpr int f = 4;
    const View coarse = fine.Coarsened(f);
    const cv::Mat c = LatticeNoise(coarse, cell, seed);
    cv::Mat up;
    cv::resize(c, up, cv::Size(coarse.w * f, coarse.h * f), 0, 0, cv::INTER_LINEAR);
    return up(cv::Rect(0, 0, fine.w, fine.h)).clone();
  }

  // Opaque write with depth test.
  inline void Put(size_t idx, float v, float d) {
    if (d > depth[idx]) {
      depth[idx] = d;
      value[idx] = v;
    }
  }
};

uint64_t LayerSeed(uint64_t seed, uint64_t layer) {
  return HashCombine(seed, layer * 0x1000193ULL);
}
uint32_t Seed32(uint64_t seed, uint64_t layer) {
  return static_cast<uint32_t>(LayerSeed(seed, layer));
}

// A stone's outline and shading, in float for the per-pixel kernel. The outline is the
// polynomial "egg" q(u, v) = ((u/a)^2 + (v/b)^2) (1 + e_u u/a + e_v v/b) < 1 in the stone's
// own axes (u, v), roughened by the floor-fixed grain noise: no square root or division per
// pixel, so the kernel vectorises well.
struct StoneShape {
  float cos_a, sin_a;  // stone axes
  float inv_a, inv_b;  // 1 / semi-axes, 1/mm
  float egg_u, egg_v;  // asymmetry
  float rough;         // outline roughness from the grain noise
  float bright, texture, coat, light_u, light_v, depth;
  float height;  // protrusion above the binder at the centre, mm
};

// A run of `n` pixels of one image row starting at pixel index `idx`, whose floor offsets from
// an element's centre are (dx0 + k step_x, dy0 + k step_y) for k = 0..n-1.
struct PixelRun {
  float dx0, dy0;
  uint32_t idx;
  int n;
};

// Draws one stone over its pixel runs: each pixel takes the stone where it lies inside the
// outline and above what was drawn before (depth test). The inner loop is branch-free so that
// the compiler vectorises it: this is the floor's hottest loop. On x86-64 an AVX2 clone is
// chosen at load time where the CPU has it; without FMA contraction both clones compute the
// same IEEE results, so the output stays byte-identical.
GTBOW_AVX2_CLONE
void StoneRuns(const PixelRun* runs, int count, float sx, float sy, float* __restrict depth,
               float* __restrict value, float* __restrict height, const float* __restrict grain,
               const StoneShape& st) {
  const float ca = st.cos_a, sa = st.sin_a, ia = st.inv_a, ib = st.inv_b, eu = st.egg_u,
              ev = st.egg_v, rough = st.rough, bright = st.bright, amp = st.texture, coat = st.coat,
              lu = st.light_u, lv = st.light_v, dep_k = st.depth, top = st.height;
  for (int r = 0; r < count; ++r) {
    const PixelRun run = runs[r];
    float* __restrict d = depth + run.idx;
    float* __restrict out = value + run.idx;
    float* __restrict ht = height + run.idx;
    const float* __restrict gr = grain + run.idx;
    for (int k = 0; k < run.n; ++k) {
      const float dx = run.dx0 + k * sx, dy = run.dy0 + k * sy;
      const float u = (ca * dx + sa * dy) * ia;
      const float v = (-sa * dx + ca * dy) * ib;
      const float g = gr[k];
      const float q = (u * u + v * v) * (1.0f + eu * u + ev * v) + rough * g;
      const float w = std::min(std::max((q - 0.4f) * (1.0f / 0.6f), 0.0f), 1.0f);
      const float val =
          (bright * (1.0f + amp * g) + lu * u + lv * v) * (1.0f - coat * w * w * (3.0f - 2.0f * w));
      // A dome: full height at the centre, falling steeply at the rim.
      const float t = std::max(1.0f - q, 0.0f);
      const float h = top * t * (2.0f - t);
      const bool take = (q < 1.0f) & (dep_k > d[k]);
      d[k] = take ? dep_k : d[k];
      out[k] = take ? val : out[k];
      ht[k] = take ? h : ht[k];
    }
  }
}

// Draws aggregate-like stones of one size class: `prob` stones per `cell` mm cell on average,
// semi-major axes in [rmin, rmax] mm, elongation and asymmetry scaled by `irregularity`.
void DrawStones(Canvas& cv, uint64_t seed, double cell, double prob, double rmin, double rmax,
                double irregularity, double bright_mean, double bright_sd, double texture) {
  const double reach = rmax * 1.6;
  float* const dep = cv.depth.data();
  float* const val = cv.value;
  float* const hgt = cv.height.data();
  const float* const grain = cv.grain;
  const double exp_prob = std::exp(-prob);
  std::vector<PixelRun> runs;
  runs.reserve(256);
  ForEachCell(cv.region, cell, reach, seed, [&](CellRng& rng, double x0, double y0) {
    const int n = rng.PoissonExp(exp_prob);
    for (int k = 0; k < n; ++k) {
      const double cx = x0 + rng.Uniform(0, cell);
      const double cy = y0 + rng.Uniform(0, cell);
      const double ua = rng.Uniform();
      const double a = rmin + (rmax - rmin) * ua * std::sqrt(ua);
      const double b = a * (1.0 - irregularity * rng.Uniform(0.0, 0.45));
      const double ang = rng.Uniform(0, M_PI);
      // Mostly mid greys, some bright (quartz) and some dark (basalt) stones.
      double bright = bright_mean + bright_sd * rng.ApproxNormal();
      const double kind = rng.Uniform();
      if (kind < 0.12)
        bright += 0.25;
      else if (kind < 0.22)
        bright -= 0.2;
      StoneShape st;
      st.cos_a = static_cast<float>(std::cos(ang));
      st.sin_a = static_cast<float>(std::sin(ang));
      st.inv_a = static_cast<float>(1.0 / a);
      st.inv_b = static_cast<float>(1.0 / b);
      st.egg_u = static_cast<float>(irregularity * rng.Uniform(-0.3, 0.3));
      st.egg_v = static_cast<float>(irregularity * rng.Uniform(-0.3, 0.3));
      st.rough = static_cast<float>(irregularity * rng.Uniform(0.15, 0.6));
      st.bright = static_cast<float>(std::clamp(bright, 0.08, 0.95));
      st.texture = static_cast<float>(texture * rng.Uniform(0.5, 1.5));
      st.coat = static_cast<float>(rng.Uniform(0.1, 0.45));  // binder coating at the rim
      st.light_u = static_cast<float>(rng.Uniform(-1, 1) * 0.08);
      st.light_v = static_cast<float>(rng.Uniform(-1, 1) * 0.08);
      st.depth = static_cast<float>(rng.Uniform());
      // Exposed aggregate stands proud of the binder by a fraction of its size. The fraction
      // comes from the digits of the depth draw rather than a new draw, so that adding relief
      // left every later random draw, and so the texture, unchanged.
      st.height = static_cast<float>(a * (0.1 + 0.25 * std::fmod(st.depth * 997.0, 1.0)));
      // q < 1 needs (u^2 + v^2) < (1 + rough) / (1 - |e|): bound the search radius by that.
      const double e = std::abs(st.egg_u) + std::abs(st.egg_v);
      const double bound = a * std::sqrt((1.0 + st.rough) / std::max(0.2, 1.0 - e));
      runs.clear();
      float step_x = 0.0f, step_y = 0.0f;
      ForEachSpanNear(cv.region, cx, cy, bound,
                      [&](float dx0, float dy0, float sx, float sy, size_t idx, int m) {
                        runs.push_back({dx0, dy0, static_cast<uint32_t>(idx), m});
                        step_x = sx;
                        step_y = sy;
                      });
      if (!runs.empty()) {
        StoneRuns(runs.data(), static_cast<int>(runs.size()), step_x, step_y, dep, val, hgt, grain,
                  st);
      }
    }
  });
}

// Pores, holes and pits: dark, with a soft shadowed rim.
void DrawPores(Canvas& cv, uint64_t seed, double cell, double prob, double rmin, double rmax,
               float darkness) {
  ForEachCell(cv.region, cell, rmax * 1.6, seed, [&](CellRng& rng, double x0, double y0) {
    const int n = rng.Poisson(prob);
    for (int k = 0; k < n; ++k) {
      Blob b;
      b.cx = x0 + rng.Uniform(0, cell);
      b.cy = y0 + rng.Uniform(0, cell);
      b.r = rmin + (rmax - rmin) * std::pow(rng.Uniform(), 3.0);
      b.Randomize(rng, 0.6);
      const float inner = darkness * static_cast<float>(rng.Uniform(0.6, 1.3));
      const double sx = rng.Uniform(-0.5, 0.5), sy = rng.Uniform(-0.5, 0.5);  // shadow side
      ForEachPixelNear(cv.region, b.cx, b.cy, b.rmax * 1.35, [&](float dx, float dy, size_t idx) {
        const double t = b.Normalized(dx, dy);
        if (t < 1.0) {
          const float shade = static_cast<float>(1.0 + (sx * dx + sy * dy) / b.r);
          cv.value[idx] = inner * shade;
          cv.depth[idx] = 2.0f;  // pores are holes: nothing lies on top
          cv.height[idx] = -0.3f * static_cast<float>(b.r);
        } else if (t < 1.35) {
          cv.value[idx] *= 0.7f + 0.3f * SmoothStep(1.0f, 1.35f, static_cast<float>(t));
        }
      });
    }
  });
}

// Strokes (fibres, scuffs, hairs). `mode` 0: opaque with depth; 1: multiply; 2: lighten.
void DrawStroke(Canvas& cv, const Stroke& s, float value, float depth, int mode, float alpha) {
  ForEachPixelNear(cv.region, s.cx, s.cy, s.reach, [&](float dx, float dy, size_t idx) {
    const double d = s.Distance(dx, dy);
    if (d >= s.width) return;
    const float q = static_cast<float>(d / s.width);
    if (mode == 0) {
      cv.Put(idx, value * (1.0f - 0.35f * q * q), depth);
    } else {
      const float a = alpha * (1.0f - q * q);
      if (mode == 1) {
        cv.value[idx] *= 1.0f - a * (1.0f - value);
      } else {
        cv.value[idx] += a * (value - cv.value[idx]);
      }
    }
  });
}

// ---------------------------------------------------------------------------------------------
// Low-frequency fields: additive brightness and multiplicative dirt, on the coarse grid.

// Days until an element born at `birth` has fully developed; strength at `day`.
inline double Developed(double day, double birth, double tau) {
  return day <= birth ? 0.0 : 1.0 - std::exp(-(day - birth) / tau);
}

// Birth day of an ageing element: exponential with the given mean, scaled by the ageing rate.
inline double BirthDay(CellRng& rng, double mean_days, double aging) {
  if (aging <= 0.0) return std::numeric_limits<double>::infinity();
  return -std::log(1.0 - rng.Uniform()) * mean_days / aging;
}

void DrawWearLowFrequency(const View& cview, uint64_t seed, const FloorState& st, cv::Mat* mul) {
  float* m = mul->ptr<float>();
  const double day = st.day;
  // General grime: a darkening film that thickens with age.
  const double film = std::min(1.0, day * st.aging / 365.0);
  if (film > 0.0) {
    const uint32_t s = Seed32(seed, 901);
    ForEachPixel(cview, [&](double x, double y, size_t idx) {
      const float n = Fbm(x / 40.0, y / 40.0, s, 3);
      m[idx] *= 1.0f - static_cast<float>(film) * (0.06f + 0.06f * n);
    });
  }
  // Stains: irregular dark blotches born at random days, that persist and darken.
  const uint32_t stain_noise = Seed32(seed, 902);
  ForEachCell(cview, 70.0, 45.0, LayerSeed(seed, 903), [&](CellRng& rng, double x0, double y0) {
    const double birth = BirthDay(rng, 300.0, st.aging);
    const double dev = Developed(day, birth, 25.0);
    if (dev <= 0.0) return;
    const double cx = x0 + rng.Uniform(0, 70.0), cy = y0 + rng.Uniform(0, 70.0);
    const double r = rng.Uniform(6.0, 30.0);
    const float strength = static_cast<float>(dev * rng.Uniform(0.15, 0.45));
    const double ox = rng.Uniform(0, 1000), oy = rng.Uniform(0, 1000);
    ForEachPixelNear(cview, cx, cy, r * 1.5, [&](float dx, float dy, size_t idx) {
      const float n = Fbm(ox + dx / (0.35 * r), oy + dy / (0.35 * r), stain_noise, 3);
      const float fall = static_cast<float>((dx * dx + dy * dy) / (r * r));
      const float mask = SmoothStep(0.0f, 0.35f, 0.6f + 0.6f * n - fall);
      m[idx] *= 1.0f - strength * mask;
    });
  });
  // Tyre marks: long faint bands with a tread pattern, laid down on random days.
  ForEachCell(cview, 400.0, 400.0, LayerSeed(seed, 904), [&](CellRng& rng, double x0, double y0) {
    const double birth = BirthDay(rng, 250.0, st.aging);
    const double dev = Developed(day, birth, 5.0);
    if (dev <= 0.0) return;
    const double cx = x0 + rng.Uniform(0, 400.0), cy = y0 + rng.Uniform(0, 400.0);
    const double ang = rng.Uniform(0, M_PI);
    const double dxu = std::cos(ang), dyu = std::sin(ang);
    const double half_width = rng.Uniform(20.0, 40.0);
    const double half_len = 400.0;
    const double tread = rng.Uniform(6.0, 12.0);
    const float alpha = static_cast<float>(dev * rng.Uniform(0.08, 0.22));
    const uint32_t ns = static_cast<uint32_t>(rng.Next());
    // Skip bands that miss the view entirely.
    const double vx = 0.5 * (cview.xmin + cview.xmax) - cx,
                 vy = 0.5 * (cview.ymin + cview.ymax) - cy;
    const double view_r = 0.5 * std::hypot(cview.xmax - cview.xmin, cview.ymax - cview.ymin);
    if (std::abs(-vx * dyu + vy * dxu) > half_width + view_r) return;
    ForEachPixelNear(cview, cx, cy, half_len, [&](float dx, float dy, size_t idx) {
      const double along = dx * dxu + dy * dyu;
      const double across = -dx * dyu + dy * dxu;
      if (std::abs(across) > half_width) return;
      const float edge =
          1.0f - SmoothStep(0.7f, 1.0f, static_cast<float>(std::abs(across) / half_width));
      const float pattern = 0.6f + 0.4f * static_cast<float>(std::cos(2 * M_PI * along / tread)) *
                                       (std::abs(across) < 0.5 * half_width ? 1.0f : -1.0f);
      const float patch = 0.5f + 0.5f * ValueNoise(along / 30.0, across / 15.0, ns);
      const float fade =
          1.0f - SmoothStep(0.6f, 1.0f, static_cast<float>(std::abs(along) / half_len));
      m[idx] *= 1.0f - alpha * edge * pattern * patch * fade;
    });
  });
}

// Scuffs (progressive, fine) and debris (transient, per visit).
void DrawWearFine(Canvas& cv, uint64_t seed, const FloorState& st) {
  const double day = st.day;
  ForEachCell(cv.region, 45.0, 45.0, LayerSeed(seed, 911), [&](CellRng& rng, double x0, double y0) {
    for (int k = 0; k < 2; ++k) {
      const double birth = BirthDay(rng, 200.0, st.aging);
      Stroke s;
      s.width = rng.Uniform(0.15, 0.8);
      const double len = rng.Uniform(8.0, 40.0);
      s.Make(rng, x0 + rng.Uniform(0, 45.0), y0 + rng.Uniform(0, 45.0), rng.Uniform(0, 2 * M_PI),
             len, 0.25);
      const bool rubber = rng.Uniform() < 0.6;  // black rubber scuff or bright scratch
      const float alpha = static_cast<float>(rng.Uniform(0.3, 0.75));
      if (day <= birth) continue;
      DrawStroke(cv, s, rubber ? 0.15f : 0.9f, 0.0f, rubber ? 1 : 2,
                 alpha * static_cast<float>(Developed(day, birth, 3.0)));
    }
  });
  // Debris: grit, dust and bits of litter that come and go between visits; more on old floors.
  const double density = 0.15 + 0.6 * std::min(1.0, day * st.aging / 180.0);
  if (st.aging <= 0.0) return;
  ForEachCell(cv.region, 12.0, 4.0, HashCombine(LayerSeed(seed, 912), st.visit_seed),
              [&](CellRng& rng, double x0, double y0) {
                const int n = rng.Poisson(density);
                for (int k = 0; k < n; ++k) {
                  Blob b;
                  b.cx = x0 + rng.Uniform(0, 12.0);
                  b.cy = y0 + rng.Uniform(0, 12.0);
                  b.r = 0.15 + 1.2 * std::pow(rng.Uniform(), 2.5);
                  b.Randomize(rng, 1.0);
                  const float v = static_cast<float>(rng.Uniform() < 0.5 ? rng.Uniform(0.75, 1.0)
                                                                         : rng.Uniform(0.02, 0.15));
                  ForEachPixelNear(
                      cv.region, b.cx, b.cy, b.rmax, [&](float dx, float dy, size_t idx) {
                        if (b.Normalized(dx, dy) < 1.0) {
                          cv.value[idx] = v;
                          cv.depth[idx] = 3.0f;
                          cv.height[idx] = 1.5f * static_cast<float>(b.r);  // lies on the surface
                        }
                      });
                }
              });
}

// ---------------------------------------------------------------------------------------------
// Surfaces.

// Each surface renders in two phases: the per-pixel base over the whole image, then the
// discrete elements tile by tile (see Floor::Render).
enum class Phase { kBase, kElements };

void RenderAsphalt(Canvas& cv, uint64_t seed, Phase phase) {
  if (phase == Phase::kElements) {
    DrawStones(cv, LayerSeed(seed, 10), 9.0, 0.7, 2.5, 5.0, 1.0, 0.5, 0.12, 0.12);
    DrawStones(cv, LayerSeed(seed, 11), 3.6, 1.3, 0.8, 1.9, 1.0, 0.5, 0.13, 0.14);
    DrawStones(cv, LayerSeed(seed, 12), 1.4, 0.8, 0.22, 0.6, 0.8, 0.45, 0.15, 0.1);
    return;
  }
  const uint32_t s1 = Seed32(seed, 1), s2 = Seed32(seed, 2);
  const cv::Mat fine = cv.Noise(0.16, s2), mid = cv.SmoothNoise(0.9, s1);
  const float* f = fine.ptr<float>();
  const float* m = mid.ptr<float>();
  const size_t n = static_cast<size_t>(cv.fine.w) * cv.fine.h;
  for (size_t idx = 0; idx < n; ++idx) {
    cv.grain[idx] = 0.6f * f[idx] + 0.4f * m[idx];
    cv.value[idx] = 0.2f + 0.05f * m[idx] + 0.07f * f[idx];
    cv.height[idx] = 0.04f * cv.grain[idx];  // a slightly rough binder
  }
}

void RenderConcrete(Canvas& cv, uint64_t seed, Phase phase) {
  if (phase == Phase::kElements) {
    // Exposed aggregate, barely darker or lighter than the paste.
    DrawStones(cv, LayerSeed(seed, 20), 14.0, 0.35, 1.5, 4.0, 1.0, 0.5, 0.07, 0.06);
    // Sand grains.
    DrawStones(cv, LayerSeed(seed, 21), 0.7, 0.6, 0.08, 0.25, 0.6, 0.52, 0.12, 0.0);
    // Pores of many sizes.
    DrawPores(cv, LayerSeed(seed, 22), 2.5, 0.35, 0.12, 1.1, 0.16f);
    return;
  }
  const uint32_t s1 = Seed32(seed, 1), s2 = Seed32(seed, 2);
  const cv::Mat fine = cv.Noise(0.18, s2), mid = cv.SmoothNoise(1.2, s1);
  const float* f = fine.ptr<float>();
  const float* m = mid.ptr<float>();
  const size_t n = static_cast<size_t>(cv.fine.w) * cv.fine.h;
  for (size_t idx = 0; idx < n; ++idx) {
    cv.grain[idx] = 0.6f * f[idx] + 0.4f * m[idx];
    cv.value[idx] = 0.52f + 0.035f * m[idx] + 0.05f * f[idx];
  }
}

void RenderCarpet(Canvas& cv, uint64_t seed, Phase phase) {
  if (phase == Phase::kBase) {
    const cv::Mat fine = cv.Noise(0.5, Seed32(seed, 1));
    const float* f = fine.ptr<float>();
    const size_t n = static_cast<size_t>(cv.fine.w) * cv.fine.h;
    for (size_t idx = 0; idx < n; ++idx) cv.value[idx] = 0.16f + 0.05f * f[idx];
    cv.grain_buf.setTo(0.0f);
    return;
  }
  constexpr double kTuft = 2.2;                             // tuft spacing, mm
  const double pile = HashCombine(seed, 77) % 628 / 100.0;  // prevailing pile direction
  ForEachCell(cv.region, kTuft, 3.0, LayerSeed(seed, 30), [&](CellRng& rng, double x0, double y0) {
    const double tx = x0 + 0.5 * kTuft + 0.25 * kTuft * rng.Uniform(-1, 1);
    const double ty = y0 + 0.5 * kTuft + 0.25 * kTuft * rng.Uniform(-1, 1);
    const double tuft_bright = rng.Uniform(0.4, 0.75);
    const int fibres = 6 + static_cast<int>(rng.Uniform() * 6);
    for (int k = 0; k < fibres; ++k) {
      Stroke s;
      s.width = rng.Uniform(0.07, 0.14);
      const double ang = rng.Uniform() < 0.6 ? pile + 0.8 * rng.Normal() : rng.Uniform(0, 2 * M_PI);
      s.Make(rng, tx + 0.2 * rng.Normal(), ty + 0.2 * rng.Normal(), ang, rng.Uniform(0.8, 2.4),
             0.35);
      const float v = static_cast<float>(std::clamp(tuft_bright + 0.08 * rng.Normal(), 0.1, 0.95));
      DrawStroke(cv, s, v, static_cast<float>(rng.Uniform()), 0, 1.0f);
    }
  });
}

void RenderLaminate(Canvas& cv, uint64_t seed, Phase phase, const cv::Mat& distortion) {
  if (phase == Phase::kElements) {
    // Pores: short dark dashes along the grain.
    ForEachCell(cv.region, 1.6, 1.0, LayerSeed(seed, 42), [&](CellRng& rng, double x0, double y0) {
      if (rng.Uniform() > 0.45) return;
      Stroke s;
      s.width = rng.Uniform(0.05, 0.1);
      s.Make(rng, x0 + rng.Uniform(0, 1.6), y0 + rng.Uniform(0, 1.6), 0.05 * rng.Normal(),
             rng.Uniform(0.3, 1.2), 0.05);
      DrawStroke(cv, s, 0.55f, 0.0f, 1, 0.6f);
    });
    return;
  }
  constexpr double kPlankW = 120.0, kPlankL = 1000.0;  // mm; planks run along floor x
  cv.grain_buf.setTo(0.0f);
  const uint64_t row_seed = LayerSeed(seed, 40);
  const uint32_t fibre_seed = Seed32(seed, 41);
  const cv::Mat dist = distortion.isContinuous() ? distortion : distortion.clone();
  const float* add = dist.ptr<float>();  // grain distortion, mm
  ForEachPixel(cv.fine, [&](double x, double y, size_t idx) {
    const double rowf = FloorD(y / kPlankW);
    const int64_t row = static_cast<int64_t>(rowf);
    const double offset = (HashCell(row, 0, row_seed) >> 11) * (kPlankL / 9007199254740992.0);
    const double pf = FloorD((x - offset) / kPlankL);
    const int64_t plank = static_cast<int64_t>(pf);
    const double u = x - offset - pf * kPlankL;  // along the plank, mm
    const double v = y - rowf * kPlankW;         // across the plank, mm
    const uint64_t ps = HashCell(plank, row, row_seed + 1);
    const double base = 0.45 + 0.2 * ((ps & 0xffff) / 65535.0);
    const double period = 1.8 + 2.5 * (((ps >> 16) & 0xffff) / 65535.0);
    const double phase = ((ps >> 32) & 0xffff) / 65535.0 * 100.0;
    const double amp = 0.5 + (((ps >> 48) & 0xffff) / 65535.0);
    const double g = std::sin(2 * M_PI * (v + phase + amp * add[idx]) / period);
    float val = static_cast<float>(base * (0.88 + 0.12 * g * g * g));
    val += 0.035f * ValueNoise(u / 4.0, v / 0.12 + phase, fibre_seed);
    // Seams with a small bevel.
    const double edge = std::min(std::min(u, kPlankL - u), std::min(v, kPlankW - v));
    if (edge < 0.9)
      val *= edge < 0.2 ? 0.25f : 0.55f + 0.45f * static_cast<float>((edge - 0.2) / 0.7);
    cv.value[idx] = val;
  });
}

// Faint flecks: soft-edged blobs that change the brightness by a factor 1 + c, c drawn with
// deviation `contrast` (sand grains in a trowelled paste, specks in a coating).
void DrawFlecks(Canvas& cv, uint64_t seed, double cell, double prob, double rmin, double rmax,
                double contrast) {
  ForEachCell(cv.region, cell, rmax * 1.6, seed, [&](CellRng& rng, double x0, double y0) {
    const int n = rng.Poisson(prob);
    for (int k = 0; k < n; ++k) {
      Blob b;
      b.cx = x0 + rng.Uniform(0, cell);
      b.cy = y0 + rng.Uniform(0, cell);
      b.r = rmin + (rmax - rmin) * std::pow(rng.Uniform(), 2.0);
      b.Randomize(rng, 0.5);
      const float c = static_cast<float>(contrast * rng.ApproxNormal());
      ForEachPixelNear(cv.region, b.cx, b.cy, b.rmax * 1.3, [&](float dx, float dy, size_t idx) {
        const float t = b.Normalized(dx, dy);
        if (t < 1.3f) cv.value[idx] *= 1.0f + c * (1.0f - SmoothStep(0.85f, 1.15f, t));
      });
    }
  });
}

// Power-trowelled or polished concrete: a cement paste whose structure is fine and faint
// (grey-level deviation of a few percent): cloudy mottling at several scales, sand fines,
// sparse small pinholes, faint flecks of fine aggregate. Nearly flat (polished).
void RenderSmoothConcrete(Canvas& cv, uint64_t seed, Phase phase) {
  if (phase == Phase::kElements) {
    DrawFlecks(cv, LayerSeed(seed, 60), 0.7, 0.8, 0.08, 0.35, 0.06);  // sand grains
    DrawFlecks(cv, LayerSeed(seed, 61), 6.0, 0.5, 0.4, 1.6, 0.04);    // fine aggregate
    DrawPores(cv, LayerSeed(seed, 62), 2.5, 0.45, 0.06, 0.5, 0.38f);  // pinholes and pits
    return;
  }
  const uint32_t s1 = Seed32(seed, 1), s2 = Seed32(seed, 2), s3 = Seed32(seed, 4);
  const cv::Mat fine = cv.Noise(0.4, s2), mid = cv.SmoothNoise(1.5, s1),
                cloud = cv.SmoothNoise(6.0, s3);
  const float* f = fine.ptr<float>();
  const float* m = mid.ptr<float>();
  const float* c = cloud.ptr<float>();
  const size_t n = static_cast<size_t>(cv.fine.w) * cv.fine.h;
  for (size_t idx = 0; idx < n; ++idx) {
    cv.grain[idx] = 0.6f * f[idx] + 0.4f * m[idx];
    cv.value[idx] = 0.55f + 0.02f * f[idx] + 0.012f * m[idx] + 0.018f * c[idx];
    cv.height[idx] = 0.004f * cv.grain[idx];
  }
}

// A painted or epoxy floor: a uniform coat whose only structure is an orange-peel relief
// (shaded by the camera's lamp), roller marks, dust specks, bubbles and hairline scratches.
void RenderEpoxy(Canvas& cv, uint64_t seed, Phase phase) {
  if (phase == Phase::kElements) {
    DrawFlecks(cv, LayerSeed(seed, 70), 1.2, 0.5, 0.05, 0.25, 0.1);  // dust and filler in the coat
    DrawPores(cv, LayerSeed(seed, 71), 14.0, 0.3, 0.08, 0.3, 0.3f);  // bubbles, pinholes
    ForEachCell(cv.region, 18.0, 30.0, LayerSeed(seed, 72),
                [&](CellRng& rng, double x0, double y0) {
                  if (rng.Uniform() > 0.6) return;  // hairline scratches
                  Stroke st;
                  st.width = rng.Uniform(0.04, 0.12);
                  st.Make(rng, x0 + rng.Uniform(0, 18.0), y0 + rng.Uniform(0, 18.0),
                          rng.Uniform(0, 2 * M_PI), rng.Uniform(5.0, 30.0), 0.15);
                  DrawStroke(cv, st, 0.75f, 0.0f, 2, static_cast<float>(rng.Uniform(0.04, 0.12)));
                });
    return;
  }
  const uint32_t s1 = Seed32(seed, 1), s2 = Seed32(seed, 2);
  const cv::Mat peel = cv.SmoothNoise(0.7, s1), fine = cv.Noise(0.35, s2);
  const float* p = peel.ptr<float>();
  const float* f = fine.ptr<float>();
  const size_t n = static_cast<size_t>(cv.fine.w) * cv.fine.h;
  for (size_t idx = 0; idx < n; ++idx) {
    cv.grain[idx] = p[idx];
    cv.value[idx] = 0.42f + 0.006f * p[idx] + 0.01f * f[idx];
    cv.height[idx] = 0.035f * p[idx];  // orange peel, mm
  }
}

// A photograph sampled bilinearly at every fine pixel's floor point.
void RenderPhoto(Canvas& cv, const PhotoRegion* region, Phase phase) {
  if (phase == Phase::kElements) return;
  const size_t n = static_cast<size_t>(cv.fine.w) * cv.fine.h;
  std::fill(cv.grain, cv.grain + n, 0.0f);
  if (region == nullptr) {
    std::fill(cv.value, cv.value + n, 0.5f);
    return;
  }
  const cv::Mat& img = region->reflectance;
  const int pw = img.cols, ph = img.rows;
  const double inv = 1.0 / (1000.0 * region->meters_per_pixel);
  const double x0 = 1000.0 * region->x0, y0 = 1000.0 * region->y0;
  ForEachPixel(cv.fine, [&](double x, double y, size_t idx) {
    const double u = std::clamp((x - x0) * inv - 0.5, 0.0, pw - 1.0);
    const double v = std::clamp((y - y0) * inv - 0.5, 0.0, ph - 1.0);
    const int iu = std::min(static_cast<int>(u), pw - 2 < 0 ? 0 : pw - 2);
    const int iv = std::min(static_cast<int>(v), ph - 2 < 0 ? 0 : ph - 2);
    const float fu = static_cast<float>(u - iu), fv = static_cast<float>(v - iv);
    const float* r0 = img.ptr<float>(iv);
    const float* r1 = img.ptr<float>(std::min(iv + 1, ph - 1));
    const int iu1 = std::min(iu + 1, pw - 1);
    const float top = r0[iu] + fu * (r0[iu1] - r0[iu]);
    const float bottom = r1[iu] + fu * (r1[iu1] - r1[iu]);
    cv.value[idx] = top + fv * (bottom - top);
  });
}

void LowFrequencyBase(Surface surface, uint64_t seed, const View& cview, cv::Mat* add) {
  float* a = add->ptr<float>();
  const uint32_t s = Seed32(seed, 3);
  switch (surface) {
    case Surface::kAsphalt:
      ForEachPixel(cview, [&](double x, double y, size_t i) {
        a[i] = 0.05f * Fbm(x / 25.0, y / 25.0, s, 3);
      });
      break;
    case Surface::kConcrete:
      ForEachPixel(cview, [&](double x, double y, size_t i) {
        a[i] = 0.06f * Fbm(x / 30.0, y / 30.0, s, 3);
      });
      break;
    case Surface::kCarpet:
      ForEachPixel(cview, [&](double x, double y, size_t i) {
        a[i] = 0.08f * Fbm(x / 12.0, y / 12.0, s, 3);
      });
      break;
    case Surface::kSmoothConcrete:  // trowel swirls: long faint bands of burnish
      ForEachPixel(cview, [&](double x, double y, size_t i) {
        a[i] = 0.012f * Fbm(x / 60.0, y / 20.0, s, 3) + 0.01f * Fbm(x / 15.0, y / 15.0, s + 1, 2);
      });
      break;
    case Surface::kEpoxy:  // roller marks
      ForEachPixel(cview, [&](double x, double y, size_t i) {
        a[i] = 0.01f * Fbm(x / 150.0, y / 25.0, s, 2);
      });
      break;
    case Surface::kLaminate:  // grain distortion (mm), stretched along the planks
      ForEachPixel(cview, [&](double x, double y, size_t i) {
        a[i] = 6.0f * Fbm(x / 80.0, y / 10.0, s, 2);
      });
      break;
    case Surface::kFlat:
    case Surface::kPhoto:
      break;
  }
}

void DrawMarkers(Canvas& cv, const std::vector<FloorMarker>& markers) {
  for (const auto& mk : markers) {
    const double r = mk.radius * 1000.0;
    ForEachPixelNear(cv.region, mk.x * 1000.0, mk.y * 1000.0, 2.0 * r,
                     [&](float dx, float dy, size_t idx) {
                       cv.value[idx] = dx * dx + dy * dy < r * r ? 1.0f : 0.0f;
                       cv.height[idx] = 0.0f;  // a flat printed disk
                     });
  }
}

// Lambertian shading of the height field by a directional light given in the image frame,
// mixed with ambient light: a flat patch keeps its reflectance, a slope facing the light
// brightens and one facing away darkens (no cast shadows).
void ShadeRelief(const View& v, const float* height, const FloorState& st, float* value) {
  double x0, y0, x1, y1;
  v.FloorAt(0, 0, &x0, &y0);
  v.FloorAt(1, 0, &x1, &y1);
  const float inv2px = static_cast<float>(0.5 / std::hypot(x1 - x0, y1 - y0));  // 1 / (2 px mm)
  const double ce = std::cos(st.light_elevation);
  const float lu = static_cast<float>(ce * std::cos(st.light_azimuth));
  const float lv = static_cast<float>(ce * std::sin(st.light_azimuth));
  const float lz = static_cast<float>(std::sin(st.light_elevation));
  const float d = static_cast<float>(st.directional), ambient = 1.0f - d, dz = d / lz;
  for (int j = 0; j < v.h; ++j) {
    const float* up = height + static_cast<size_t>(std::max(j - 1, 0)) * v.w;
    const float* row = height + static_cast<size_t>(j) * v.w;
    const float* down = height + static_cast<size_t>(std::min(j + 1, v.h - 1)) * v.w;
    float* out = value + static_cast<size_t>(j) * v.w;
    for (int i = 0; i < v.w; ++i) {
      const float hu = (row[std::min(i + 1, v.w - 1)] - row[std::max(i - 1, 0)]) * inv2px;
      const float hv = (down[i] - up[i]) * inv2px;
      const float ndotl = (lz - hu * lu - hv * lv) / std::sqrt(1.0f + hu * hu + hv * hv);
      out[i] *= ambient + dz * std::max(ndotl, 0.0f);
    }
  }
}

}  // namespace

namespace {
// The surfaces a dataset can be rendered from by name (a photo floor is made from photographs).
constexpr EnumName<Surface> kSurfaces[] = {{"asphalt", Surface::kAsphalt},
                                           {"concrete", Surface::kConcrete},
                                           {"carpet", Surface::kCarpet},
                                           {"laminate", Surface::kLaminate},
                                           {"smooth_concrete", Surface::kSmoothConcrete},
                                           {"epoxy", Surface::kEpoxy},
                                           {"flat", Surface::kFlat}};
}  // namespace

Surface ParseSurface(const std::string& name) { return ParseEnumName(name, "surface", kSurfaces); }

std::string SurfaceName(Surface surface) {
  return surface == Surface::kPhoto ? "photo" : EnumValueName(surface, kSurfaces);
}

std::vector<std::string> SurfaceNames() {
  std::vector<std::string> out;
  for (const auto& s : kSurfaces) out.push_back(s.name);
  return out;
}

Floor::Floor(Surface surface, uint64_t seed)
    : surface_(surface),
      seed_(Mix64(seed + 0x5eed)),
      regions_(std::make_shared<std::vector<PhotoRegion>>()) {
  if (surface == Surface::kPhoto)
    throw std::invalid_argument("Floor: a photo floor needs its photographs");
}

Floor::Floor(std::vector<PhotoRegion> regions, uint64_t seed)
    : surface_(Surface::kPhoto),
      seed_(Mix64(seed + 0x5eed)),
      regions_(std::make_shared<std::vector<PhotoRegion>>(std::move(regions))) {
  if (regions_->empty())
    throw std::invalid_argument("Floor: a photo floor needs at least one photograph");
  for (const auto& r : *regions_) {
    if (r.reflectance.empty() || r.reflectance.type() != CV_32F || !(r.meters_per_pixel > 0)) {
      throw std::invalid_argument("Floor: photo region " + r.path.string() +
                                  " has no image or scale");
    }
  }
}

PhotoRegion LoadPhotoRegion(const std::filesystem::path& path, double meters_per_pixel) {
  if (!(meters_per_pixel > 0) || !std::isfinite(meters_per_pixel)) {
    throw std::invalid_argument("photo " + path.string() + ": metres per pixel must be positive");
  }
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw std::invalid_argument("photo " + path.string() + ": no such file");
  }
  cv::Mat img;
  try {
    img = cv::imread(path.string(), cv::IMREAD_ANYDEPTH | cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception& e) {
    img.release();
  }
  if (img.empty()) {
    throw std::invalid_argument(
        "photo " + path.string() +
        ": not an image, or a format that cannot be decoded (use PNG, JPEG, "
        "TIFF or BMP)");
  }
  PhotoRegion r;
  r.path = path;
  r.label = path.stem().string();
  r.meters_per_pixel = meters_per_pixel;
  const double scale = img.depth() == CV_16U  ? 1.0 / 65535.0
                       : img.depth() == CV_8U ? 1.0 / 255.0
                                              : 0.0;
  if (scale == 0.0) {
    throw std::invalid_argument("photo " + path.string() +
                                ": unsupported pixel depth (8 or 16 bits)");
  }
  img.convertTo(r.reflectance, CV_32F, scale);
  return r;
}

void Floor::Render(const Homography& floor_from_image, int width, int height, int supersample,
                   const FloorState& state, cv::Mat* out) const {
  if (width <= 0 || height <= 0) throw std::invalid_argument("Floor::Render: empty target");
  if (supersample < 1 || supersample > 8) {
    throw std::invalid_argument("Floor::Render: supersample must be in 1..8");
  }
  if (!(state.day >= 0.0)) throw std::invalid_argument("Floor::Render: day must be >= 0");
  if (!(state.directional >= 0.0 && state.directional <= 1.0)) {
    throw std::invalid_argument("Floor::Render: directional must be in [0, 1]");
  }
  if (!(state.light_elevation > 0.0 && state.light_elevation <= M_PI / 2)) {
    throw std::invalid_argument("Floor::Render: light_elevation must be in (0, pi/2]");
  }
  // Fine (supersampled) pixel (i, j) has image coordinates u = (i + 0.5) / s - 0.5.
  const double s = supersample;
  const double a[9] = {1.0 / s, 0, 0.5 / s - 0.5, 0, 1.0 / s, 0.5 / s - 0.5, 0, 0, 1};
  Homography fine_h{};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      double v = 0;
      for (int k = 0; k < 3; ++k) v += floor_from_image[3 * r + k] * a[3 * k + c];
      fine_h[3 * r + c] = v;
    }
  }
  const View image(floor_from_image, width, height);
  const View fine(fine_h, width * supersample, height * supersample);

  // Low-frequency fields (brightness variation, grime, stains, tyre marks) are evaluated on a
  // grid coarser than the image and applied after the supersampled detail is averaged down.
  constexpr int kLowFactor = 4;
  const View coarse = image.Coarsened(kLowFactor);
  cv::Mat add_c(coarse.h, coarse.w, CV_32F, cv::Scalar(0));
  cv::Mat mul_c(coarse.h, coarse.w, CV_32F, cv::Scalar(1));
  if (surface_ != Surface::kLaminate) LowFrequencyBase(surface_, seed_, coarse, &add_c);
  if (surface_ != Surface::kFlat) DrawWearLowFrequency(coarse, seed_, state, &mul_c);
  // A photo floor: the region under the image centre.
  const PhotoRegion* region = nullptr;
  if (surface_ == Surface::kPhoto) {
    double cx, cy;
    image.FloorAt(0.5 * (width - 1), 0.5 * (height - 1), &cx, &cy);
    cx /= 1000.0;
    cy /= 1000.0;
    double best = std::numeric_limits<double>::max();
    for (const auto& r : *regions_) {
      const double dx = std::max({r.x0 - cx, 0.0, cx - (r.x0 + r.width())});
      const double dy = std::max({r.y0 - cy, 0.0, cy - (r.y0 + r.height())});
      if (dx * dx + dy * dy < best) {
        best = dx * dx + dy * dy;
        region = &r;
      }
    }
  }

  cv::Mat fine_img(fine.h, fine.w, CV_32F);
  {
    Canvas canvas(fine, fine_img.ptr<float>());
    cv::Mat dist;  // laminate grain distortion, needed at full resolution
    if (surface_ == Surface::kLaminate) {
      const View fc = fine.Coarsened(kCoarse);
      cv::Mat dist_c(fc.h, fc.w, CV_32F, cv::Scalar(0));
      LowFrequencyBase(surface_, seed_, fc, &dist_c);
      cv::resize(dist_c, dist, cv::Size(fc.w * kCoarse, fc.h * kCoarse), 0, 0, cv::INTER_LINEAR);
      dist = dist(cv::Rect(0, 0, fine.w, fine.h)).clone();
    }
    // Phase 1: the per-pixel base. Phase 2: elements, tile by tile so that the buffers they
    // touch stay in cache. Every pixel still meets the elements in the same global order, so
    // the result does not depend on the tiling.
    for (Phase phase : {Phase::kBase, Phase::kElements}) {
      constexpr int kTile = 256;
      const int tw = phase == Phase::kBase ? fine.w : kTile;
      const int th = phase == Phase::kBase ? fine.h : kTile;
      for (int j0 = 0; j0 < fine.h; j0 += th) {
        for (int i0 = 0; i0 < fine.w; i0 += tw) {
          canvas.region =
              fine.Tile(i0, j0, std::min(fine.w, i0 + tw) - 1, std::min(fine.h, j0 + th) - 1);
          switch (surface_) {
            case Surface::kAsphalt:
              RenderAsphalt(canvas, seed_, phase);
              break;
            case Surface::kConcrete:
              RenderConcrete(canvas, seed_, phase);
              break;
            case Surface::kCarpet:
              RenderCarpet(canvas, seed_, phase);
              break;
            case Surface::kLaminate:
              RenderLaminate(canvas, seed_, phase, dist);
              break;
            case Surface::kSmoothConcrete:
              RenderSmoothConcrete(canvas, seed_, phase);
              break;
            case Surface::kEpoxy:
              RenderEpoxy(canvas, seed_, phase);
              break;
            case Surface::kFlat:
              if (phase == Phase::kBase) fine_img.setTo(0.5);
              break;
            case Surface::kPhoto:
              RenderPhoto(canvas, region, phase);
              break;
          }
          if (phase == Phase::kElements) {
            if (surface_ != Surface::kFlat) DrawWearFine(canvas, seed_, state);
            DrawMarkers(canvas, state.markers);
          }
        }
      }
    }
    const bool relief = surface_ == Surface::kAsphalt || surface_ == Surface::kConcrete ||
                        surface_ == Surface::kSmoothConcrete || surface_ == Surface::kEpoxy;
    if (relief && state.directional > 0.0)
      ShadeRelief(fine, canvas.height.data(), state, fine_img.ptr<float>());
  }
  if (supersample > 1) {
    cv::resize(fine_img, *out, cv::Size(width, height), 0, 0, cv::INTER_AREA);
  } else {
    *out = fine_img;
  }
  const cv::Size up(coarse.w * kLowFactor, coarse.h * kLowFactor);
  const cv::Rect roi(0, 0, width, height);
  cv::Mat add, mul;
  cv::resize(add_c, add, up, 0, 0, cv::INTER_LINEAR);
  cv::resize(mul_c, mul, up, 0, 0, cv::INTER_LINEAR);
  float* o = out->ptr<float>();
  for (int v = 0; v < height; ++v) {
    const float* ar = add.ptr<float>(v);
    const float* mr = mul.ptr<float>(v);
    float* orow = o + static_cast<size_t>(v) * width;
    for (int u = 0; u < width; ++u) orow[u] = (orow[u] + ar[u]) * mr[u];
  }
}

}  // namespace synth
}  // namespace gtbow
