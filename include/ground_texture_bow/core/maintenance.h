// A map that keeps up with a floor that changes (lifelong mapping): while a robot localizes on a
// saved map, a view whose fix says the floor there has changed (few inliers left, but enough to
// place it) becomes a keyframe at its fix, so that the next visit finds the floor as it is now.
// The map's own keyframes (mapping: accurate poses, the floor as mapped, and what a cleaned
// floor looks like again) are never retired. Growth is bounded per place: when a place holds
// max_views_per_place maintained views, the one matched longest ago (never matched: the oldest)
// is retired from the index (Localizer::Retire) to make room.
//
// The policy is here, ROS-free, so that the node's maintenance mode and gtbow eval --maintain
// make the same decisions; the caller applies them (retire, add, Track the new keyframe).
// Read-only localization never constructs one.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/pose.h"

namespace gtbow {

struct MaintenanceOptions {
  // A fix with fewer inliers than this says the floor at its place has changed: the view is
  // added. A view of a floor as mapped verifies with far more (the whole overlap agrees).
  int refresh_below_inliers = 60;
  // A fix with fewer inliers than this is not trusted to place a keyframe (a wrong keyframe
  // would mislead every later visit); it still localizes the robot.
  int min_inliers = 12;
  // Nor is a fix whose rotation is less certain than this (radians, the fix's standard
  // deviation): a keyframe's error is passed on to every fix it gives later.
  double max_theta_sigma = 0.0026;  // 0.15 degrees
  // A place: keyframe centres within this fraction of the footprint's shorter side of the
  // view's fix.
  double place_fraction = 0.25;
  // Maintained views a place may hold, the new one included (the ones matched longest ago are
  // retired); the map's own keyframes there do not count.
  int max_views_per_place = 3;
  // Throws std::invalid_argument naming the bad field as the node's parameter
  // (maintenance_<field>; max_views_per_place: maintenance_views_per_place).
  void Check() const;
};

// What to do with one localized view: retire these keyframes, then (add) insert the view as a
// keyframe at the fix's pose and Track it.
struct MaintenanceStep {
  bool add = false;
  std::vector<uint32_t> retire;
  std::string reason;  // why nothing is added ("no fix", "floor unchanged", "fix too weak")
};

class MapMaintainer {
 public:
  MapMaintainer(const MaintenanceOptions& options, const ImageGeometry& geometry);

  // A keyframe of the map, last matched at `stamp_ns` (its own stamp when it is first tracked:
  // a map's keyframes count as matched when they were made); `maintained`: a view maintenance
  // added (Keyframe::maintained), which may be retired. Keyframes without a finite pose cannot
  // be placed and are not tracked.
  void Track(uint32_t id, const Pose2D& pose, int64_t stamp_ns, bool maintained);
  // A keyframe that left the map (retired, or the map was replaced: Clear).
  void Forget(uint32_t id);
  void Clear();

  // A view's localization at `stamp_ns`: the keyframe that gave the fix counts as matched then;
  // the step says whether the view becomes a keyframe and which keyframes make room for it.
  // The retired ones are forgotten here.
  MaintenanceStep Observe(const Localization& fix, int64_t stamp_ns);

  // Live keyframes within the place radius of `pose` (maintained views only with `views_only`),
  // by id.
  std::vector<uint32_t> PlaceOf(const Pose2D& pose, bool views_only = false) const;
  double place_radius() const { return radius_; }
  size_t tracked() const { return keyframes_.size(); }
  const MaintenanceOptions& options() const { return options_; }

 private:
  struct Entry {
    Pose2D pose;
    int64_t stamp_ns = 0;         // made
    int64_t last_matched_ns = 0;  // gave a fix (or made)
    bool maintained = false;
  };
  int64_t CellKey(double x, double y) const;
  MaintenanceOptions options_;
  double radius_;
  std::unordered_map<uint32_t, Entry> keyframes_;
  std::unordered_map<int64_t, std::vector<uint32_t>> cells_;  // cell of radius_ -> ids
};

// Tracks every live keyframe of `localizer` that has a pose (a map loaded, or the maintainer
// made): the map's own and the views maintenance added, as the map file records them.
void TrackMap(const Localizer& localizer, MapMaintainer* maintainer);

// A step applied to a Localizer, as the node's maintenance mode does: the retired keyframes
// taken out of the index, then, when the step adds, `view` (the image processed as a keyframe)
// added at the fix (KeyframeSource::kMaintenance) and tracked. Returns the new keyframe's id.
std::optional<uint32_t> ApplyMaintenance(const MaintenanceStep& step, const Localization& fix,
                                         const ProcessedImage& view, int64_t stamp_ns,
                                         Localizer* localizer, MapMaintainer* maintainer);

}  // namespace gtbow
