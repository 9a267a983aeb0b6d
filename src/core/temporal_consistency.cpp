#include "ground_texture_bow/core/temporal_consistency.h"

#include <cmath>
#include <string>

namespace gtbow {

void TemporalConsistencyOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("temporal consistency: ") + what);
  };
  need(required >= 1, "required (N) must be >= 1");
  need(distance > 0.0 && std::isfinite(distance), "distance must be positive");
  need(angle > 0.0 && std::isfinite(angle), "angle must be positive");
  need(max_motion > 0.0 && std::isfinite(max_motion), "max_motion must be positive");
}

TemporalConsistency::TemporalConsistency(const TemporalConsistencyOptions& options)
    : options_(options) {
  options_.Check();
}

void TemporalConsistency::Reset() {
  last_.reset();
  run_ = 0;
}

bool TemporalConsistency::Agree(const ClosureObservation& a, const ClosureObservation& b) const {
  if (a.map_from_match && b.map_from_match) {
    const Pose2D pa = Compose(*a.map_from_match, a.match_from_query);
    const Pose2D pb = Compose(*b.map_from_match, b.match_from_query);
    if (a.map_from_query && b.map_from_query) {
      // The loop corrections (where the closure puts the image, against where the image's own
      // pose says it is) must be the same: odometry drifts slowly.
      const Pose2D ca = Compose(pa, Inverse(*a.map_from_query));
      const Pose2D cb = Compose(pb, Inverse(*b.map_from_query));
      return std::hypot(ca.x - cb.x, ca.y - cb.y) <= options_.distance &&
             std::abs(WrapAngle(ca.theta - cb.theta)) <= options_.angle;
    }
    return std::hypot(pa.x - pb.x, pa.y - pb.y) <= options_.max_motion;
  }
  const uint32_t gap = a.match_id > b.match_id ? a.match_id - b.match_id : b.match_id - a.match_id;
  return gap <= options_.max_id_gap;
}

size_t TemporalConsistency::Pick(const std::vector<ClosureObservation>& candidates) const {
  if (last_) {
    for (size_t i = 0; i < candidates.size(); ++i) {
      if (Agree(*last_, candidates[i])) return i;
    }
  }
  return 0;
}

bool TemporalConsistency::Next(const std::optional<ClosureObservation>& closure) {
  if (!closure) {
    Reset();
    return false;
  }
  run_ = last_ && Agree(*last_, *closure) ? run_ + 1 : 1;
  last_ = closure;
  return run_ >= options_.required;
}

}  // namespace gtbow
