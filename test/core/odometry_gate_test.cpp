// The odometry gate (core/odometry_gate.h): wrong fixes are held, a kidnapped robot relocalises.
#include "ground_texture_bow/core/odometry_gate.h"

#include <cmath>
#include <stdexcept>

#include <gtest/gtest.h>

namespace gtbow {
namespace {

// A robot driving a circle of radius 0.5 m, 1 cm per image; its odometry is the truth seen
// through a fixed map -> odom offset, plus a heading drift of 0.01 rad per metre.
struct Drive {
  Pose2D map_from_odom{0.3, -0.2, 0.4};
  Pose2D Truth(int i) const {
    const double a = 0.02 * i;
    return {0.5 * std::sin(a), 0.5 - 0.5 * std::cos(a), a};
  }
  Pose2D Odom(int i) const {
    Pose2D o = Compose(Inverse(map_from_odom), Truth(i));
    o.theta += 0.01 * 0.01 * i;  // drift: 0.01 rad per metre driven
    return o;
  }
};

double Distance(const Pose2D& a, const Pose2D& b) { return std::hypot(a.x - b.x, a.y - b.y); }

TEST(OdometryGate, AcceptsFixesThatAgreeWithOdometry) {
  OdometryGate gate{OdometryGateOptions{}};
  Drive d;
  for (int i = 0; i < 200; ++i) {
    ASSERT_EQ(gate.Offer(d.Truth(i), d.Odom(i)), GateVerdict::kAccepted) << i;
  }
  ASSERT_TRUE(gate.correction());
  // The correction maps the latest odometry onto the latest fix.
  EXPECT_LT(Distance(Compose(*gate.correction(), d.Odom(199)), d.Truth(199)), 1e-9);
}

TEST(OdometryGate, AWrongFixIsHeldAndDoesNotMoveTheCorrection) {
  OdometryGate gate{OdometryGateOptions{}};
  Drive d;
  for (int i = 0; i < 10; ++i) ASSERT_EQ(gate.Offer(d.Truth(i), d.Odom(i)), GateVerdict::kAccepted);
  const Pose2D before = *gate.correction();
  // A fix 111 mm off with the right heading (a stain that outvoted the floor).
  Pose2D wrong = d.Truth(10);
  wrong.x += 0.111;
  EXPECT_EQ(gate.Offer(wrong, d.Odom(10)), GateVerdict::kHeld);
  EXPECT_EQ(gate.held_run(), 1);
  EXPECT_NEAR(gate.last_error_distance(), 0.111, 1e-4);  // and the drift
  EXPECT_EQ(gate.correction()->x, before.x);
  EXPECT_EQ(gate.correction()->y, before.y);
  EXPECT_EQ(gate.correction()->theta, before.theta);
  // A wrong heading alone is held too.
  Pose2D turned = d.Truth(11);
  turned.theta += 0.2;
  EXPECT_EQ(gate.Offer(turned, d.Odom(11)), GateVerdict::kHeld);
  // The true fixes go on being accepted; two wrong fixes at different places never relocalise.
  EXPECT_EQ(gate.Offer(d.Truth(12), d.Odom(12)), GateVerdict::kAccepted);
  EXPECT_EQ(gate.held_run(), 0);
  for (int i = 13; i < 40; ++i) {
    Pose2D w = d.Truth(i);
    w.y += (i % 2 ? 0.2 : -0.3);
    const GateVerdict v = gate.Offer(i % 3 == 0 ? d.Truth(i) : w, d.Odom(i));
    EXPECT_NE(v, GateVerdict::kRelocalized) << i;
  }
}

TEST(OdometryGate, AKidnappedRobotRelocalisesAfterNAgreeingFixes) {
  OdometryGateOptions o;
  o.relocalize_after = 3;
  OdometryGate gate(o);
  Drive d;
  for (int i = 0; i < 20; ++i) gate.Offer(d.Truth(i), d.Odom(i));
  // Carried 1.2 m away and turned: odometry saw nothing, so map -> odom is now another one.
  Drive carried = d;
  carried.map_from_odom = Compose({1.2, 0.4, 1.0}, d.map_from_odom);
  std::vector<GateVerdict> v;
  for (int i = 20; i < 25; ++i) {
    const Pose2D truth = Compose(carried.map_from_odom, d.Odom(i));
    v.push_back(gate.Offer(truth, d.Odom(i)));
  }
  EXPECT_EQ(v, (std::vector<GateVerdict>{GateVerdict::kHeld, GateVerdict::kHeld,
                                         GateVerdict::kRelocalized, GateVerdict::kAccepted,
                                         GateVerdict::kAccepted}));
  const Pose2D c = *gate.correction();
  EXPECT_LT(Distance(Compose(c, d.Odom(24)), Compose(carried.map_from_odom, d.Odom(24))), 1e-6);
}

TEST(OdometryGate, ToleranceGrowsWithTheDistanceDriven) {
  OdometryGateOptions o;
  o.distance = 0.01;
  o.distance_drift = 0.05;
  OdometryGate gate(o);
  const Pose2D odom0{0, 0, 0};
  EXPECT_EQ(gate.Offer({0, 0, 0}, odom0), GateVerdict::kAccepted);
  // 2 m driven without a fix (Drive), then a fix 80 mm from odometry's prediction: within
  // 10 mm + 5% of 2 m = 110 mm.
  for (int i = 1; i <= 200; ++i) gate.Drive({0.01 * i, 0, 0});
  EXPECT_EQ(gate.Offer({2.08, 0, 0}, {2.0, 0, 0}), GateVerdict::kAccepted);
  // Right after it, the same 80 mm is too much.
  EXPECT_EQ(gate.Offer({2.09, 0.08, 0}, {2.01, 0, 0}), GateVerdict::kHeld);
}

TEST(OdometryGate, SetCorrectionIsAnInitialPoseAndOffAcceptsEverything) {
  OdometryGate gate{OdometryGateOptions{}};
  gate.SetCorrection({1.0, 2.0, 0.0}, {0, 0, 0});
  EXPECT_EQ(gate.Offer({1.5, 2.0, 0.0}, {0, 0, 0}), GateVerdict::kHeld);  // 0.5 m off it
  EXPECT_EQ(gate.Offer({1.0, 2.0, 0.0}, {0, 0, 0}), GateVerdict::kAccepted);
  OdometryGateOptions off;
  off.enabled = false;
  OdometryGate open(off);
  EXPECT_EQ(open.Offer({0, 0, 0}, {0, 0, 0}), GateVerdict::kAccepted);
  EXPECT_EQ(open.Offer({5, 5, 3}, {0, 0, 0}), GateVerdict::kAccepted);
  EXPECT_EQ(open.correction()->x, 5.0);
  gate.Reset();
  EXPECT_FALSE(gate.correction());
}

TEST(OdometryGate, BadOptionsAreNamed) {
  OdometryGateOptions o;
  o.distance = 0;
  EXPECT_THROW(OdometryGate{o}, std::invalid_argument);
  o = OdometryGateOptions{};
  o.relocalize_after = 0;
  try {
    OdometryGate g(o);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("relocalize_after"), std::string::npos);
  }
}

}  // namespace
}  // namespace gtbow
