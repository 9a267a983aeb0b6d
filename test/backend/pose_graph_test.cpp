// The pose graph on a synthetic drive without images: true poses from the drive generator,
// odometry from its noise model, loop closures from the truth with noise. The backend must
// remove most of the drift and keep a wrong closure out of the graph.
#include "ground_texture_bow/backend/pose_graph.h"

#include <cmath>
#include <cstdio>
#include <ostream>
#include <random>

#include <gtest/gtest.h>

#include "ground_texture_bow/eval/synth/generator.h"

namespace gtbow {
namespace backend {

void PrintTo(ClosureState s, std::ostream* os) {
  *os << (s == ClosureState::kAccepted  ? "accepted"
          : s == ClosureState::kPending ? "pending"
                                        : "rejected");
}

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

// The wrong closure of the tests below: a true closure from the middle of the drive with its
// match moved 30 samples (0.3 m of driving) on, so it claims two poses about 0.3 m apart are
// as close as the true pair. Inserted where the true one was: the true closures after it, their
// matches further on, fall in its consistency window and could confirm it.
struct Injected {
  std::vector<Closure> closures;  // in the order they are added
  size_t index;                   // the wrong one's position
  double true_distance;           // between the wrong pair's poses, m
  size_t later_neighbours;        // true closures after it, both ends within 0.45 m of driving
};

Injected WithWrongClosure(const Drive& d) {
  Injected in;
  in.closures = TrueClosures(d.truth, 200);
  in.index = in.closures.size() / 2;
  Closure wrong = in.closures[in.index];
  wrong.match_ns += 30 * kStep;
  in.closures.insert(in.closures.begin() + static_cast<long>(in.index), wrong);
  auto at = [&](int64_t ns) { return static_cast<size_t>(ns / kStep); };
  const Pose2D &m = d.truth[at(wrong.match_ns)], &q = d.truth[at(wrong.query_ns)];
  in.true_distance = std::hypot(m.x - q.x, m.y - q.y);
  std::vector<double> driven(d.truth.size(), 0.0);
  for (size_t i = 1; i < d.truth.size(); ++i) {
    driven[i] = driven[i - 1] +
                std::hypot(d.truth[i].x - d.truth[i - 1].x, d.truth[i].y - d.truth[i - 1].y);
  }
  in.later_neighbours = 0;
  for (size_t i = in.index + 1; i < in.closures.size(); ++i) {
    const Closure& c = in.closures[i];
    if (std::abs(driven[at(c.query_ns)] - driven[at(wrong.query_ns)]) < 0.45 &&
        std::abs(driven[at(c.match_ns)] - driven[at(wrong.match_ns)]) < 0.45) {
      ++in.later_neighbours;
    }
  }
  return in;
}

// The bound a backend must meet on that input: the trajectory within 3 mm RMSE of the truth and
// the wrong pair's distance within 5 mm of the true one (test/ros/backend_rostest.cpp's fold).
constexpr double kMaxRmse = 0.003, kMaxFold = 0.005;

struct Outcome {
  size_t wrong_id = 0;
  bool wrong_ever_accepted = false;  // after any later closure or optimisation
  ClosureState wrong_final = ClosureState::kPending;
  double rmse = 0, fold = 0;
  size_t accepted = 0;
};

// Feeds the drive and the closures to a graph with `o`, optimising every 25 closures (as the
// node does once a second) and at the end; the wrong closure's state is read by its id after
// every closure and every optimisation that follow it.
Outcome Feed(const Drive& d, const Injected& in, const PoseGraphOptions& o) {
  PoseGraph g{o};
  for (size_t i = 0; i < d.odom.size(); ++i) {
    g.AddOdometry(static_cast<int64_t>(i) * kStep, d.odom[i]);
  }
  Outcome out;
  for (size_t i = 0; i < in.closures.size(); ++i) {
    if (i == in.index) out.wrong_id = g.closures_added();
    g.AddClosure(in.closures[i]);
    if (i % 25 == 24) g.Optimize();
    if (i >= in.index) {
      out.wrong_ever_accepted |= g.State(out.wrong_id) == ClosureState::kAccepted;
    }
  }
  g.Optimize();
  EXPECT_FALSE(g.dirty());
  out.wrong_final = g.State(out.wrong_id);
  out.wrong_ever_accepted |= out.wrong_final == ClosureState::kAccepted;
  std::vector<Pose2D> est;
  for (const auto& p : g.Trajectory()) est.push_back(p.map_from_base);
  out.rmse = Rmse(d.truth, est);
  const Closure& w = in.closures[in.index];
  const Pose2D a = g.PoseAt(w.match_ns), b = g.PoseAt(w.query_ns);
  out.fold = std::abs(std::hypot(a.x - b.x, a.y - b.y) - in.true_distance);
  out.accepted = g.accepted();
  std::printf(
      "consistency check %s, loss %s: wrong closure %s (%zu later closures in its "
      "window), ATE RMSE %.2f mm, wrong pair off by %.2f mm, %zu of %zu closures "
      "accepted\n",
      o.consistency_check ? "on" : "off", o.loss.c_str(),
      ::testing::PrintToString(out.wrong_final).c_str(), in.later_neighbours, 1e3 * out.rmse,
      1e3 * out.fold, out.accepted, in.closures.size());
  return out;
}

TEST(PoseGraph, ClosuresRemoveTheDriftAndAWrongOneStaysOut) {
  // The defaults: the consistency check and the Cauchy loss.
  const Drive d = MakeDrive();
  const Injected in = WithWrongClosure(d);
  ASSERT_GT(in.closures.size(), 100u);
  const Outcome r = Feed(d, in, PoseGraphOptions{});
  EXPECT_FALSE(r.wrong_ever_accepted) << "a later closure confirmed the wrong one";
  EXPECT_EQ(r.wrong_final, ClosureState::kPending);
  const double before = Rmse(d.truth, d.odom);
  EXPECT_GT(before, 0.005);
  EXPECT_LT(r.rmse, 0.2 * before) << "odometry " << before << " m, backend " << r.rmse << " m";
  EXPECT_LT(r.rmse, kMaxRmse);
  EXPECT_LT(r.fold, kMaxFold);
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

TEST(PoseGraph, TheConsistencyCheckAloneKeepsTheWrongClosureOut) {
  // No robust loss: only the check stands between the wrong closure and the graph.
  const Drive d = MakeDrive();
  const Injected in = WithWrongClosure(d);
  ASSERT_GT(in.true_distance, 0.1);
  ASSERT_GE(in.later_neighbours, 10u) << "too few later closures could confirm the wrong one";
  PoseGraphOptions o;
  o.loss = "none";
  o.consistency_check = true;
  const Outcome r = Feed(d, in, o);
  EXPECT_FALSE(r.wrong_ever_accepted) << "a later closure confirmed the wrong one";
  EXPECT_EQ(r.wrong_final, ClosureState::kPending);
  EXPECT_GT(r.accepted, in.closures.size() / 2) << "the check must still accept true closures";
  EXPECT_LT(r.rmse, kMaxRmse);
  EXPECT_LT(r.fold, kMaxFold);

  // The negative control: the same input with the check off (and no loss) takes the wrong
  // closure in and fails the bound, so the check is what met it.
  o.consistency_check = false;
  const Outcome control = Feed(d, in, o);
  EXPECT_EQ(control.wrong_final, ClosureState::kAccepted);
  EXPECT_GT(control.fold, 2 * kMaxFold) << "the control should fold onto the wrong closure";
  EXPECT_GT(control.rmse, 2 * kMaxRmse) << "the control should bend the whole trajectory";
}

// A second session on a map made before: odometry from the origin (the robot booted somewhere
// on the floor), fixes from verified matches to the old map's keyframes (their poses are fixed,
// so a fix is the base's pose in the map frame). Nothing is placed before two fixes agree; the
// first accepted fix places the map frame, and the session's own closures and later fixes then
// hold the trajectory to the truth. A wrong fix (5 cm off) finds no partner and stays out.
TEST(PoseGraph, ASessionOnAnEarlierMapIsAnchoredByItsFixes) {
  const std::vector<Pose2D> truth =
      synth::DrivePath(1.2, 0.8, ImageGeometry{640, 480, 0.00025}, 6.0, 0.01, 1.0 / 3.0);
  std::vector<Pose2D> odom = synth::SimulateOdometry(truth, synth::OdometryNoise{}, 11);
  const Pose2D boot = Inverse(odom.front());
  for (Pose2D& p : odom) p = Compose(boot, p);
  PoseGraphOptions o;
  o.anchor_at_start = false;
  PoseGraph g{o};
  for (size_t i = 0; i < odom.size(); ++i) g.AddOdometry(static_cast<int64_t>(i) * kStep, odom[i]);
  EXPECT_FALSE(g.anchored());
  for (const Closure& c : TrueClosures(truth, 200)) g.AddClosure(c);
  EXPECT_FALSE(g.Optimize().ran) << "no map frame yet: nothing to optimise";
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 1.0);
  auto fix_at = [&](size_t i, double off) {
    Fix f;
    f.stamp_ns = static_cast<int64_t>(i) * kStep;
    f.map_from_base = truth[i];
    f.map_from_base.x += off + 2e-4 * n(rng);
    f.map_from_base.y += 2e-4 * n(rng);
    f.map_from_base.theta += 1e-3 * n(rng);
    f.covariance = {4e-8, 0, 0, 0, 4e-8, 0, 0, 0, 1e-6};
    return f;
  };
  EXPECT_EQ(g.AddFix(fix_at(10, 0.05)), ClosureState::kPending);  // wrong: 5 cm off
  EXPECT_EQ(g.AddFix(fix_at(14, 0.0)), ClosureState::kPending);   // alone so far
  EXPECT_FALSE(g.anchored());
  EXPECT_EQ(g.AddFix(fix_at(18, 0.0)), ClosureState::kAccepted);  // agrees with the one at 14
  EXPECT_EQ(g.FixState(1), ClosureState::kAccepted);
  EXPECT_TRUE(g.anchored());
  EXPECT_EQ(g.anchored_at_ns(), 18 * kStep);  // when the fix at 18 confirmed the one at 14
  // Later fixes come in runs, as a robot's consecutive images match the old map.
  for (size_t i = 100; i + 5 < truth.size(); i += 100) {
    g.AddFix(fix_at(i, 0.0));
    g.AddFix(fix_at(i + 5, 0.0));
  }
  EXPECT_TRUE(g.Optimize().ran);
  EXPECT_EQ(g.FixState(0), ClosureState::kPending) << "the wrong fix found a partner";
  std::vector<Pose2D> est;
  for (const auto& p : g.Trajectory()) est.push_back(p.map_from_base);
  std::vector<Pose2D> anchored_odom;
  const Pose2D map_from_odom_start = Compose(truth.front(), Inverse(odom.front()));
  for (const Pose2D& p : odom) anchored_odom.push_back(Compose(map_from_odom_start, p));
  const double rmse = Rmse(truth, est), odometry = Rmse(truth, anchored_odom);
  std::printf(
      "second session: anchored at sample 18, ATE RMSE %.3f mm (odometry placed by its "
      "true start: %.2f mm), %zu of %zu fixes accepted\n",
      1e3 * rmse, 1e3 * odometry, g.fixes_accepted(), g.fixes_added());
  EXPECT_LT(rmse, 0.001);
  EXPECT_GT(odometry, 5 * rmse);
  // map -> odom: the map frame is not the odometry's (the robot booted elsewhere).
  const Pose2D m = g.MapFromOdom();
  EXPECT_GT(std::hypot(m.x, m.y), 0.1);
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
  EXPECT_EQ(g.closures_added(), 0u) << "a closure refused by throwing gets no id";
  EXPECT_THROW(g.State(0), std::out_of_range);
  c.query_ns = 10;  // the same stamp at both ends: rejected, and so it stays
  EXPECT_EQ(g.AddClosure(c), ClosureState::kRejected);
  EXPECT_EQ(g.State(0), ClosureState::kRejected);
  c.query_ns = 20;
  EXPECT_EQ(g.AddClosure(c), ClosureState::kPending);
  EXPECT_EQ(g.State(1), ClosureState::kPending);
  PoseGraphOptions bad;
  bad.loss = "square";
  EXPECT_THROW(PoseGraph{bad}, std::invalid_argument);
}

}  // namespace
}  // namespace backend
}  // namespace gtbow
