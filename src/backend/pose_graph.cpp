#include "ground_texture_bow/backend/pose_graph.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <stdexcept>

#include <ceres/ceres.h>
#include <Eigen/Cholesky>
#include <Eigen/Core>

namespace gtbow {
namespace backend {

namespace {

bool Finite(const Pose2D& p) {
  return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.theta);
}

Eigen::Matrix3d ToMatrix(const std::array<double, 9>& c) {
  Eigen::Matrix3d m;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m(i, j) = c[3 * i + j];
  }
  return m;
}

// (-pi, pi] for doubles and Jets alike.
template <typename T>
T Wrap(const T& a) {
  using std::floor;
  const T two_pi(2.0 * M_PI);
  return a - two_pi * floor((a + T(M_PI)) / two_pi);
}

// The relative pose b in a's frame against a measurement, whitened by sqrt_info (upper
// triangular: r^T r = e^T Sigma^-1 e).
struct RelativePoseCost {
  RelativePoseCost(const Pose2D& measured, const Eigen::Matrix3d& sqrt_info)
      : m(measured), l(sqrt_info) {}

  template <typename T>
  bool operator()(const T* a, const T* b, T* residual) const {
    using std::cos;
    using std::sin;
    const T dx = b[0] - a[0], dy = b[1] - a[1];
    const T c = cos(a[2]), s = sin(a[2]);
    T e[3];
    e[0] = c * dx + s * dy - T(m.x);
    e[1] = -s * dx + c * dy - T(m.y);
    e[2] = Wrap(T(b[2] - a[2] - T(m.theta)));
    for (int i = 0; i < 3; ++i) {
      residual[i] = T(l(i, 0)) * e[0] + T(l(i, 1)) * e[1] + T(l(i, 2)) * e[2];
    }
    return true;
  }

  Pose2D m;
  Eigen::Matrix3d l;
};

// A pose against a measurement of it (a fix), whitened by sqrt_info.
struct PoseCost {
  PoseCost(const Pose2D& measured, const Eigen::Matrix3d& sqrt_info) : m(measured), l(sqrt_info) {}

  template <typename T>
  bool operator()(const T* a, T* residual) const {
    T e[3];
    e[0] = a[0] - T(m.x);
    e[1] = a[1] - T(m.y);
    e[2] = Wrap(T(a[2] - T(m.theta)));
    for (int i = 0; i < 3; ++i) {
      residual[i] = T(l(i, 0)) * e[0] + T(l(i, 1)) * e[1] + T(l(i, 2)) * e[2];
    }
    return true;
  }

  Pose2D m;
  Eigen::Matrix3d l;
};

// Whitening matrix of a covariance, or false when it is not symmetric positive definite.
bool SqrtInformation(const Eigen::Matrix3d& cov, Eigen::Matrix3d* out) {
  if (!cov.allFinite() || (cov - cov.transpose()).cwiseAbs().maxCoeff() >
                              1e-9 * std::max(1e-30, cov.cwiseAbs().maxCoeff())) {
    return false;
  }
  Eigen::LLT<Eigen::Matrix3d> llt(cov);
  if (llt.info() != Eigen::Success) return false;
  // cov = L L^T, so Sigma^-1 = L^-T L^-1 and r = L^-1 e has r^T r = e^T Sigma^-1 e.
  *out = llt.matrixL().solve(Eigen::Matrix3d::Identity());
  return out->allFinite();
}

}  // namespace

void PoseGraphOptions::Check() const {
  auto need = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument(what);
  };
  auto positive = [&](double v, const char* name) {
    need(std::isfinite(v) && v > 0, std::string(name) + " must be > 0");
  };
  positive(odom_sigma_xy, "odom_sigma_xy");
  positive(odom_sigma_theta, "odom_sigma_theta");
  need(std::isfinite(odom_sigma_turn) && odom_sigma_turn >= 0, "odom_sigma_turn must be >= 0");
  positive(odom_min_sigma_xy, "odom_min_sigma_xy");
  positive(odom_min_sigma_theta, "odom_min_sigma_theta");
  need(std::isfinite(closure_min_sigma_xy) && closure_min_sigma_xy >= 0,
       "closure_min_sigma_xy must be >= 0");
  need(std::isfinite(closure_min_sigma_theta) && closure_min_sigma_theta >= 0,
       "closure_min_sigma_theta must be >= 0");
  need(loss == "none" || loss == "huber" || loss == "cauchy",
       "loss must be none, huber or cauchy, not '" + loss + "'");
  positive(loss_scale, "loss_scale");
  positive(consistency_window, "consistency_window");
  positive(consistency_chi2, "consistency_chi2");
  need(max_iterations > 0, "max_iterations must be > 0");
  need(max_odometry_samples > 0, "max_odometry_samples must be > 0");
}

PoseGraph::PoseGraph(const PoseGraphOptions& options) : options_(options) { options_.Check(); }

int64_t PoseGraph::FirstStamp() const {
  if (odom_.empty()) throw std::logic_error("PoseGraph: no odometry yet");
  return odom_.front().t;
}

int64_t PoseGraph::LastStamp() const {
  if (odom_.empty()) throw std::logic_error("PoseGraph: no odometry yet");
  return odom_.back().t;
}

bool PoseGraph::Covers(int64_t t) const {
  return !odom_.empty() && t >= odom_.front().t && t <= odom_.back().t;
}

void PoseGraph::AddOdometry(int64_t t, const Pose2D& pose) {
  if (!Finite(pose)) throw std::invalid_argument("odometry pose has a non-finite value");
  if (!odom_.empty() && t <= odom_.back().t) {
    throw std::invalid_argument("odometry stamp " + std::to_string(t * 1e-9) +
                                " s is not after the previous one (" +
                                std::to_string(odom_.back().t * 1e-9) + " s)");
  }
  if (odom_.size() >= options_.max_odometry_samples) {
    throw std::length_error("odometry buffer full (" +
                            std::to_string(options_.max_odometry_samples) + " samples)");
  }
  Sample s{t, pose, 0.0};
  if (!odom_.empty()) {
    s.dist =
        odom_.back().dist + std::hypot(pose.x - odom_.back().odom.x, pose.y - odom_.back().odom.y);
  }
  odom_.push_back(s);
  if (odom_.size() == 1) {
    // The anchor: the map frame is the odometry frame at the start.
    Node& n = nodes_[t];
    n.odom = pose;
    n.est[0] = pose.x;
    n.est[1] = pose.y;
    n.est[2] = pose.theta;
  }
}

PoseGraph::Sample PoseGraph::Interpolate(int64_t t) const {
  if (!Covers(t)) {
    throw std::invalid_argument("stamp " + std::to_string(t * 1e-9) +
                                " s is outside the odometry received");
  }
  auto it = std::lower_bound(odom_.begin(), odom_.end(), t,
                             [](const Sample& s, int64_t v) { return s.t < v; });
  if (it->t == t) return *it;
  const Sample& b = *it;
  const Sample& a = *(it - 1);
  const double f = static_cast<double>(t - a.t) / static_cast<double>(b.t - a.t);
  Sample s;
  s.t = t;
  s.odom = {a.odom.x + f * (b.odom.x - a.odom.x), a.odom.y + f * (b.odom.y - a.odom.y),
            WrapAngle(a.odom.theta + f * WrapAngle(b.odom.theta - a.odom.theta))};
  s.dist = a.dist + f * (b.dist - a.dist);
  return s;
}

PoseGraph::Node& PoseGraph::NodeAt(int64_t t) {
  auto it = nodes_.find(t);
  if (it != nodes_.end()) return it->second;
  const Sample s = Interpolate(t);
  // Warm start: the previous node's estimate carried forward by odometry.
  auto prev = nodes_.lower_bound(t);
  --prev;  // exists: the anchor is the first sample and t is covered
  const Node& p = prev->second;
  const Pose2D est = Compose(Compose({p.est[0], p.est[1], p.est[2]}, Inverse(p.odom)), s.odom);
  Node& n = nodes_[t];
  n.odom = s.odom;
  n.dist = s.dist;
  n.est[0] = est.x;
  n.est[1] = est.y;
  n.est[2] = WrapAngle(est.theta);
  return n;
}

std::array<double, 9> PoseGraph::OdometryCovariance(double distance, double turn) const {
  const double vxy = std::max(options_.odom_min_sigma_xy * options_.odom_min_sigma_xy,
                              options_.odom_sigma_xy * options_.odom_sigma_xy * distance);
  const double vt = std::max(options_.odom_min_sigma_theta * options_.odom_min_sigma_theta,
                             options_.odom_sigma_theta * options_.odom_sigma_theta * distance +
                                 options_.odom_sigma_turn * options_.odom_sigma_turn * turn * turn);
  return {vxy, 0, 0, 0, vxy, 0, 0, 0, vt};
}

bool PoseGraph::Consistent(const StoredClosure& a, const StoredClosure& b) const {
  // m_a -> q_a (closure a) -> q_b (odometry) -> m_b (closure b inverted) -> m_a (odometry).
  const Sample qa = Interpolate(a.c.query_ns), qb = Interpolate(b.c.query_ns);
  const Sample ma = Interpolate(a.c.match_ns), mb = Interpolate(b.c.match_ns);
  const Pose2D qa_from_qb = Compose(Inverse(qa.odom), qb.odom);
  const Pose2D mb_from_ma = Compose(Inverse(mb.odom), ma.odom);
  Pose2D cycle =
      Compose(Compose(Compose(a.c.match_from_query, qa_from_qb), Inverse(b.c.match_from_query)),
              mb_from_ma);
  const Eigen::Vector3d e(cycle.x, cycle.y, WrapAngle(cycle.theta));
  // Covariances added as they are: their frames differ by small rotations only when the two
  // closures are nearby, and the xy parts are near isotropic.
  const Eigen::Matrix3d cov =
      ToMatrix(a.c.covariance) + ToMatrix(b.c.covariance) +
      ToMatrix(OdometryCovariance(std::abs(qb.dist - qa.dist), std::abs(qa_from_qb.theta))) +
      ToMatrix(OdometryCovariance(std::abs(mb.dist - ma.dist), std::abs(mb_from_ma.theta)));
  const double chi2 = e.dot(cov.ldlt().solve(e));
  return std::isfinite(chi2) && chi2 <= options_.consistency_chi2;
}

void PoseGraph::Accept(StoredClosure* s) {
  if (s->state == ClosureState::kPending) --pending_;
  s->state = ClosureState::kAccepted;
  ++accepted_;
  NodeAt(s->c.match_ns);
  NodeAt(s->c.query_ns);
  dirty_ = true;
}

ClosureState PoseGraph::AddClosure(const Closure& closure) {
  if (!Finite(closure.match_from_query)) {
    throw std::invalid_argument("closure pose has a non-finite value");
  }
  if (!Covers(closure.match_ns) || !Covers(closure.query_ns)) {
    throw std::invalid_argument("closure stamps (match " + std::to_string(closure.match_ns * 1e-9) +
                                " s, query " + std::to_string(closure.query_ns * 1e-9) +
                                " s) are outside the odometry received");
  }
  StoredClosure s{closure, ClosureState::kPending, 0.0, 0.0};
  // The localizer's covariance plus the floor (see PoseGraphOptions).
  s.c.covariance[0] += options_.closure_min_sigma_xy * options_.closure_min_sigma_xy;
  s.c.covariance[4] += options_.closure_min_sigma_xy * options_.closure_min_sigma_xy;
  s.c.covariance[8] += options_.closure_min_sigma_theta * options_.closure_min_sigma_theta;
  Eigen::Matrix3d unused;
  if (!SqrtInformation(ToMatrix(s.c.covariance), &unused)) {
    throw std::invalid_argument("closure covariance is not symmetric positive definite");
  }
  s.match_dist = Interpolate(closure.match_ns).dist;
  s.query_dist = Interpolate(closure.query_ns).dist;
  if (closure.match_ns == closure.query_ns) {
    s.state = ClosureState::kRejected;
    closures_.push_back(s);  // kept for its id: never a partner, never an edge
    ++rejected_;
    return ClosureState::kRejected;
  }
  closures_.push_back(s);
  StoredClosure& added = closures_.back();
  ++pending_;  // until accepted
  if (!options_.consistency_check) {
    Accept(&added);
    return added.state;
  }
  for (size_t i = 0; i + 1 < closures_.size(); ++i) {
    StoredClosure& other = closures_[i];
    if (other.state == ClosureState::kRejected) continue;
    if (std::abs(other.query_dist - added.query_dist) > options_.consistency_window ||
        std::abs(other.match_dist - added.match_dist) > options_.consistency_window) {
      continue;
    }
    if (!Consistent(added, other)) continue;
    if (added.state == ClosureState::kPending) Accept(&added);
    if (other.state == ClosureState::kPending) Accept(&other);
  }
  return added.state;
}

bool PoseGraph::Consistent(const StoredFix& a, const StoredFix& b) const {
  // Fix a carried by odometry to b's stamp, against fix b, in the map frame.
  const Sample sa = Interpolate(a.f.stamp_ns), sb = Interpolate(b.f.stamp_ns);
  const Pose2D rel = Compose(Inverse(sa.odom), sb.odom);
  const Pose2D predicted = Compose(a.f.map_from_base, rel);
  const Eigen::Vector3d e(b.f.map_from_base.x - predicted.x, b.f.map_from_base.y - predicted.y,
                          WrapAngle(b.f.map_from_base.theta - predicted.theta));
  // The prediction's covariance: fix a's through the lever arm of rel, and the odometry's in
  // the map frame.
  const double c = std::cos(a.f.map_from_base.theta), s = std::sin(a.f.map_from_base.theta);
  const double px = c * rel.x - s * rel.y, py = s * rel.x + c * rel.y;
  Eigen::Matrix3d j = Eigen::Matrix3d::Identity();
  j(0, 2) = -py;
  j(1, 2) = px;
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
  r(0, 0) = c;
  r(0, 1) = -s;
  r(1, 0) = s;
  r(1, 1) = c;
  const Eigen::Matrix3d cov =
      j * ToMatrix(a.f.covariance) * j.transpose() + ToMatrix(b.f.covariance) +
      r * ToMatrix(OdometryCovariance(std::abs(sb.dist - sa.dist), std::abs(rel.theta))) *
          r.transpose();
  const double chi2 = e.dot(cov.ldlt().solve(e));
  return std::isfinite(chi2) && chi2 <= options_.consistency_chi2;
}

void PoseGraph::Accept(StoredFix* s) {
  if (s->state == ClosureState::kPending) --fixes_pending_;
  s->state = ClosureState::kAccepted;
  ++fixes_accepted_;
  Node& n = NodeAt(s->f.stamp_ns);
  if (!anchored()) {
    // The first accepted fix places the map frame: every estimate so far (odometry, in the
    // odometry frame) is moved by the correction this fix implies at its node.
    const Pose2D map_from_frame =
        Compose(s->f.map_from_base, Inverse(Pose2D{n.est[0], n.est[1], n.est[2]}));
    for (auto& [t, node] : nodes_) {
      const Pose2D moved = Compose(map_from_frame, {node.est[0], node.est[1], node.est[2]});
      node.est[0] = moved.x;
      node.est[1] = moved.y;
      node.est[2] = WrapAngle(moved.theta);
    }
    anchored_at_ns_ = s->f.stamp_ns;
  }
  dirty_ = true;
}

ClosureState PoseGraph::AddFix(const Fix& fix) {
  if (!Finite(fix.map_from_base)) throw std::invalid_argument("fix pose has a non-finite value");
  if (!Covers(fix.stamp_ns)) {
    throw std::invalid_argument("fix stamp " + std::to_string(fix.stamp_ns * 1e-9) +
                                " s is outside the odometry received");
  }
  StoredFix s{fix, ClosureState::kPending, Interpolate(fix.stamp_ns).dist};
  s.f.covariance[0] += options_.closure_min_sigma_xy * options_.closure_min_sigma_xy;
  s.f.covariance[4] += options_.closure_min_sigma_xy * options_.closure_min_sigma_xy;
  s.f.covariance[8] += options_.closure_min_sigma_theta * options_.closure_min_sigma_theta;
  Eigen::Matrix3d unused;
  if (!SqrtInformation(ToMatrix(s.f.covariance), &unused)) {
    throw std::invalid_argument("fix covariance is not symmetric positive definite");
  }
  fixes_.push_back(s);
  StoredFix& added = fixes_.back();
  ++fixes_pending_;
  if (!options_.consistency_check) {
    Accept(&added);
    return added.state;
  }
  const bool was_anchored = anchored();
  for (size_t i = 0; i + 1 < fixes_.size(); ++i) {
    StoredFix& other = fixes_[i];
    if (std::abs(other.dist - added.dist) > options_.consistency_window) continue;
    if (!Consistent(other, added)) continue;
    if (other.state == ClosureState::kPending) Accept(&other);  // the older one anchors
    if (added.state == ClosureState::kPending) Accept(&added);
  }
  // Placed when this fix confirmed an earlier one: the moment a robot knows where it is.
  if (!was_anchored && anchored()) anchored_at_ns_ = added.f.stamp_ns;
  return added.state;
}

ClosureState PoseGraph::FixState(size_t id) const {
  if (id >= fixes_.size()) {
    throw std::out_of_range("no fix " + std::to_string(id) + " (" + std::to_string(fixes_.size()) +
                            " added)");
  }
  return fixes_[id].state;
}

ClosureState PoseGraph::State(size_t id) const {
  if (id >= closures_.size()) {
    throw std::out_of_range("no closure " + std::to_string(id) + " (" +
                            std::to_string(closures_.size()) + " added)");
  }
  return closures_[id].state;
}

SolveReport PoseGraph::Optimize() {
  SolveReport report;
  report.nodes = nodes_.size();
  if (!dirty_) {
    report.message = "nothing changed";
    return report;
  }
  if (!anchored()) {
    report.message = "waiting for a fix to place the map frame";
    return report;
  }
  const auto t0 = std::chrono::steady_clock::now();
  ceres::Problem problem;
  // Odometry edges between consecutive nodes.
  for (auto it = nodes_.begin(); std::next(it) != nodes_.end(); ++it) {
    Node& a = it->second;
    Node& b = std::next(it)->second;
    const Pose2D rel = Compose(Inverse(a.odom), b.odom);
    Eigen::Matrix3d l;
    SqrtInformation(ToMatrix(OdometryCovariance(b.dist - a.dist, std::abs(WrapAngle(rel.theta)))),
                    &l);
    problem.AddResidualBlock(
        new ceres::AutoDiffCostFunction<RelativePoseCost, 3, 3, 3>(new RelativePoseCost(rel, l)),
        nullptr, a.est, b.est);
  }
  // Closure edges.
  for (const StoredClosure& s : closures_) {
    if (s.state != ClosureState::kAccepted) continue;
    Eigen::Matrix3d l;
    SqrtInformation(ToMatrix(s.c.covariance), &l);
    ceres::LossFunction* loss = nullptr;
    if (options_.loss == "cauchy") {
      loss = new ceres::CauchyLoss(options_.loss_scale);
    } else if (options_.loss == "huber") {
      loss = new ceres::HuberLoss(options_.loss_scale);
    }
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<RelativePoseCost, 3, 3, 3>(
                                 new RelativePoseCost(s.c.match_from_query, l)),
                             loss, nodes_.at(s.c.match_ns).est, nodes_.at(s.c.query_ns).est);
    ++report.closure_edges;
  }
  // Fix edges (a map made before: its keyframes' poses hold the map frame).
  for (const StoredFix& s : fixes_) {
    if (s.state != ClosureState::kAccepted) continue;
    Eigen::Matrix3d l;
    SqrtInformation(ToMatrix(s.f.covariance), &l);
    ceres::LossFunction* loss = nullptr;
    if (options_.loss == "cauchy") {
      loss = new ceres::CauchyLoss(options_.loss_scale);
    } else if (options_.loss == "huber") {
      loss = new ceres::HuberLoss(options_.loss_scale);
    }
    problem.AddResidualBlock(
        new ceres::AutoDiffCostFunction<PoseCost, 3, 3>(new PoseCost(s.f.map_from_base, l)), loss,
        nodes_.at(s.f.stamp_ns).est);
  }
  // The gauge: the first node (map = odom at the start), or the fixes alone.
  if (options_.anchor_at_start) problem.SetParameterBlockConstant(nodes_.begin()->second.est);
  if (nodes_.size() > 1 || !options_.anchor_at_start) {
    ceres::Solver::Options so;
    so.max_num_iterations = options_.max_iterations;
    so.num_threads = 1;  // the localizer needs the cores more
    if (ceres::IsSparseLinearAlgebraLibraryTypeAvailable(ceres::SUITE_SPARSE)) {
      so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
      so.sparse_linear_algebra_library_type = ceres::SUITE_SPARSE;
    } else if (ceres::IsSparseLinearAlgebraLibraryTypeAvailable(ceres::EIGEN_SPARSE)) {
      so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
      so.sparse_linear_algebra_library_type = ceres::EIGEN_SPARSE;
    } else {
      so.linear_solver_type = ceres::DENSE_QR;
    }
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    report.ran = true;
    report.converged = summary.termination_type == ceres::CONVERGENCE;
    report.iterations = static_cast<int>(summary.iterations.size());
    report.initial_cost = summary.initial_cost;
    report.final_cost = summary.final_cost;
    report.message = summary.BriefReport();
  }
  for (auto& [t, n] : nodes_) n.est[2] = WrapAngle(n.est[2]);
  // Closures the loss flattened: residuals beyond loss_scale standard deviations.
  for (const StoredClosure& s : closures_) {
    if (s.state != ClosureState::kAccepted) continue;
    Eigen::Matrix3d l;
    SqrtInformation(ToMatrix(s.c.covariance), &l);
    double r[3];
    RelativePoseCost(s.c.match_from_query, l)(nodes_.at(s.c.match_ns).est,
                                              nodes_.at(s.c.query_ns).est, r);
    if (r[0] * r[0] + r[1] * r[1] + r[2] * r[2] > options_.loss_scale * options_.loss_scale) {
      ++report.downweighted;
    }
  }
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  dirty_ = false;
  return report;
}

Pose2D PoseGraph::PoseAt(int64_t t) const {
  const Sample s = Interpolate(t);
  auto after = nodes_.upper_bound(t);
  auto before = std::prev(after);  // exists: the anchor is the first sample
  auto corrected = [&](const Node& n) {
    return Compose(Compose({n.est[0], n.est[1], n.est[2]}, Inverse(n.odom)), s.odom);
  };
  const Pose2D a = corrected(before->second);
  if (after == nodes_.end()) return {a.x, a.y, WrapAngle(a.theta)};
  const Pose2D b = corrected(after->second);
  const double span = after->second.dist - before->second.dist;
  double f = span > 1e-12 ? (s.dist - before->second.dist) / span
                          : static_cast<double>(t - before->first) /
                                static_cast<double>(after->first - before->first);
  f = std::clamp(f, 0.0, 1.0);
  return {a.x + f * (b.x - a.x), a.y + f * (b.y - a.y),
          WrapAngle(a.theta + f * WrapAngle(b.theta - a.theta))};
}

std::vector<PoseGraph::TrajectoryPoint> PoseGraph::Trajectory() const {
  std::vector<TrajectoryPoint> out;
  out.reserve(odom_.size());
  for (const Sample& s : odom_) out.push_back({s.t, PoseAt(s.t), s.odom});
  return out;
}

Pose2D PoseGraph::MapFromOdom() const {
  if (nodes_.empty()) return {};
  const Node& n = nodes_.rbegin()->second;
  const Pose2D m = Compose({n.est[0], n.est[1], n.est[2]}, Inverse(n.odom));
  return {m.x, m.y, WrapAngle(m.theta)};
}

}  // namespace backend
}  // namespace gtbow
