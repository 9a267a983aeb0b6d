// The odometry gate of global localization: a fix is checked against the robot's odometry
// before it may move map -> odom. One wrong fix (a repeated patch of floor, a stain that outvotes
// the texture) must not teleport the robot; a robot that really was carried somewhere else (a
// kidnapped robot) must still relocalise.
//
// Every fix and odometry pose here is the camera's footprint (geometry.h's Pose2D): the fix in
// the map frame, odometry in the odom frame, both at the image's stamp. A fix implies a map ->
// odom correction, fix * odom^-1. The gate keeps the accepted correction and accepts a fix when
// its correction predicts it within a tolerance that grows with the distance driven since the
// last accepted fix (odometry drifts with distance). A fix outside is held. After
// `relocalize_after` consecutive held fixes whose corrections agree with one another, the robot
// is somewhere else: the newest is accepted and replaces the correction.
#pragma once

#include <optional>

#include "ground_texture_bow/core/geometry.h"

namespace gtbow {

struct OdometryGateOptions {
  bool enabled = true;
  double distance = 0.05;        // m: a fix may disagree with odometry by this much ...
  double angle = 0.0873;         // rad (5 deg)
  double distance_drift = 0.05;  // ... plus this fraction of the distance driven since the last
                                 // accepted fix
  double angle_drift = 0.035;    // rad per metre driven (2 deg per metre)
  int relocalize_after = 3;      // consecutive held fixes that agree with one another: relocalise

  void Check() const;  // throws std::invalid_argument naming the bad field
};

enum class GateVerdict {
  kAccepted,     // agrees with odometry (or the gate is off, or it is the first fix)
  kHeld,         // disagrees: not to be published
  kRelocalized,  // the last `relocalize_after` held fixes agreed: the robot is elsewhere
};
const char* GateVerdictName(GateVerdict v);

class OdometryGate {
 public:
  explicit OdometryGate(const OdometryGateOptions& options);

  // A fix (map frame) with odometry at its stamp (odom frame). The correction is updated unless
  // the fix is held.
  GateVerdict Offer(const Pose2D& map_from_camera, const Pose2D& odom_from_camera);
  // Odometry of an image without a fix, so that the distance driven is counted.
  void Drive(const Pose2D& odom_from_camera);
  // An external estimate (amcl's initialpose): the correction is set, held fixes forgotten.
  void SetCorrection(const Pose2D& map_from_odom, const Pose2D& odom_from_camera);
  // The accepted map -> odom, if any fix was accepted.
  const std::optional<Pose2D>& correction() const { return correction_; }
  int held_run() const { return held_run_; }  // consecutive held fixes that agree
  // How far the last offered fix was from the correction's prediction (m, rad) and the
  // tolerance it was held to; for diagnostics.
  double last_error_distance() const { return last_error_distance_; }
  double last_error_angle() const { return last_error_angle_; }
  void Reset();

 private:
  void Travel(const Pose2D& odom_from_camera);

  OdometryGateOptions options_;
  std::optional<Pose2D> correction_;       // map_from_odom of the last accepted fix
  std::optional<Pose2D> last_odom_;        // odometry at the previous image
  double driven_ = 0;                      // metres since the last accepted fix
  std::optional<Pose2D> held_correction_;  // the previous held fix's correction
  int held_run_ = 0;
  double last_error_distance_ = 0, last_error_angle_ = 0;
};

}  // namespace gtbow
