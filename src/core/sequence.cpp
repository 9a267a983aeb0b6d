#include "ground_texture_bow/core/sequence.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

namespace gtbow {

double SameKeypointRadius(float size) { return std::max(2.0, 0.1 * static_cast<double>(size)); }

namespace {

// The keypoints taken so far, hashed on a grid of `cell` pixels, for the nearness test.
class TakenGrid {
 public:
  explicit TakenGrid(double cell) : cell_(cell) {}
  void Insert(float x, float y) { cells_[Key(Cell(x), Cell(y))].push_back({x, y}); }
  bool Near(float x, float y, double radius) const {
    const int reach = static_cast<int>(std::ceil(radius / cell_));
    const int cx = Cell(x), cy = Cell(y);
    for (int i = cx - reach; i <= cx + reach; ++i) {
      for (int j = cy - reach; j <= cy + reach; ++j) {
        const auto it = cells_.find(Key(i, j));
        if (it == cells_.end()) continue;
        for (const Vec2& p : it->second) {
          if (std::hypot(p.x - x, p.y - y) <= radius) return true;
        }
      }
    }
    return false;
  }

 private:
  int Cell(float v) const { return static_cast<int>(std::floor(v / cell_)); }
  static uint64_t Key(int i, int j) {
    return (static_cast<uint64_t>(static_cast<uint32_t>(i)) << 32) | static_cast<uint32_t>(j);
  }
  double cell_;
  std::unordered_map<uint64_t, std::vector<Vec2>> cells_;
};

}  // namespace

ImageFeatures CombineViews(const std::vector<const ImageFeatures*>& views,
                           const std::vector<Pose2D>& poses, const ImageGeometry& geometry) {
  if (views.empty() || views.size() != poses.size()) {
    throw std::invalid_argument("CombineViews: " + std::to_string(views.size()) + " views and " +
                                std::to_string(poses.size()) + " poses (one pose per view)");
  }
  if (!(geometry.meters_per_pixel > 0) || geometry.width <= 0 || geometry.height <= 0) {
    throw std::invalid_argument("CombineViews: the image geometry has no size or scale");
  }
  const ImageFeatures& newest = *views[0];
  for (size_t i = 0; i < views.size(); ++i) {
    const ImageFeatures& f = *views[i];
    const bool rows_ok = f.descriptors.empty() ? f.keypoints.empty()
                                               : f.descriptors.rows == static_cast<int>(f.size());
    if (!rows_ok) {
      throw std::invalid_argument("CombineViews: view " + std::to_string(i) + " has " +
                                  std::to_string(f.size()) + " keypoints and " +
                                  std::to_string(f.descriptors.rows) + " descriptor rows");
    }
    if (i > 0 && !f.descriptors.empty() && !newest.descriptors.empty() &&
        (f.descriptors.type() != newest.descriptors.type() ||
         f.descriptors.cols != newest.descriptors.cols)) {
      throw std::invalid_argument("CombineViews: view " + std::to_string(i) +
                                  "'s descriptors differ in type or width from view 0's");
    }
  }
  ImageFeatures out;
  out.keypoints = newest.keypoints;
  std::vector<cv::Mat> rows;
  if (!newest.descriptors.empty()) rows.push_back(newest.descriptors);
  TakenGrid taken(8.0);
  for (const Keypoint& k : newest.keypoints) taken.Insert(k.x, k.y);
  const double two_pi = 2.0 * M_PI;
  for (size_t i = 1; i < views.size(); ++i) {
    const ImageFeatures& f = *views[i];
    const double turn = poses[i].theta - poses[0].theta;
    std::vector<int> kept;
    std::vector<Keypoint> moved_all;
    for (size_t k = 0; k < f.size(); ++k) {
      const Keypoint& kp = f.keypoints[k];
      const Vec2 p =
          ImageFromFloor(poses[0], geometry, FloorFromImage(poses[i], geometry, {kp.x, kp.y}));
      // Odometry that places an image absurdly far (more than a million pixels away) relates
      // nothing: its keypoints are left out.
      if (!(std::abs(p.x) < 1e6 && std::abs(p.y) < 1e6)) continue;
      Keypoint moved = kp;
      moved.x = static_cast<float>(p.x);
      moved.y = static_cast<float>(p.y);
      if (taken.Near(moved.x, moved.y, SameKeypointRadius(kp.size))) continue;
      double a = std::fmod(static_cast<double>(kp.angle) + turn, two_pi);
      if (a < 0) a += two_pi;
      moved.angle = static_cast<float>(a);
      if (moved.angle >= static_cast<float>(two_pi)) moved.angle = 0.0f;
      moved_all.push_back(moved);
      kept.push_back(static_cast<int>(k));
    }
    // Taken only after the whole view: a view's own keypoints never hide each other.
    for (const Keypoint& m : moved_all) {
      taken.Insert(m.x, m.y);
      out.keypoints.push_back(m);
    }
    if (kept.empty()) continue;
    const cv::Mat& d = f.descriptors;
    cv::Mat part(static_cast<int>(kept.size()), d.cols, d.type());
    for (size_t r = 0; r < kept.size(); ++r) d.row(kept[r]).copyTo(part.row(static_cast<int>(r)));
    rows.push_back(part);
  }
  if (!rows.empty()) cv::vconcat(rows, out.descriptors);
  return out;
}

void SequenceOptions::Check() const {
  if (length < 1 || length > 20) {
    throw std::invalid_argument("sequence length must be in [1, 20], not " +
                                std::to_string(length));
  }
  if (!(max_span > 0) || !std::isfinite(max_span)) {
    throw std::invalid_argument("sequence max_span must be positive and finite metres");
  }
}

Localization SequenceFix(const SequenceOptions& options,
                         const std::function<Localization()>& single,
                         const std::function<Localization()>& combined, bool* used_combined) {
  if (used_combined != nullptr) *used_combined = false;
  if (options.single_first) {
    Localization own = single();
    if (own.success) return own;
  }
  if (used_combined != nullptr) *used_combined = true;
  return combined();
}

size_t ImagesInSpan(const std::vector<std::optional<Pose2D>>& newest_first,
                    const SequenceOptions& options) {
  if (newest_first.empty()) return 0;
  const std::optional<Pose2D>& newest = newest_first.front();
  if (!newest) return 1;
  const size_t most = std::min(newest_first.size(), static_cast<size_t>(options.length));
  for (size_t i = 1; i < most; ++i) {
    const std::optional<Pose2D>& o = newest_first[i];
    if (!o || std::hypot(o->x - newest->x, o->y - newest->y) > options.max_span) return i;
  }
  return most;
}

QuerySequence::QuerySequence(const SequenceOptions& options) : options_(options) {
  options_.Check();
}

void QuerySequence::Push(ProcessedImage image, const std::optional<Pose2D>& odometry) {
  if (!odometry || (!entries_.empty() && (entries_.front().image.width != image.width ||
                                          entries_.front().image.height != image.height))) {
    entries_.clear();  // no odometry to relate it, or another camera mode: start again
  }
  entries_.push_front({std::move(image), odometry});
  std::vector<std::optional<Pose2D>> odometries;
  for (const Entry& e : entries_) odometries.push_back(e.odometry);
  entries_.resize(ImagesInSpan(odometries, options_));
}

std::vector<const ProcessedImage*> QuerySequence::images() const {
  std::vector<const ProcessedImage*> out;
  for (const Entry& e : entries_) out.push_back(&e.image);
  return out;
}

std::vector<Pose2D> QuerySequence::poses() const {
  std::vector<Pose2D> out;
  for (const Entry& e : entries_) out.push_back(e.odometry.value_or(Pose2D{}));
  return out;
}

}  // namespace gtbow
