// Temporal consistency of loop closures (issue 15, part 4): a loop closure is published only
// once N consecutive images agree on the same place, as DBoW2 does (and ORB-SLAM3 with 3
// keyframes, Kimera-LCD): one image that happens to verify against a repeated patch of floor is
// not enough. N = 1 publishes every verified closure (the behaviour without it).
#pragma once

#include <cstdint>
#include <optional>
#include <stdexcept>
#include <vector>

#include "ground_texture_bow/core/geometry.h"

namespace gtbow {

struct TemporalConsistencyOptions {
  int required = 1;          // N: consecutive agreeing images before a closure is published
  double distance = 0.01;    // m: two closures agree when their loop corrections (with the
  double angle = 0.05;       // rad: images' own poses) differ by at most this much
  double max_motion = 0.1;   // m: without own poses, when their implied poses are this close
  uint32_t max_id_gap = 10;  // without keyframe poses either, when the matched ids are this close

  void Check() const;  // throws std::invalid_argument naming the bad field
};

// What one image's loop closure says about the place.
struct ClosureObservation {
  uint32_t match_id = 0;
  std::optional<Pose2D> map_from_match;  // the matched keyframe's pose, if it has one
  Pose2D match_from_query;               // the verified relative pose
  std::optional<Pose2D> map_from_query;  // the image's own pose (odometry / TF), if known
};

class TemporalConsistency {
 public:
  explicit TemporalConsistency(const TemporalConsistencyOptions& options);

  // The next image's closure (nullopt: the image gave none, which breaks the run). True when
  // this closure is to be published: it agrees with the previous image's and the run of
  // agreeing images has reached N.
  bool Next(const std::optional<ClosureObservation>& closure);
  int run() const { return run_; }  // consecutive agreeing images so far (0 after none)
  // Which of an image's verified candidates (best first) to follow: the first that agrees with
  // the previous image's closure, which continues the run, else the first (a new run). Two
  // passes over one place each give a candidate; keyframe poses that are odometry disagree by the
  // drift between the passes, so the run follows the pass it is on (as DBoW2 follows islands).
  // 0 for an empty list.
  size_t Pick(const std::vector<ClosureObservation>& candidates) const;
  void Reset();

  // Whether two consecutive closures point at the same place.
  bool Agree(const ClosureObservation& a, const ClosureObservation& b) const;

 private:
  TemporalConsistencyOptions options_;
  std::optional<ClosureObservation> last_;
  int run_ = 0;
};

}  // namespace gtbow
