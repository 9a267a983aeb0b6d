// The mapping pipeline, ROS-free: what the localizer node does with each image in mapping (and
// external) mode, in one place, so that `gtbow slam` and the tests run exactly what the node
// runs. For each image (its features, stamp and optional pose in the map frame) the mapper
//   1. queries the map for the top K keyframes, verified, leaving out the newest
//      `exclude_recent` keyframes of this session (the robot's own recent past, which trivially
//      overlaps it);
//   2. decides whether the image becomes a keyframe (moved keyframe_min_distance or turned
//      keyframe_min_angle since the last one when poses are known, else every Nth image) and
//      adds it;
//   3. picks the loop closure among the verified candidates (LoopClosureCandidate first, then by
//      inliers; with temporal consistency the one that continues the current run) and says
//      whether to publish it now or hold it until `temporal.required` images in a row agree.
// The node converts, looks up TF, calls Process and publishes what it returns.
#pragma once

#include <cstdint>
#include <mutex>
#include <optional>
#include <vector>

#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/temporal_consistency.h"

namespace gtbow {

struct MapperOptions {
  double keyframe_min_distance = 0.05;  // metres moved since the last keyframe (with poses)
  double keyframe_min_angle = 0.35;     // radians turned since the last keyframe (with poses)
  int keyframe_every_n = 10;            // without poses: every Nth processed image
  int exclude_recent = 20;              // newest keyframes not reported as loop closures
  TemporalConsistencyOptions temporal;  // N consecutive agreeing images per closure

  // Throws std::invalid_argument naming the bad field.
  void Check() const;
};

// What one image did.
struct MapperStep {
  std::vector<Candidate> candidates;  // the top K keyframes, verified, best first
  std::optional<uint32_t> keyframe;   // the id the image was added as
  // The verified candidate the loop closure follows (an index into candidates; -1: none
  // verified), and whether it is published now (`publish`) or held by temporal consistency.
  int closure = -1;
  bool publish = false;
  int run = 0;  // consecutive agreeing images so far, this one included (0: none)
  // When the closure's keyframe belongs to a map made before this session (loaded before the
  // mapper started or was last Reset), its pose is fixed: the match places the camera in the
  // map. `fix` is then that pose (the keyframe's pose composed with the relative one; the
  // covariance in the map frame) and the node publishes it as a fix (~pose), not as a loop
  // closure: a backend anchors the session in the old map with it.
  std::optional<PoseEstimate> fix;
};

class Mapper {
 public:
  // `localizer` must outlive the mapper; the mapper adds keyframes to it and queries it.
  Mapper(Localizer* localizer, const MapperOptions& options);

  // One image. insert: mapping mode (keyframes are added, the newest exclude_recent keyframes
  // are not candidates); false: external mode (a backend inserts keyframes itself: nothing is
  // added or excluded). `pose` is the image's pose in the map frame (odometry or TF), if known;
  // the keyframe is stored with it. `motion`, when given, is what the keyframe policy measures
  // the motion since the last keyframe with instead: odometry, smooth, where `pose` is in a map
  // frame that a SLAM backend's corrections move (the node maps in the backend's frame), so
  // that the keyframes chosen do not depend on when the corrections arrived.
  MapperStep Process(const ProcessedImage& image, int64_t stamp_ns,
                     const std::optional<Pose2D>& pose, bool insert = true,
                     const std::optional<Pose2D>& motion = std::nullopt);

  // Forgets the keyframe policy's state and the temporal run: after the map is loaded, reset
  // or replaced; the keyframes the map holds then are the earlier sessions' (fixed poses, never
  // left out as recent). Safe from any thread (it waits for a Process in progress).
  void Reset();
  // The first keyframe id of this session (the keyframes before it were in the map already).
  uint32_t session_start() const;

  const MapperOptions& options() const { return options_; }

 private:
  bool IsKeyframe(const std::optional<Pose2D>& pose);

  Localizer* localizer_;
  MapperOptions options_;
  mutable std::mutex mutex_;  // one Process at a time; guards everything below
  TemporalConsistency temporal_;
  std::optional<Pose2D> last_keyframe_pose_;
  uint64_t frames_since_keyframe_ = 0;
  uint32_t session_start_ = 0;
};

}  // namespace gtbow
