#include "ground_texture_bow/core/maintenance.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <tuple>

namespace gtbow {
namespace {

// Packs a cell's two signed indices into one key (the high word holds i). The shift is done on
// unsigned values: shifting a negative signed value is undefined behaviour.
int64_t PackCell(int64_t i, int64_t j) {
  return static_cast<int64_t>((static_cast<uint64_t>(i) << 32) ^
                              (static_cast<uint64_t>(j) & 0xffffffffull));
}

}  // namespace

void MaintenanceOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("maintenance_") + what);
  };
  need(min_inliers >= 4, "min_inliers must be at least 4");
  need(refresh_below_inliers > min_inliers, "refresh_below_inliers must exceed min_inliers");
  need(std::isfinite(max_theta_sigma) && max_theta_sigma > 0, "max_theta_sigma must be positive");
  need(std::isfinite(place_fraction) && place_fraction > 0 && place_fraction <= 1,
       "place_fraction must be in (0, 1]");
  need(max_views_per_place >= 1 && max_views_per_place <= 100,
       "views_per_place must be in [1, 100]");
}

MapMaintainer::MapMaintainer(const MaintenanceOptions& options, const ImageGeometry& geometry)
    : options_(options) {
  options_.Check();
  if (!(geometry.meters_per_pixel > 0) || geometry.width <= 0 || geometry.height <= 0) {
    throw std::invalid_argument("MapMaintainer: the image geometry has no size or scale");
  }
  radius_ = options_.place_fraction * std::min(geometry.width, geometry.height) *
            geometry.meters_per_pixel;
}

int64_t MapMaintainer::CellKey(double x, double y) const {
  const auto i = static_cast<int64_t>(std::floor(x / radius_));
  const auto j = static_cast<int64_t>(std::floor(y / radius_));
  return PackCell(i, j);
}

void MapMaintainer::Track(uint32_t id, const Pose2D& pose, int64_t stamp_ns, bool maintained) {
  if (!std::isfinite(pose.x) || !std::isfinite(pose.y) || std::abs(pose.x) > 1e7 ||
      std::abs(pose.y) > 1e7) {
    return;  // cannot be placed
  }
  Forget(id);
  keyframes_[id] = Entry{pose, stamp_ns, stamp_ns, maintained};
  cells_[CellKey(pose.x, pose.y)].push_back(id);
}

void MapMaintainer::Forget(uint32_t id) {
  const auto it = keyframes_.find(id);
  if (it == keyframes_.end()) return;
  const auto cell = cells_.find(CellKey(it->second.pose.x, it->second.pose.y));
  if (cell != cells_.end()) {
    auto& ids = cell->second;
    ids.erase(std::remove(ids.begin(), ids.end(), id), ids.end());
    if (ids.empty()) cells_.erase(cell);
  }
  keyframes_.erase(it);
}

void MapMaintainer::Clear() {
  keyframes_.clear();
  cells_.clear();
}

std::vector<uint32_t> MapMaintainer::PlaceOf(const Pose2D& pose, bool views_only) const {
  std::vector<uint32_t> out;
  const auto ci = static_cast<int64_t>(std::floor(pose.x / radius_));
  const auto cj = static_cast<int64_t>(std::floor(pose.y / radius_));
  for (int64_t i = ci - 1; i <= ci + 1; ++i) {
    for (int64_t j = cj - 1; j <= cj + 1; ++j) {
      const auto cell = cells_.find(PackCell(i, j));
      if (cell == cells_.end()) continue;
      for (uint32_t id : cell->second) {
        const Entry& e = keyframes_.at(id);
        if (views_only && !e.maintained) continue;
        if (std::hypot(e.pose.x - pose.x, e.pose.y - pose.y) <= radius_) out.push_back(id);
      }
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

MaintenanceStep MapMaintainer::Observe(const Localization& fix, int64_t stamp_ns) {
  MaintenanceStep step;
  if (!fix.success) {
    step.reason = "no fix";
    return step;
  }
  const auto matched = keyframes_.find(fix.image);
  if (matched != keyframes_.end()) {
    matched->second.last_matched_ns = std::max(matched->second.last_matched_ns, stamp_ns);
  }
  if (fix.estimate.inliers >= options_.refresh_below_inliers) {
    step.reason = "floor unchanged";
    return step;
  }
  if (fix.estimate.inliers < options_.min_inliers ||
      !(fix.estimate.theta_sigma <= options_.max_theta_sigma)) {
    step.reason = "fix too weak to place a keyframe";
    return step;
  }
  step.add = true;
  std::vector<uint32_t> place = PlaceOf(fix.estimate.floor_from_query, true);
  const size_t room = static_cast<size_t>(options_.max_views_per_place - 1);
  if (place.size() > room) {
    // Matched longest ago first (then made longest ago, then the smaller id); the keyframe that
    // gave this fix was matched just now and goes last.
    std::sort(place.begin(), place.end(), [&](uint32_t a, uint32_t b) {
      const Entry& ea = keyframes_.at(a);
      const Entry& eb = keyframes_.at(b);
      return std::tie(ea.last_matched_ns, ea.stamp_ns, a) <
             std::tie(eb.last_matched_ns, eb.stamp_ns, b);
    });
    step.retire.assign(place.begin(), place.begin() + static_cast<long>(place.size() - room));
    for (uint32_t id : step.retire) Forget(id);
  }
  return step;
}

void TrackMap(const Localizer& localizer, MapMaintainer* maintainer) {
  for (const Keyframe& k : localizer.Keyframes()) {
    if (k.has_pose && !k.retired) {
      maintainer->Track(k.id, k.map_from_camera, k.stamp_ns, k.maintained);
    }
  }
}

std::optional<uint32_t> ApplyMaintenance(const MaintenanceStep& step, const Localization& fix,
                                         const ProcessedImage& view, int64_t stamp_ns,
                                         Localizer* localizer, MapMaintainer* maintainer) {
  for (uint32_t id : step.retire) localizer->Retire(id);
  if (!step.add) return std::nullopt;
  const Pose2D& pose = fix.estimate.floor_from_query;
  const uint32_t id = localizer->Add(view, stamp_ns, pose, Localizer::KeyframeSource::kMaintenance);
  maintainer->Track(id, pose, stamp_ns, true);
  return id;
}

}  // namespace gtbow
