#include "ground_texture_bow/core/pose.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

namespace gtbow {

namespace {

Vec2 Rotate(double theta, Vec2 p) {
  const double c = std::cos(theta), s = std::sin(theta);
  return {c * p.x - s * p.y, s * p.x + c * p.y};
}

double Squared(Vec2 a) { return a.x * a.x + a.y * a.y; }

// Draws indices with probability proportional to their weight (or uniformly).
class Sampler {
 public:
  Sampler(const std::vector<PointMatch>& m, bool weighted, uint64_t seed) : rng_(seed) {
    cumulative_.reserve(m.size());
    double sum = 0.0;
    for (const PointMatch& x : m) cumulative_.push_back(sum += weighted ? x.weight : 1.0);
  }
  int Draw() {
    const double u = static_cast<double>(rng_() >> 11) * 0x1.0p-53 * cumulative_.back();
    const auto it = std::upper_bound(cumulative_.begin(), cumulative_.end(), u);
    return static_cast<int>(std::min<size_t>(it - cumulative_.begin(), cumulative_.size() - 1));
  }

 private:
  std::mt19937_64 rng_;
  std::vector<double> cumulative_;
};

// Weighted least-squares rigid transform (2-D Procrustes) over `idx`; centred coordinates.
Rigid2D FitRigid(const std::vector<Vec2>& q, const std::vector<Vec2>& d,
                 const std::vector<double>& w, const std::vector<int>& idx) {
  double sw = 0.0;
  Vec2 qm, dm;
  for (int i : idx) {
    sw += w[i];
    qm.x += w[i] * q[i].x;
    qm.y += w[i] * q[i].y;
    dm.x += w[i] * d[i].x;
    dm.y += w[i] * d[i].y;
  }
  qm = {qm.x / sw, qm.y / sw};
  dm = {dm.x / sw, dm.y / sw};
  double sin_sum = 0.0, cos_sum = 0.0;
  for (int i : idx) {
    const Vec2 a{q[i].x - qm.x, q[i].y - qm.y}, b{d[i].x - dm.x, d[i].y - dm.y};
    cos_sum += w[i] * (a.x * b.x + a.y * b.y);
    sin_sum += w[i] * (a.x * b.y - a.y * b.x);
  }
  Rigid2D r;
  r.theta = std::atan2(sin_sum, cos_sum);
  const Vec2 rq = Rotate(r.theta, qm);
  r.t = {dm.x - rq.x, dm.y - rq.y};
  return r;
}

double Residual2(const Rigid2D& r, Vec2 q, Vec2 d) {
  const Vec2 p = Rotate(r.theta, q);
  return Squared({p.x + r.t.x - d.x, p.y + r.t.y - d.y});
}

// Inverse of a symmetric 3x3 matrix; false when singular.
bool Invert3(const std::array<double, 9>& m, std::array<double, 9>* out) {
  const double a = m[0], b = m[1], c = m[2], d = m[3], e = m[4], f = m[5], g = m[6], h = m[7],
               k = m[8];
  const double A = e * k - f * h, B = -(d * k - f * g), C = d * h - e * g;
  const double det = a * A + b * B + c * C;
  if (!(std::abs(det) > 1e-12)) return false;
  const double inv = 1.0 / det;
  *out = {A * inv, -(b * k - c * h) * inv, (b * f - c * e) * inv,
          B * inv, (a * k - c * g) * inv,  -(a * f - c * d) * inv,
          C * inv, -(a * h - b * g) * inv, (a * e - b * d) * inv};
  return true;
}

}  // namespace

void PoseOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("pose: ") + what);
  };
  need(max_iterations >= 1, "max_iterations must be >= 1");
  need(confidence > 0.0 && confidence < 1.0, "confidence must be in (0, 1)");
  need(inlier_threshold > 0.0 && std::isfinite(inlier_threshold),
       "inlier_threshold must be positive");
  need(min_inliers >= 2, "min_inliers must be >= 2");
  need(refine_iterations >= 0, "refine_iterations must be >= 0");
}

void LocalizationOptions::Check() const {
  if (candidates < 1) throw std::invalid_argument("localization: candidates must be >= 1");
  pose.Check();
}

PoseEstimate EstimatePose(const std::vector<PointMatch>& matches, const Pose2D& floor_from_database,
                          const ImageGeometry& geometry, const PoseOptions& o) {
  o.Check();
  PoseEstimate est;
  const int n = static_cast<int>(matches.size());
  if (n < o.min_inliers) {
    est.reason =
        std::to_string(n) + " matches, fewer than min_inliers = " + std::to_string(o.min_inliers);
    return est;
  }
  const Vec2 c{(geometry.width - 1) / 2.0, (geometry.height - 1) / 2.0};
  std::vector<Vec2> q(n), d(n);
  std::vector<double> w(n);
  for (int i = 0; i < n; ++i) {
    const PointMatch& m = matches[i];
    if (!(m.weight > 0.0) || !std::isfinite(m.weight) || !std::isfinite(m.query.x) ||
        !std::isfinite(m.query.y) || !std::isfinite(m.database.x) || !std::isfinite(m.database.y)) {
      throw std::invalid_argument("EstimatePose: match " + std::to_string(i) +
                                  " has a non-finite coordinate or a non-positive weight");
    }
    q[i] = {m.query.x - c.x, m.query.y - c.y};
    d[i] = {m.database.x - c.x, m.database.y - c.y};
    w[i] = o.weighted ? m.weight : 1.0;
  }
  double total = 0.0;
  for (double x : w) total += x;
  const double thr2 = o.inlier_threshold * o.inlier_threshold;

  // RANSAC over two-point samples.
  Sampler sampler(matches, o.weighted, o.seed);
  Rigid2D best;
  double best_score = -1.0;
  int needed = o.max_iterations;
  for (int it = 0; it < std::min(needed, o.max_iterations); ++it) {
    const int i = sampler.Draw(), j = sampler.Draw();
    if (i == j) continue;
    const Vec2 dq{q[j].x - q[i].x, q[j].y - q[i].y}, dd{d[j].x - d[i].x, d[j].y - d[i].y};
    const double lq = std::sqrt(Squared(dq)), ld = std::sqrt(Squared(dd));
    // A rigid map keeps distances: a pair that does not cannot be two inliers.
    if (lq < 2.0 * o.inlier_threshold || std::abs(lq - ld) > 2.0 * o.inlier_threshold) continue;
    Rigid2D h;
    h.theta = std::atan2(dq.x * dd.y - dq.y * dd.x, dq.x * dd.x + dq.y * dd.y);
    const Vec2 rq = Rotate(h.theta, {(q[i].x + q[j].x) / 2, (q[i].y + q[j].y) / 2});
    h.t = {(d[i].x + d[j].x) / 2 - rq.x, (d[i].y + d[j].y) / 2 - rq.y};
    double score = 0.0;
    for (int k = 0; k < n; ++k) {
      if (Residual2(h, q[k], d[k]) < thr2) score += w[k];
    }
    if (score > best_score) {
      best_score = score;
      best = h;
      // Adaptive stop: the (weighted) inlier fraction makes an all-inlier sample likely.
      const double f = std::min(1.0, score / total);
      if (f >= 1.0) {
        needed = it + 1;
      } else if (f > 0.0) {
        const double k = std::log(1.0 - o.confidence) / std::log(1.0 - f * f);
        needed = static_cast<int>(std::min<double>(o.max_iterations, std::ceil(k)));
      }
    }
  }
  if (best_score <= 0.0) {
    est.reason = "no consistent pair of matches among " + std::to_string(n);
    return est;
  }
  // Least-squares refinement on the inliers, re-selected after each fit.
  std::vector<int> inl;
  auto select = [&](const Rigid2D& r) {
    inl.clear();
    for (int k = 0; k < n; ++k) {
      if (Residual2(r, q[k], d[k]) < thr2) inl.push_back(k);
    }
  };
  select(best);
  for (int it = 0; it < o.refine_iterations && static_cast<int>(inl.size()) >= 2; ++it) {
    const Rigid2D r = FitRigid(q, d, w, inl);
    const std::vector<int> before = inl;
    select(r);
    best = r;
    if (inl == before) break;
  }
  est.inliers = static_cast<int>(inl.size());
  if (est.inliers < o.min_inliers) {
    est.reason = std::to_string(est.inliers) +
                 " inliers, fewer than min_inliers = " + std::to_string(o.min_inliers);
    return est;
  }
  double sum2 = 0.0;
  for (int k : inl) sum2 += Residual2(best, q[k], d[k]);
  est.residual_rms = std::sqrt(sum2 / est.inliers);
  est.inlier_indices = inl;
  est.database_from_query = best;

  // Query pose on the floor: its centre pixel lands at c + t in the database image.
  const double s = geometry.meters_per_pixel;
  const Vec2 tf = Rotate(floor_from_database.theta, best.t);
  est.floor_from_query = {floor_from_database.x + s * tf.x, floor_from_database.y + s * tf.y,
                          WrapAngle(floor_from_database.theta + best.theta)};

  // Covariance: sigma^2 (J^T J)^-1 over (t_x, t_y, theta) in pixels, then into floor units.
  const double dof = std::max(1, 2 * est.inliers - 3);
  const double sigma2 = std::max(sum2 / dof, 1e-4);  // never claim better than 0.01 px
  std::array<double, 9> jtj{};
  for (int k : inl) {
    const Vec2 p = Rotate(best.theta, q[k]);  // d residual / d theta = (-p.y, p.x)
    jtj[0] += 1;
    jtj[4] += 1;
    jtj[2] += -p.y;
    jtj[5] += p.x;
    jtj[8] += p.x * p.x + p.y * p.y;
  }
  jtj[6] = jtj[2];
  jtj[7] = jtj[5];
  std::array<double, 9> cov_px;
  if (!Invert3(jtj, &cov_px)) {
    est.reason = "degenerate inlier set (all inliers at one point)";
    est.inliers = 0;
    return est;
  }
  for (double& x : cov_px) x *= sigma2;
  // J_f = diag(s R(theta_d), 1).
  const double cr = std::cos(floor_from_database.theta), sr = std::sin(floor_from_database.theta);
  const double jf[9] = {s * cr, -s * sr, 0, s * sr, s * cr, 0, 0, 0, 1};
  std::array<double, 9> tmp{};
  for (int r = 0; r < 3; ++r)
    for (int col = 0; col < 3; ++col)
      for (int k = 0; k < 3; ++k) tmp[r * 3 + col] += jf[r * 3 + k] * cov_px[k * 3 + col];
  est.covariance.fill(0.0);
  for (int r = 0; r < 3; ++r)
    for (int col = 0; col < 3; ++col)
      for (int k = 0; k < 3; ++k) est.covariance[r * 3 + col] += tmp[r * 3 + k] * jf[col * 3 + k];
  est.success = true;
  return est;
}

std::vector<PointMatch> MatchesOf(const QueryResult& result,
                                  const std::vector<Keypoint>& query_keypoints,
                                  const std::vector<Keypoint>& database_keypoints) {
  std::vector<MatchPair> pairs = result.matches;
  std::sort(pairs.begin(), pairs.end(), [](const MatchPair& a, const MatchPair& b) {
    return a.query_keypoint != b.query_keypoint ? a.query_keypoint < b.query_keypoint
                                                : a.database_keypoint < b.database_keypoint;
  });
  std::vector<PointMatch> out;
  for (size_t i = 0; i < pairs.size();) {
    const MatchPair& p = pairs[i];
    double weight = 0.0;
    size_t j = i;
    for (; j < pairs.size() && pairs[j].query_keypoint == p.query_keypoint &&
           pairs[j].database_keypoint == p.database_keypoint;
         ++j) {
      weight += pairs[j].weight;
    }
    i = j;
    if (p.query_keypoint >= query_keypoints.size() ||
        p.database_keypoint >= database_keypoints.size()) {
      throw std::out_of_range("MatchesOf: keypoint id beyond the keypoints given");
    }
    if (!(weight > 0.0)) continue;
    const Keypoint& a = query_keypoints[p.query_keypoint];
    const Keypoint& b = database_keypoints[p.database_keypoint];
    out.push_back({{a.x, a.y}, {b.x, b.y}, weight});
  }
  return out;
}

PoseEstimate VerifyCandidate(const QueryResult& r, const BowVector& query, const MapAccess& map,
                             const ImageGeometry& geometry, const PoseOptions& options,
                             std::vector<Vec2>* inlier_pixels) {
  const auto matches = MatchesOf(r, query.source, map.keypoints(r.image));
  PoseEstimate est = EstimatePose(matches, map.pose(r.image), geometry, options);
  if (est.success && inlier_pixels != nullptr) {
    for (int i : est.inlier_indices) inlier_pixels->push_back(matches[i].query);
  }
  return est;
}

Localization VerifyCandidates(const std::vector<QueryResult>& results, const BowVector& query,
                              const MapAccess& map, const ImageGeometry& geometry,
                              const LocalizationOptions& o) {
  o.Check();
  Localization loc;
  if (query.source.empty()) {
    loc.reason = "the query image has no features";
    return loc;
  }
  if (results.empty()) {
    loc.reason = "no database image shares a word with the query";
    return loc;
  }
  std::string reasons;
  const size_t n = std::min(results.size(), static_cast<size_t>(o.candidates));
  for (size_t rank = 0; rank < n; ++rank) {
    const QueryResult& r = results[rank];
    std::string why = map.unusable ? map.unusable(r.image) : std::string();
    if (why.empty()) {
      PoseEstimate est = VerifyCandidate(r, query, map, geometry, o.pose, &loc.inlier_pixels);
      if (est.success) {
        loc.success = true;
        loc.image = r.image;
        loc.rank = static_cast<int>(rank);
        loc.score = r.score;
        loc.estimate = std::move(est);
        return loc;
      }
      why = est.reason;
    }
    if (rank < 3)
      reasons += (reasons.empty() ? "" : "; ") + ("image " + std::to_string(r.image) + ": " + why);
  }
  loc.reason = "none of " + std::to_string(n) + " candidates verified (" + reasons +
               (n > 3 ? "; ..." : "") + ")";
  return loc;
}

Localization Localize(const BowDatabase& database, const BowVector& query, const MapAccess& map,
                      const ImageGeometry& geometry, const LocalizationOptions& o) {
  o.Check();
  if (query.source.empty()) return VerifyCandidates({}, query, map, geometry, o);
  return VerifyCandidates(database.Query(query, static_cast<size_t>(o.candidates), true), query,
                          map, geometry, o);
}

}  // namespace gtbow
