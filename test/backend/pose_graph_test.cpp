// The pose graph on a synthetic drive without images: true poses from the drive generator,
// odometry from its noise model, loop closures from the truth with noise. The backend must
// remove most of the drift and keep a wrong closure out of the graph.
#include "ground_texture_bow/backend/pose_graph.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "ground_texture_bow/eval/synth/generator.h"

namespace gtbow {
namespace backend {
namespace {

constexpr int64_t kStep = 100000000;  // 0.1 s between samples

struct Drive {
  std::vector<Pose2D> truth, odom;
};

Drive MakeDrive() {
  Drive d;
  d.truth = synth::DrivePath(1.2, 0.8, ImageGeometry{640, 480, 0.00025}, 12.0, 0.01);
  d.odom = synth::SimulateOdometry(d.truth, synth::OdometryNoise{}, 7);
  return d;
}

double Rmse(const std::vector<Pose2D>& truth, const std::vector<Pose2D>& est) {
  double s = 0;
  for (size_t i = 0; i < truth.size(); ++i) {
    s += std::pow(truth[i].x - est[i].x, 2) + std::pow(truth[i].y - est[i].y, 2);
  }
  return std::sqrt(s / truth.size());
}

// Closures like the localizer's: each pose on a revisit against the nearest pose more than
// `min_gap` samples earlier, 0.2 mm / 1 mrad noise.
std::vector<Closure> TrueClosures(const std::vector<Pose2D>& truth, size_t min_gap) {
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  std::vector<Closure> out;
  for (size_t q = min_gap; q < truth.size(); q += 3) {
    size_t best = 0;
    double best_d = 1e9;
    for (size_t m = 0; m + min_gap <= q; ++m) {
      const double d = std::hypot(truth[q].x - truth[m].x, truth[q].y - truth[m].y);
      if (d < best_d) {
        best_d = d;
        best = m;
      }
    }
    if (best_d > 0.03) continue;
    Closure c;
    c.match_ns = static_cast<int64_t>(best) * kStep;
    c.query_ns = static_cast<int64_t>(q) * kStep;
    c.match_from_query = Compose(Inverse(truth[best]), truth[q]);
    c.match_from_query.x += 2e-4 * n(rng);
    c.match_from_query.y += 2e-4 * n(rng);
    c.match_from_query.theta += 1e-3 * n(rng);
    c.covariance = {4e-8, 0, 0, 0, 4e-8, 0, 0, 0, 1e-6};
    out.push_back(c);
  }
  return out;
}

TEST(PoseGraph, ClosuresRemoveTheDriftAndAWrongOneStaysOut) {
  const Drive d = MakeDrive();
  PoseGraph g{PoseGraphOptions{}};
  for (size_t i = 0; i < d.odom.size(); ++i)
    g.AddOdometry(static_cast<int64_t>(i) * kStep, d.odom[i]);
  auto closures = TrueClosures(d.truth, 200);
  ASSERT_GT(closures.size(), 100u);
  // A wrong closure in the middle: claims two poses 0.3 m apart are 1 cm apart.
  Closure wrong = closures[closures.size() / 2];
  wrong.match_ns -= 30 * kStep;
  const size_t wrong_index = closures.size() / 2;
  closures.insert(closures.begin() + wrong_index, wrong);
  for (size_t i = 0; i < closures.size(); ++i) {
    const ClosureState s = g.AddClosure(closures[i]);
    if (i == wrong_index) {
      EXPECT_EQ(s, ClosureState::kPending);
    }
  }
  EXPECT_GE(g.pending(), 1u);
  const SolveReport r = g.Optimize();
  EXPECT_TRUE(r.ran);
  std::vector<Pose2D> est;
  for (const auto& p : g.Trajectory()) est.push_back(p.map_from_base);
  const double before = Rmse(d.truth, d.odom), after = Rmse(d.truth, est);
  EXPECT_GT(before, 0.005);
  EXPECT_LT(after, 0.2 * before) << "odometry " << before << " m, backend " << after << " m";
  EXPECT_LT(after, 0.003);
}

TEST(PoseGraph, WithoutDefencesTheWrongClosureBendsTheTrajectory) {
  // The negative control of the test above: the same wrong closure, accepted with a quadratic
  // loss, visibly harms the result (so the test above measures the defences, not luck).
  const Drive d = MakeDrive();
  PoseGraphOptions o;
  o.consistency_check = false;
  o.loss = "none";
  PoseGraph clean{o}, harmed{o};
  for (size_t i = 0; i < d.odom.size(); ++i) {
    clean.AddOdometry(static_cast<int64_t>(i) * kStep, d.odom[i]);
    harmed.AddOdometry(static_cast<int64_t>(i) * kStep, d.odom[i]);
  }
  auto closures = TrueClosures(d.truth, 200);
  Closure wrong = closures[closures.size() / 2];
  wrong.match_ns -= 30 * kStep;
  for (const auto& c : closures) {
    clean.AddClosure(c);
    harmed.AddClosure(c);
  }
  harmed.AddClosure(wrong);
  clean.Optimize();
  harmed.Optimize();
  std::vector<Pose2D> a, b;
  for (const auto& p : clean.Trajectory()) a.push_back(p.map_from_base);
  for (const auto& p : harmed.Trajectory()) b.push_back(p.map_from_base);
  EXPECT_GT(Rmse(d.truth, b), 2.0 * Rmse(d.truth, a));
}

TEST(PoseGraph, RefusesBadInput) {
  PoseGraph g{PoseGraphOptions{}};
  g.AddOdometry(10, {0, 0, 0});
  g.AddOdometry(20, {0.01, 0, 0});
  EXPECT_THROW(g.AddOdometry(20, {0.02, 0, 0}), std::invalid_argument);
  EXPECT_THROW(g.AddOdometry(30, {NAN, 0, 0}), std::invalid_argument);
  Closure c;
  c.match_ns = 10;
  c.query_ns = 20;
  c.match_from_query = {0.01, 0, 0};
  c.covariance = {1e-8, 0, 0, 0, 1e-8, 0, 0, 0, -1};  // not positive definite
  EXPECT_THROW(g.AddClosure(c), std::invalid_argument);
  c.covariance = {1e-8, 0, 0, 0, 1e-8, 0, 0, 0, 1e-6};
  c.query_ns = 25;  // beyond the odometry
  EXPECT_THROW(g.AddClosure(c), std::invalid_argument);
  PoseGraphOptions bad;
  bad.loss = "square";
  EXPECT_THROW(PoseGraph{bad}, std::invalid_argument);
}

}  // namespace
}  // namespace backend
}  // namespace gtbow
