#include "ground_texture_bow/core/odometry_gate.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace gtbow {

void OdometryGateOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(what);
  };
  need(std::isfinite(distance) && distance > 0, "gate_distance must be > 0");
  need(std::isfinite(angle) && angle > 0, "gate_angle must be > 0");
  need(std::isfinite(distance_drift) && distance_drift >= 0, "gate_distance_drift must be >= 0");
  need(std::isfinite(angle_drift) && angle_drift >= 0, "gate_angle_drift must be >= 0");
  need(relocalize_after >= 1, "relocalize_after must be >= 1");
}

const char* GateVerdictName(GateVerdict v) {
  switch (v) {
    case GateVerdict::kAccepted:
      return "accepted";
    case GateVerdict::kHeld:
      return "held";
    case GateVerdict::kRelocalized:
      return "relocalized";
  }
  return "?";
}

OdometryGate::OdometryGate(const OdometryGateOptions& options) : options_(options) {
  options_.Check();
}

void OdometryGate::Travel(const Pose2D& odom) {
  if (last_odom_) driven_ += std::hypot(odom.x - last_odom_->x, odom.y - last_odom_->y);
  last_odom_ = odom;
}

void OdometryGate::Drive(const Pose2D& odom_from_camera) { Travel(odom_from_camera); }

GateVerdict OdometryGate::Offer(const Pose2D& fix, const Pose2D& odom) {
  Travel(odom);
  const Pose2D implied = Compose(fix, Inverse(odom));  // map_from_odom
  auto accept = [&](const Pose2D& c) {
    correction_ = c;
    driven_ = 0;
    held_correction_.reset();
    held_run_ = 0;
  };
  if (!correction_ || !options_.enabled) {
    last_error_distance_ = last_error_angle_ = 0;
    accept(implied);
    return GateVerdict::kAccepted;
  }
  const Pose2D predicted = Compose(*correction_, odom);
  last_error_distance_ = std::hypot(fix.x - predicted.x, fix.y - predicted.y);
  last_error_angle_ = std::abs(WrapAngle(fix.theta - predicted.theta));
  if (last_error_distance_ <= options_.distance + options_.distance_drift * driven_ &&
      last_error_angle_ <= options_.angle + options_.angle_drift * driven_) {
    accept(implied);
    return GateVerdict::kAccepted;
  }
  // Held. Does it agree with the previous held fix? Both corrections are map -> odom, so two
  // fixes of a robot that was carried elsewhere give the same one, up to the fixes' error and
  // the drift between them.
  bool agrees = false;
  if (held_correction_) {
    const Pose2D a = Compose(*held_correction_, odom), b = Compose(implied, odom);
    agrees = std::hypot(a.x - b.x, a.y - b.y) <= options_.distance &&
             std::abs(WrapAngle(a.theta - b.theta)) <= options_.angle;
  }
  held_run_ = agrees ? held_run_ + 1 : 1;
  held_correction_ = implied;
  if (held_run_ >= options_.relocalize_after) {
    accept(implied);
    return GateVerdict::kRelocalized;
  }
  return GateVerdict::kHeld;
}

void OdometryGate::SetCorrection(const Pose2D& map_from_odom, const Pose2D& odom_from_camera) {
  correction_ = map_from_odom;
  last_odom_ = odom_from_camera;
  driven_ = 0;
  held_correction_.reset();
  held_run_ = 0;
}

void OdometryGate::Reset() {
  correction_.reset();
  last_odom_.reset();
  driven_ = 0;
  held_correction_.reset();
  held_run_ = 0;
  last_error_distance_ = last_error_angle_ = 0;
}

}  // namespace gtbow
