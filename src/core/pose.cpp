#include "ground_texture_bow/core/pose.h"

#include "ground_texture_bow/core/enum_names.h"
#include "hamming_distance.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <limits>
#include <random>
#include <stdexcept>

namespace gtbow {

namespace {

Vec2 Rotate(double theta, Vec2 p) {
  const double c = std::cos(theta), s = std::sin(theta);
  return {c * p.x - s * p.y, s * p.x + c * p.y};
}

double Squared(Vec2 a) { return a.x * a.x + a.y * a.y; }

// Draws from `pool` with probability proportional to the weights (or uniformly).
class Sampler {
 public:
  Sampler(const std::vector<double>& w, const std::vector<int>& pool, uint64_t seed)
      : rng_(seed), pool_(pool) {
    cumulative_.reserve(pool.size());
    double sum = 0.0;
    for (int i : pool) cumulative_.push_back(sum += w[i]);
  }
  int Draw() {
    const double u = static_cast<double>(rng_() >> 11) * 0x1.0p-53 * cumulative_.back();
    const auto it = std::upper_bound(cumulative_.begin(), cumulative_.end(), u);
    return pool_[std::min<size_t>(it - cumulative_.begin(), cumulative_.size() - 1)];
  }

 private:
  std::mt19937_64 rng_;
  const std::vector<int>& pool_;
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

// The matches in centred coordinates, with their weights and orientation changes.
struct Problem {
  std::vector<Vec2> q, d;
  std::vector<double> w, rot;
  double thr2 = 0.0;
  double angle_tolerance = 0.0;  // 0: orientations not checked

  bool Inlier(const Rigid2D& h, int k) const {
    if (Residual2(h, q[k], d[k]) >= thr2) return false;
    return angle_tolerance <= 0.0 || !std::isfinite(rot[k]) ||
           std::abs(WrapAngle(rot[k] - h.theta)) <= angle_tolerance;
  }
};

struct Hypothesis {
  Rigid2D r;
  double score = -1.0;  // summed weight of its inliers; < 0: none found
};

// Two-point RANSAC over the matches in `pool`; hypotheses `accept` refuses are skipped.
Hypothesis Ransac(const Problem& p, const std::vector<int>& pool, const PoseOptions& o,
                  const std::function<bool(const Rigid2D&)>& accept) {
  Hypothesis best;
  if (pool.size() < 2) return best;
  double total = 0.0;
  for (int k : pool) total += p.w[k];
  Sampler sampler(p.w, pool, o.seed);
  const double thr = o.inlier_threshold;
  int needed = o.max_iterations;
  for (int it = 0; it < std::min(needed, o.max_iterations); ++it) {
    const int i = sampler.Draw(), j = sampler.Draw();
    if (i == j) continue;
    const Vec2 dq{p.q[j].x - p.q[i].x, p.q[j].y - p.q[i].y};
    const Vec2 dd{p.d[j].x - p.d[i].x, p.d[j].y - p.d[i].y};
    const double lq = std::sqrt(Squared(dq)), ld = std::sqrt(Squared(dd));
    // A rigid map keeps distances: a pair that does not cannot be two inliers.
    if (lq < 2.0 * thr || std::abs(lq - ld) > 2.0 * thr) continue;
    Rigid2D h;
    h.theta = std::atan2(dq.x * dd.y - dq.y * dd.x, dq.x * dd.x + dq.y * dd.y);
    const Vec2 rq = Rotate(h.theta, {(p.q[i].x + p.q[j].x) / 2, (p.q[i].y + p.q[j].y) / 2});
    h.t = {(p.d[i].x + p.d[j].x) / 2 - rq.x, (p.d[i].y + p.d[j].y) / 2 - rq.y};
    if (accept && !accept(h)) continue;
    double score = 0.0;
    for (int k : pool) {
      if (p.Inlier(h, k)) score += p.w[k];
    }
    if (score > best.score) {
      best = {h, score};
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
  return best;
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
  need(angle_tolerance >= 0.0 && angle_tolerance <= M_PI, "angle_tolerance must be in [0, pi]");
  need(min_inlier_fraction >= 0.0 && min_inlier_fraction <= 1.0,
       "min_inlier_fraction must be in [0, 1]");
  need(min_spread >= 0.0 && std::isfinite(min_spread), "min_spread must be >= 0");
  need(max_theta_sigma >= 0.0 && std::isfinite(max_theta_sigma), "max_theta_sigma must be >= 0");
  need(max_second_ratio >= 0.0 && std::isfinite(max_second_ratio), "max_second_ratio must be >= 0");
}

void LocalizationOptions::Check() const {
  if (candidates < 1) throw std::invalid_argument("localization: candidates must be >= 1");
  if (!(descriptor_ratio > 0.0 && descriptor_ratio <= 1.0)) {
    throw std::invalid_argument("localization: descriptor_ratio must be in (0, 1]");
  }
  if (!(max_conflict_ratio >= 0.0) || !std::isfinite(max_conflict_ratio)) {
    throw std::invalid_argument("localization: max_conflict_ratio must be >= 0");
  }
  if (!(consensus_distance > 0.0) || !(consensus_angle > 0.0) ||
      !std::isfinite(consensus_distance) || !std::isfinite(consensus_angle)) {
    throw std::invalid_argument("localization: consensus_distance and consensus_angle must be > 0");
  }
  if (!(guided_radius >= 0.0) || !std::isfinite(guided_radius) || !(guided_max_distance >= 0.0) ||
      !std::isfinite(guided_max_distance)) {
    throw std::invalid_argument("localization: guided_radius and guided_max_distance must be >= 0");
  }
  if (guided_repeat_check && !(guided_radius > 0.0)) {
    throw std::invalid_argument("localization: guided_repeat_check needs guided_radius > 0");
  }
  if (!(guided_repeat_ratio >= 0.0) || !std::isfinite(guided_repeat_ratio)) {
    throw std::invalid_argument("localization: guided_repeat_ratio must be >= 0");
  }
  if (!(plain_repeat_ratio >= 0.0) || !std::isfinite(plain_repeat_ratio)) {
    throw std::invalid_argument("localization: plain_repeat_ratio must be >= 0");
  }
  if (plain_repeat_below < 0) {
    throw std::invalid_argument("localization: plain_repeat_below must be >= 0");
  }
  if (plain_repeat_below > 0 && !guided_repeat_check) {
    throw std::invalid_argument("localization: plain_repeat_below needs guided_repeat_check");
  }
  if (guided_repeat_candidates < 1) {
    throw std::invalid_argument("localization: guided_repeat_candidates must be >= 1");
  }
  if (escalate_min_inliers < 0) {
    throw std::invalid_argument("localization: escalate_min_inliers must be >= 0");
  }
  if (guided_seed_inliers < 2) {
    throw std::invalid_argument("localization: guided_seed_inliers must be >= 2");
  }
  if (guided_radius > 0.0 && matches != MatchSource::kDescriptors) {
    throw std::invalid_argument("localization: guided_radius needs matches: descriptors");
  }
  if (guided_radius > 0.0 && guided_seed_inliers >= pose.min_inliers) {
    throw std::invalid_argument(
        "localization: guided_seed_inliers must be below min_inliers (a seed is a hypothesis "
        "short of min_inliers)");
  }
  pose.Check();
}

namespace {
constexpr EnumName<MatchSource> kMatchSources[] = {{"words", MatchSource::kWords},
                                                   {"descriptors", MatchSource::kDescriptors}};
}  // namespace

MatchSource ParseMatchSource(const std::string& name) {
  return ParseEnumName(name, "match source", kMatchSources);
}
std::string MatchSourceName(MatchSource source) { return EnumValueName(source, kMatchSources); }

PoseEstimate EstimatePose(const std::vector<PointMatch>& matches, const Pose2D& floor_from_database,
                          const ImageGeometry& geometry, const PoseOptions& o) {
  o.Check();
  PoseEstimate est;
  const int n = static_cast<int>(matches.size());
  est.matches = n;
  if (n < o.min_inliers) {
    est.reason =
        std::to_string(n) + " matches, fewer than min_inliers = " + std::to_string(o.min_inliers);
    return est;
  }
  const Vec2 c{(geometry.width - 1) / 2.0, (geometry.height - 1) / 2.0};
  Problem p;
  p.q.resize(n);
  p.d.resize(n);
  p.w.resize(n);
  p.rot.resize(n);
  p.thr2 = o.inlier_threshold * o.inlier_threshold;
  p.angle_tolerance = o.angle_tolerance;
  for (int i = 0; i < n; ++i) {
    const PointMatch& m = matches[i];
    if (!(m.weight > 0.0) || !std::isfinite(m.weight) || !std::isfinite(m.query.x) ||
        !std::isfinite(m.query.y) || !std::isfinite(m.database.x) || !std::isfinite(m.database.y)) {
      throw std::invalid_argument("EstimatePose: match " + std::to_string(i) +
                                  " has a non-finite coordinate or a non-positive weight");
    }
    p.q[i] = {m.query.x - c.x, m.query.y - c.y};
    p.d[i] = {m.database.x - c.x, m.database.y - c.y};
    p.w[i] = o.weighted ? m.weight : 1.0;
    p.rot[i] = m.rotation;
  }
  std::vector<int> all(n);
  for (int i = 0; i < n; ++i) all[i] = i;
  const Hypothesis first = Ransac(p, all, o, nullptr);
  if (first.score <= 0.0) {
    est.reason = "no consistent pair of matches among " + std::to_string(n);
    return est;
  }
  // Least-squares refinement on the inliers, re-selected after each fit.
  Rigid2D best = first.r;
  std::vector<int> inl;
  auto select = [&](const Rigid2D& r) {
    inl.clear();
    for (int k = 0; k < n; ++k) {
      if (p.Inlier(r, k)) inl.push_back(k);
    }
  };
  select(best);
  for (int it = 0; it < o.refine_iterations && static_cast<int>(inl.size()) >= 2; ++it) {
    const Rigid2D r = FitRigid(p.q, p.d, p.w, inl);
    const std::vector<int> before = inl;
    select(r);
    best = r;
    if (inl == before) break;
  }
  est.inliers = static_cast<int>(inl.size());
  est.database_from_query = best;

  // The evidence: spread of the inliers, agreement of their orientations.
  if (!inl.empty()) {
    double mx = 0, my = 0;
    for (int k : inl) mx += p.q[k].x, my += p.q[k].y;
    mx /= est.inliers;
    my /= est.inliers;
    double sxx = 0, syy = 0, sxy = 0;
    for (int k : inl) {
      const double dx = p.q[k].x - mx, dy = p.q[k].y - my;
      sxx += dx * dx;
      syy += dy * dy;
      sxy += dx * dy;
    }
    sxx /= est.inliers;
    syy /= est.inliers;
    sxy /= est.inliers;
    const double half = (sxx + syy) / 2,
                 root = std::sqrt((sxx - syy) * (sxx - syy) / 4 + sxy * sxy);
    est.spread = std::sqrt(std::max(0.0, half - root));
    int with = 0, agree = 0;
    for (int k : inl) {
      if (!std::isfinite(p.rot[k])) continue;
      ++with;
      agree += std::abs(WrapAngle(p.rot[k] - best.theta)) <= 15.0 * M_PI / 180.0 ? 1 : 0;
    }
    est.angle_agreement = with > 0 ? static_cast<double>(agree) / with : 1.0;
  }
  if (est.inliers < o.min_inliers) {
    est.reason = std::to_string(est.inliers) +
                 " inliers, fewer than min_inliers = " + std::to_string(o.min_inliers);
    return est;
  }
  double sum2 = 0.0;
  for (int k : inl) sum2 += Residual2(best, p.q[k], p.d[k]);
  est.residual_rms = std::sqrt(sum2 / est.inliers);

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
    const Vec2 r = Rotate(best.theta, p.q[k]);  // d residual / d theta = (-r.y, r.x)
    jtj[0] += 1;
    jtj[4] += 1;
    jtj[2] += -r.y;
    jtj[5] += r.x;
    jtj[8] += r.x * r.x + r.y * r.y;
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
  est.theta_sigma = std::sqrt(std::max(0.0, cov_px[8]));
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

  // A second hypothesis among the matches the best one leaves out, distinct from it: some image
  // corner lands more than three inlier thresholds away.
  if (o.max_second_ratio > 0.0) {
    std::vector<int> rest;
    size_t next = 0;
    for (int k = 0; k < n; ++k) {
      if (next < inl.size() && inl[next] == k) {
        ++next;
        continue;
      }
      rest.push_back(k);
    }
    const double hw = geometry.width / 2.0, hh = geometry.height / 2.0;
    const double far2 = 9.0 * p.thr2;
    auto distinct = [&](const Rigid2D& h) {
      for (const Vec2 corner : {Vec2{-hw, -hh}, Vec2{hw, -hh}, Vec2{hw, hh}, Vec2{-hw, hh}}) {
        const Vec2 a = Rotate(h.theta, corner), b = Rotate(best.theta, corner);
        if (Squared({a.x + h.t.x - b.x - best.t.x, a.y + h.t.y - b.y - best.t.y}) > far2)
          return true;
      }
      return false;
    };
    const Hypothesis second = Ransac(p, rest, o, distinct);
    if (second.score > 0.0) {
      for (int k : rest) est.second_inliers += p.Inlier(second.r, k) ? 1 : 0;
    }
  }

  // The checks (issue 15), each off at 0.
  char why[160] = "";
  if (est.inliers < o.min_inlier_fraction * n) {
    std::snprintf(why, sizeof(why), "%d inliers of %d matches, fewer than min_inlier_fraction %g",
                  est.inliers, n, o.min_inlier_fraction);
  } else if (est.spread < o.min_spread) {
    std::snprintf(why, sizeof(why), "inliers spread over %.1f px, less than min_spread %g",
                  est.spread, o.min_spread);
  } else if (o.max_theta_sigma > 0.0 && est.theta_sigma > o.max_theta_sigma) {
    std::snprintf(why, sizeof(why), "rotation uncertain: sigma %.2f deg above max_theta_sigma %.2f",
                  est.theta_sigma * 180.0 / M_PI, o.max_theta_sigma * 180.0 / M_PI);
  } else if (o.max_second_ratio > 0.0 && est.second_inliers >= o.max_second_ratio * est.inliers) {
    std::snprintf(why, sizeof(why),
                  "ambiguous: a second pose has %d inliers against %d (max_second_ratio %g)",
                  est.second_inliers, est.inliers, o.max_second_ratio);
  }
  if (why[0] != '\0') {
    est.reason = why;
    return est;
  }
  est.inlier_indices = inl;
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
    out.push_back({{a.x, a.y}, {b.x, b.y}, weight, WrapAngle(b.angle - a.angle)});
  }
  return out;
}

namespace {

// out[i * nd + j] = Hamming distance of query row i and database row j (rows of a multiple of
// 8 bytes), through the vector-popcount kernel the word search uses.
void HammingTable(const cv::Mat& q, const cv::Mat& d, uint32_t* out) {
  std::vector<uint64_t> blocks, row(static_cast<size_t>(q.cols / 8));
  const cv::Mat rows = d.isContinuous() ? d : d.clone();  // packed from one buffer
  PackBinaryRows(rows.ptr<uint8_t>(), rows.rows, rows.cols, &blocks);
  for (int i = 0; i < q.rows; ++i) {
    std::memcpy(row.data(), q.ptr(i), static_cast<size_t>(q.cols));
    HammingAll(row.data(), blocks.data(), d.rows, q.cols / 8,
               out + static_cast<size_t>(i) * d.rows);
  }
}

// Nearest and second nearest of each row of the nq x nd `table`, and each column's nearest row.
template <typename T>
void NearestInTable(const T* table, int nq, int nd, std::vector<double>* q_best,
                    std::vector<double>* q_second, std::vector<int>* q_arg,
                    std::vector<int>* d_arg) {
  std::vector<T> d_best(static_cast<size_t>(nd), std::numeric_limits<T>::max());
  for (int i = 0; i < nq; ++i) {
    const T* r = table + static_cast<size_t>(i) * nd;
    T b1 = std::numeric_limits<T>::max(), b2 = b1;
    int a = -1;
    for (int j = 0; j < nd; ++j) {
      const T x = r[j];
      if (x < b1) {
        b2 = b1;
        b1 = x;
        a = j;
      } else if (x < b2) {
        b2 = x;
      }
      if (x < d_best[j]) {
        d_best[j] = x;
        (*d_arg)[j] = i;
      }
    }
    (*q_best)[i] = static_cast<double>(b1);
    (*q_second)[i] = b2 == std::numeric_limits<T>::max() ? std::numeric_limits<double>::infinity()
                                                         : static_cast<double>(b2);
    (*q_arg)[i] = a;
  }
}

}  // namespace

namespace {
// The distance of row i of `a` to row j of `b` (same kind): Hamming bits for CV_8U, L2 for
// CV_32F.
double RowDistance(const cv::Mat& a, int i, const cv::Mat& b, int j) {
  if (a.type() == CV_8U) return HammingDistance(a.ptr<uint8_t>(i), b.ptr<uint8_t>(j), a.cols);
  const float* x = a.ptr<float>(i);
  const float* y = b.ptr<float>(j);
  double sum = 0.0;
  for (int k = 0; k < a.cols; ++k) sum += (x[k] - y[k]) * (x[k] - y[k]);
  return std::sqrt(sum);
}
}  // namespace

std::vector<PointMatch> DescriptorMatches(const std::vector<Keypoint>& qk, const cv::Mat& qd,
                                          const std::vector<Keypoint>& dk, const cv::Mat& dd,
                                          double ratio) {
  const int nq = qd.rows, nd = dd.rows;
  if (nq != static_cast<int>(qk.size()) || nd != static_cast<int>(dk.size())) {
    throw std::invalid_argument("DescriptorMatches: " + std::to_string(qk.size()) + " and " +
                                std::to_string(dk.size()) + " keypoints but " + std::to_string(nq) +
                                " and " + std::to_string(nd) + " descriptor rows");
  }
  std::vector<PointMatch> out;
  if (nq == 0 || nd == 0) return out;
  if (qd.type() != dd.type() || qd.cols != dd.cols || (qd.type() != CV_8U && qd.type() != CV_32F)) {
    throw std::invalid_argument("DescriptorMatches: the two images' descriptors differ in kind");
  }
  const bool binary = qd.type() == CV_8U && qd.cols % 8 == 0;
  // The whole n_q x n_d table of distances, then each row's two nearest and each column's
  // nearest.
  std::vector<double> q_best(nq), q_second(nq);
  std::vector<int> q_arg(nq, -1), d_arg(nd, -1);
  if (binary) {
    std::vector<uint32_t> table(static_cast<size_t>(nq) * nd);
    HammingTable(qd, dd, table.data());
    NearestInTable(table.data(), nq, nd, &q_best, &q_second, &q_arg, &d_arg);
  } else {
    std::vector<double> table(static_cast<size_t>(nq) * nd);
    for (int i = 0; i < nq; ++i) {
      for (int j = 0; j < nd; ++j) {
        table[static_cast<size_t>(i) * nd + j] = RowDistance(qd, i, dd, j);
      }
    }
    NearestInTable(table.data(), nq, nd, &q_best, &q_second, &q_arg, &d_arg);
  }
  for (int i = 0; i < nq; ++i) {
    const int j = q_arg[i];
    if (j < 0 || d_arg[j] != i || !(q_best[i] < ratio * q_second[i])) continue;
    const Keypoint& a = qk[i];
    const Keypoint& b = dk[j];
    out.push_back({{a.x, a.y}, {b.x, b.y}, 1.0, WrapAngle(b.angle - a.angle)});
  }
  return out;
}

std::vector<PointMatch> GuidedMatches(const std::vector<Keypoint>& qk, const cv::Mat& qd,
                                      const std::vector<Keypoint>& dk, const cv::Mat& dd,
                                      const Rigid2D& h, const ImageGeometry& geometry,
                                      double radius, double max_distance) {
  if (qd.rows != static_cast<int>(qk.size()) || dd.rows != static_cast<int>(dk.size())) {
    throw std::invalid_argument("GuidedMatches: keypoints and descriptor rows differ in number");
  }
  std::vector<PointMatch> out;
  if (qk.empty() || dk.empty()) return out;
  if (qd.type() != dd.type() || qd.cols != dd.cols || (qd.type() != CV_8U && qd.type() != CV_32F)) {
    throw std::invalid_argument("GuidedMatches: the two images' descriptors differ in kind");
  }
  const Vec2 c{(geometry.width - 1) / 2.0, (geometry.height - 1) / 2.0};
  const double r2 = radius * radius;
  // Each database keypoint keeps the nearest query keypoint that chose it.
  std::vector<int> from(dk.size(), -1);
  std::vector<double> best(dk.size(), std::numeric_limits<double>::infinity());
  for (size_t i = 0; i < qk.size(); ++i) {
    const Vec2 at = Rotate(h.theta, {qk[i].x - c.x, qk[i].y - c.y});
    const double px = at.x + h.t.x + c.x, py = at.y + h.t.y + c.y;
    int arg = -1;
    double nearest = std::numeric_limits<double>::infinity();
    for (size_t j = 0; j < dk.size(); ++j) {
      const double dx = dk[j].x - px, dy = dk[j].y - py;
      if (dx * dx + dy * dy > r2) continue;
      const double d = RowDistance(qd, static_cast<int>(i), dd, static_cast<int>(j));
      if (d < nearest) {
        nearest = d;
        arg = static_cast<int>(j);
      }
    }
    if (arg < 0 || nearest > max_distance || nearest >= best[arg]) continue;
    best[arg] = nearest;
    from[arg] = static_cast<int>(i);
  }
  for (size_t j = 0; j < dk.size(); ++j) {
    if (from[j] < 0) continue;
    const Keypoint& a = qk[from[j]];
    const Keypoint& b = dk[j];
    out.push_back({{a.x, a.y}, {b.x, b.y}, 1.0, WrapAngle(b.angle - a.angle)});
  }
  return out;
}

namespace {

// Whether a failed estimate is a seed for guided matching: a hypothesis short of inliers (not
// one refused by a check: clustered inliers are a floor's local repeat).
bool GuidedSeed(const PoseEstimate& e, const LocalizationOptions& o) {
  return o.guided_radius > 0.0 && !e.success && e.inliers >= o.guided_seed_inliers &&
         e.inliers < o.pose.min_inliers;
}

// Verifies candidate `r` again from guided matches through the seed's hypothesis.
PoseEstimate VerifyGuided(const QueryResult& r, const BowVector& query, const MapAccess& map,
                          const ImageGeometry& geometry, const LocalizationOptions& o,
                          const PoseEstimate& seed, std::vector<Vec2>* inlier_pixels) {
  const std::vector<PointMatch> matches = GuidedMatches(
      query.source, query.source_descriptors, map.keypoints(r.image), map.descriptors(r.image),
      seed.database_from_query, geometry, o.guided_radius, o.guided_max_distance);
  PoseEstimate est = EstimatePose(matches, map.pose(r.image), geometry, o.pose);
  if (!est.success) {
    est.reason = "guided: " + est.reason + " (seed: " + seed.reason + ")";
    return est;
  }
  if (inlier_pixels != nullptr) {
    for (int i : est.inlier_indices) inlier_pixels->push_back(matches[i].query);
  }
  return est;
}

// The copies of map image `image`: where it verifies (plainly, then guided) among its first
// guided_repeat_candidates candidates when queried against its own map, beyond the consensus
// distance or angle of its own pose.
std::vector<RepeatCache::Copy> FindCopies(uint32_t image, const MapAccess& map,
                                          const ImageGeometry& geometry,
                                          const LocalizationOptions& o) {
  std::vector<RepeatCache::Copy> copies;
  const BowVector self = map.query_of(image);
  if (self.source.empty()) return copies;
  const std::vector<QueryResult> results =
      map.retrieve(self, image, static_cast<size_t>(o.guided_repeat_candidates));
  const Pose2D own = map.pose(image);
  const size_t n = std::min(results.size(), static_cast<size_t>(o.guided_repeat_candidates));
  for (size_t k = 0; k < n; ++k) {
    const QueryResult& r = results[k];
    if (r.image == image || (map.unusable && !map.unusable(r.image).empty())) continue;
    PoseEstimate e = VerifyCandidate(r, self, map, geometry, o);
    if (!e.success && GuidedSeed(e, o)) e = VerifyGuided(r, self, map, geometry, o, e, nullptr);
    if (!e.success) continue;
    const Pose2D& p = e.floor_from_query;
    if (std::hypot(p.x - own.x, p.y - own.y) <= o.consensus_distance &&
        std::abs(WrapAngle(p.theta - own.theta)) <= o.consensus_angle)
      continue;
    std::vector<int>().swap(e.inlier_indices);  // kept: only the pose and the counts
    copies.push_back({r.image, std::move(e)});
  }
  return copies;
}

// The repeat check (LocalizationOptions::guided_repeat_check) of `query`'s guided estimate `est`
// with map image `image`: empty when the image has no copy (FindCopies) or, with `ratio` > 0,
// when the query holds fewer than `ratio` times its inliers at each copy; else why not.
// A plain estimate (`plain`, the check of LocalizationOptions::plain_repeat_below) contests the
// copy with its own guided matches, counted as the copy's are.
std::string RepeatsElsewhere(const BowVector& query, const PoseEstimate& est, uint32_t image,
                             const MapAccess& map, const ImageGeometry& geometry,
                             const LocalizationOptions& o, double ratio, bool plain) {
  if (!map.query_of || !map.retrieve) {
    throw std::invalid_argument(
        "guided_repeat_check (and plain_repeat_below): the map gives no query of its own images "
        "(MapAccess::query_of, retrieve)");
  }
  // The keyframe's copies do not depend on the query: kept by the map's cache when it has one.
  std::shared_ptr<const std::vector<RepeatCache::Copy>> copies =
      map.repeats != nullptr
          ? map.repeats->Get(image, [&] { return FindCopies(image, map, geometry, o); })
          : std::make_shared<const std::vector<RepeatCache::Copy>>(
                FindCopies(image, map, geometry, o));
  const Pose2D own = map.pose(image);
  // The query's inliers at the keyframe, counted as at a copy: a guided pose's own; a plain
  // pose's from guided matching through its hypothesis, at the first copy found. Should that
  // give no pose (0 inliers), any copy refuses: the check fails safe.
  int held = plain ? -1 : est.inliers;
  for (const RepeatCache::Copy& copy : *copies) {
    const PoseEstimate& e = copy.estimate;
    const Pose2D& p = e.floor_from_query;
    const double apart = std::hypot(p.x - own.x, p.y - own.y);
    const double turned = std::abs(WrapAngle(p.theta - own.theta));
    char why[300];
    std::snprintf(why, sizeof(why),
                  "keyframe %u repeats elsewhere: it verifies with keyframe %u (%d inliers) "
                  "%.1f mm and %.1f degrees from its own pose",
                  image, copy.image, e.inliers, 1000.0 * apart, turned * 180.0 / M_PI);
    if (ratio > 0.0) {
      if (held < 0) {
        held =
            EstimatePose(GuidedMatches(query.source, query.source_descriptors, map.keypoints(image),
                                       map.descriptors(image), est.database_from_query, geometry,
                                       o.guided_radius, o.guided_max_distance),
                         own, geometry, o.pose)
                .inliers;
      }
      // The query matched at the copy through the same hypothesis (image -> copy after
      // query -> image): a query whose place is the image's holds fewer inliers there.
      const Rigid2D& a = est.database_from_query;  // image from query
      const Rigid2D& b = e.database_from_query;    // copy from image
      const double c = std::cos(b.theta), s = std::sin(b.theta);
      const Rigid2D copy_from_query{WrapAngle(a.theta + b.theta),
                                    {c * a.t.x - s * a.t.y + b.t.x, s * a.t.x + c * a.t.y + b.t.y}};
      const std::vector<PointMatch> there =
          GuidedMatches(query.source, query.source_descriptors, map.keypoints(copy.image),
                        map.descriptors(copy.image), copy_from_query, geometry, o.guided_radius,
                        o.guided_max_distance);
      const PoseEstimate at_copy = EstimatePose(there, map.pose(copy.image), geometry, o.pose);
      if (at_copy.inliers < ratio * held) continue;
      const size_t len = std::strlen(why);
      std::snprintf(why + len, sizeof(why) - len,
                    "; the query holds %d inliers at the copy against %d (%s %g)", at_copy.inliers,
                    held, plain ? "plain_repeat_ratio" : "guided_repeat_ratio", ratio);
    }
    return why;
  }
  return std::string();
}

// `options` without guided matching of the query (the repeat checks keep their own).
LocalizationOptions WithoutGuidedMatching(const LocalizationOptions& options) {
  LocalizationOptions o = options;
  o.guided = false;
  return o;
}

// The repeat check of a query's best plain pose (LocalizationOptions::plain_repeat_below), in
// `out` (verified or not; consensus applied): empty when it does not apply or finds no copy,
// else why the place is ambiguous.
std::string PlainRepeat(const std::vector<QueryResult>& results, const BowVector& query,
                        const std::vector<PoseEstimate>& out, const MapAccess& map,
                        const ImageGeometry& geometry, const LocalizationOptions& o) {
  if (o.plain_repeat_below <= 0) return std::string();
  int best = -1;
  for (size_t k = 0; k < out.size(); ++k) {
    if (out[k].success && (best < 0 || out[k].inliers > out[best].inliers))
      best = static_cast<int>(k);
  }
  if (best < 0 || out[best].inliers >= o.plain_repeat_below) return std::string();
  return RepeatsElsewhere(query, out[best], results[best].image, map, geometry, o,
                          o.plain_repeat_ratio, true);
}

}  // namespace

LocalizationOptions CombinedViewOptions(const LocalizationOptions& options) {
  return options.guided_combined ? options : WithoutGuidedMatching(options);
}

LocalizationOptions FirstPassOptions(const LocalizationOptions& options) {
  return WithoutGuidedMatching(options);
}

EscalationBackoff::EscalationBackoff(int max_skip) : max_skip_(max_skip) {
  if (max_skip < 0) throw std::invalid_argument("EscalationBackoff: max_skip must be >= 0");
}

bool EscalationBackoff::TryFirstPass() {
  if (left_ == 0) return true;
  --left_;
  ++skipped_;
  return false;
}

void EscalationBackoff::Record(bool stood) {
  if (stood) {
    failures_ = 0;
    return;
  }
  failures_ = std::min(failures_ + 1, 30);
  left_ = static_cast<int>(std::min<int64_t>(max_skip_, (int64_t{1} << failures_) - 1));
}

Localization EscalatedFix(bool escalate, const LocalizationOptions& options,
                          const std::function<Localization()>& first,
                          const std::function<Localization()>& full, bool* escalated,
                          EscalationBackoff* backoff) {
  if (escalated != nullptr) *escalated = false;
  if (escalate && (backoff == nullptr || backoff->TryFirstPass())) {
    Localization fix = first();
    const bool stands = fix.success && fix.estimate.inliers >= options.escalate_min_inliers;
    if (backoff != nullptr) backoff->Record(stands);
    if (stands) return fix;
  }
  if (escalated != nullptr) *escalated = escalate;
  return full();
}

std::shared_ptr<const std::vector<RepeatCache::Copy>> RepeatCache::Get(
    uint32_t image, const std::function<std::vector<Copy>()>& find) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = copies_.find(image);
    if (it != copies_.end()) return it->second;
  }
  auto found = std::make_shared<const std::vector<Copy>>(find());  // outside the lock: slow
  std::lock_guard<std::mutex> lock(mutex_);
  return copies_.emplace(image, std::move(found)).first->second;
}

void RepeatCache::Clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  copies_.clear();
}

size_t RepeatCache::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return copies_.size();
}

PoseEstimate VerifyCandidate(const QueryResult& r, const BowVector& query, const MapAccess& map,
                             const ImageGeometry& geometry, const LocalizationOptions& options,
                             std::vector<Vec2>* inlier_pixels) {
  std::vector<PointMatch> matches;
  if (options.matches == MatchSource::kDescriptors) {
    if (!map.descriptors) {
      throw std::invalid_argument("VerifyCandidate: descriptor matching without map descriptors");
    }
    matches = DescriptorMatches(query.source, query.source_descriptors, map.keypoints(r.image),
                                map.descriptors(r.image), options.descriptor_ratio);
  } else {
    matches = MatchesOf(r, query.source, map.keypoints(r.image));
  }
  PoseEstimate est = EstimatePose(matches, map.pose(r.image), geometry, options.pose);
  if (est.success && inlier_pixels != nullptr) {
    for (int i : est.inlier_indices) inlier_pixels->push_back(matches[i].query);
  }
  return est;
}

void ResolveConflicts(const std::vector<std::optional<Pose2D>>& poses,
                      std::vector<PoseEstimate>* estimates, const LocalizationOptions& o) {
  if (o.max_conflict_ratio <= 0.0) return;
  std::vector<PoseEstimate>& e = *estimates;
  int best = -1;
  for (size_t k = 0; k < e.size(); ++k) {
    if (e[k].success && poses[k] && (best < 0 || e[k].inliers > e[best].inliers))
      best = static_cast<int>(k);
  }
  if (best < 0) return;
  const Pose2D& b = *poses[best];
  auto agrees = [&](const Pose2D& p) {
    return std::hypot(p.x - b.x, p.y - b.y) <= o.consensus_distance &&
           std::abs(WrapAngle(p.theta - b.theta)) <= o.consensus_angle;
  };
  int strongest = -1;  // the strongest disagreeing pose
  for (size_t k = 0; k < e.size(); ++k) {
    if (!e[k].success || !poses[k] || agrees(*poses[k])) continue;
    if (strongest < 0 || e[k].inliers > e[strongest].inliers) strongest = static_cast<int>(k);
  }
  if (strongest < 0) return;
  const Pose2D& s = *poses[strongest];
  const double apart = std::hypot(s.x - b.x, s.y - b.y);
  const bool ambiguous = e[strongest].inliers >= o.max_conflict_ratio * e[best].inliers;
  char why[200];
  for (size_t k = 0; k < e.size(); ++k) {
    if (!e[k].success || !poses[k]) continue;
    const bool conflicting = !agrees(*poses[k]);
    if (!conflicting && !ambiguous) continue;
    if (ambiguous) {
      std::snprintf(why, sizeof(why),
                    "ambiguous place: candidates %d and %d verified with %d and %d inliers at "
                    "poses %.1f mm apart (max_conflict_ratio %g)",
                    best + 1, strongest + 1, e[best].inliers, e[strongest].inliers, 1000.0 * apart,
                    o.max_conflict_ratio);
    } else {
      std::snprintf(why, sizeof(why),
                    "disagrees with candidate %d (%d inliers against %d, %.1f mm apart)", best + 1,
                    e[best].inliers, e[k].inliers,
                    1000.0 * std::hypot(poses[k]->x - b.x, poses[k]->y - b.y));
    }
    e[k].success = false;
    e[k].reason = why;
    e[k].inlier_indices.clear();
  }
}

std::vector<PoseEstimate> VerifyEach(const std::vector<QueryResult>& results,
                                     const BowVector& query, const MapAccess& map,
                                     const ImageGeometry& geometry, const LocalizationOptions& o,
                                     std::vector<std::vector<Vec2>>* inlier_pixels) {
  o.Check();
  const size_t n = std::min(results.size(), static_cast<size_t>(o.candidates));
  std::vector<PoseEstimate> out(n);
  std::vector<std::optional<Pose2D>> poses(n);
  if (inlier_pixels != nullptr) inlier_pixels->assign(n, {});
  for (size_t k = 0; k < n; ++k) {
    const std::string why = map.unusable ? map.unusable(results[k].image) : std::string();
    if (!why.empty()) {
      out[k].reason = why;
      continue;
    }
    out[k] = VerifyCandidate(results[k], query, map, geometry, o,
                             inlier_pixels != nullptr ? &(*inlier_pixels)[k] : nullptr);
    if (out[k].success) poses[k] = out[k].floor_from_query;
  }
  ResolveConflicts(poses, &out, o);
  // The repeat check of the best plain pose: a copy refuses every pose of the query.
  const std::string plain_repeat = PlainRepeat(results, query, out, map, geometry, o);
  for (size_t k = 0; k < n && !plain_repeat.empty(); ++k) {
    if (!out[k].success) continue;
    out[k].success = false;
    out[k].reason = "repeat: " + plain_repeat;
    out[k].inlier_indices.clear();
  }
  // Guided matching, when no candidate verified and none was refused by the consensus (or the
  // repeat check).
  bool any = false, refused = false;
  for (size_t k = 0; k < n; ++k) {
    any = any || out[k].success;
    refused = refused || (poses[k] && !out[k].success);
  }
  if (o.guided && o.guided_radius > 0.0 && !any && !refused) {
    std::vector<char> guided(n, 0);
    std::string repeat;  // the repeat check's finding: the place is ambiguous
    for (size_t k = 0; k < n; ++k) {
      if (!GuidedSeed(out[k], o)) continue;
      out[k] = VerifyGuided(results[k], query, map, geometry, o, out[k],
                            inlier_pixels != nullptr ? &(*inlier_pixels)[k] : nullptr);
      if (!out[k].success) continue;
      poses[k] = out[k].floor_from_query;
      guided[k] = 1;
      if (o.guided_repeat_check && repeat.empty()) {
        repeat = RepeatsElsewhere(query, out[k], results[k].image, map, geometry, o,
                                  o.guided_repeat_ratio, false);
      }
    }
    // One guided keyframe that repeats elsewhere makes every guided pose of the query doubtful:
    // refusing that one alone would leave its copy's pose standing (seen on the held-out photos,
    // a sand floor with a copy turned 180 degrees).
    for (size_t k = 0; k < n && !repeat.empty(); ++k) {
      if (!guided[k]) continue;
      out[k].success = false;
      out[k].reason = "guided: " + repeat;
      out[k].inlier_indices.clear();
      poses[k].reset();
    }
    ResolveConflicts(poses, &out, o);
  }
  if (inlier_pixels != nullptr) {
    for (size_t k = 0; k < n; ++k) {
      if (!out[k].success) (*inlier_pixels)[k].clear();
    }
  }
  return out;
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
  const size_t n = std::min(results.size(), static_cast<size_t>(o.candidates));
  auto answer = [&](size_t rank, PoseEstimate est) {
    loc.success = true;
    loc.image = results[rank].image;
    loc.rank = static_cast<int>(rank);
    loc.score = results[rank].score;
    loc.estimate = std::move(est);
    return loc;
  };
  std::string reasons;
  auto note = [&](size_t rank, const std::string& why) {
    if (rank < 3) {
      reasons += (reasons.empty() ? "" : "; ") +
                 ("image " + std::to_string(results[rank].image) + ": " + why);
    }
  };
  if (o.max_conflict_ratio > 0.0) {
    std::vector<std::vector<Vec2>> pixels;
    std::vector<PoseEstimate> each = VerifyEach(results, query, map, geometry, o, &pixels);
    int best = -1;
    for (size_t k = 0; k < each.size(); ++k) {
      if (each[k].success && (best < 0 || each[k].inliers > each[best].inliers))
        best = static_cast<int>(k);
    }
    if (best >= 0) {
      loc.inlier_pixels = std::move(pixels[best]);
      return answer(static_cast<size_t>(best), std::move(each[best]));
    }
    for (size_t k = 0; k < each.size(); ++k) note(k, each[k].reason);
  } else {
    std::vector<PoseEstimate> seeds(n);
    bool ambiguous = false;  // the repeat check refused the first verified pose
    for (size_t rank = 0; rank < n && !ambiguous; ++rank) {
      const QueryResult& r = results[rank];
      std::string why = map.unusable ? map.unusable(r.image) : std::string();
      if (why.empty()) {
        PoseEstimate est = VerifyCandidate(r, query, map, geometry, o, &loc.inlier_pixels);
        if (est.success) {
          const std::string repeat = PlainRepeat({r}, query, {est}, map, geometry, o);
          if (repeat.empty()) return answer(rank, std::move(est));
          // The place is ambiguous: no pose for this query, plain or guided. Without consensus
          // the first verified pose is the one checked (VerifyEach checks the best of all).
          loc.inlier_pixels.clear();
          reasons += (reasons.empty() ? "" : "; ") +
                     ("image " + std::to_string(r.image) + ": repeat: " + repeat);
          ambiguous = true;
          continue;
        }
        why = est.reason;
        seeds[rank] = std::move(est);
      }
      note(rank, why);
    }
    // Guided matching, in rank order, when none verified.
    for (size_t rank = 0; rank < n && o.guided && !ambiguous; ++rank) {
      if (!GuidedSeed(seeds[rank], o)) continue;
      PoseEstimate est =
          VerifyGuided(results[rank], query, map, geometry, o, seeds[rank], &loc.inlier_pixels);
      if (!est.success) continue;
      const std::string repeat = o.guided_repeat_check
                                     ? RepeatsElsewhere(query, est, results[rank].image, map,
                                                        geometry, o, o.guided_repeat_ratio, false)
                                     : std::string();
      if (repeat.empty()) return answer(rank, std::move(est));
      loc.inlier_pixels.clear();  // no guided pose for this query (as VerifyEach)
      reasons += "; guided: " + repeat;
      break;
    }
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
