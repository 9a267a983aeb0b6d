#include "ground_texture_bow/core/mapper.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace gtbow {

void MapperOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(what);
  };
  need(keyframe_min_distance >= 0 && std::isfinite(keyframe_min_distance),
       "keyframe_min_distance must be >= 0");
  need(keyframe_min_angle >= 0 && std::isfinite(keyframe_min_angle),
       "keyframe_min_angle must be >= 0");
  need(keyframe_every_n >= 1, "keyframe_every_n must be >= 1");
  need(exclude_recent >= 0, "exclude_recent must be >= 0");
  try {
    temporal.Check();
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("temporal_*: ") + e.what());
  }
}

namespace {
const MapperOptions& Checked(const MapperOptions& o) {
  o.Check();
  return o;
}
}  // namespace

Mapper::Mapper(Localizer* localizer, const MapperOptions& options)
    : localizer_(localizer), options_(Checked(options)), temporal_(options.temporal) {
  if (localizer_ == nullptr) throw std::invalid_argument("Mapper: no localizer");
  session_start_ = static_cast<uint32_t>(localizer_->size());
}

void Mapper::Reset() {
  std::lock_guard<std::mutex> lock(mutex_);
  temporal_.Reset();
  last_keyframe_pose_.reset();
  frames_since_keyframe_ = 0;
  session_start_ = static_cast<uint32_t>(localizer_->size());
}

uint32_t Mapper::session_start() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return session_start_;
}

bool Mapper::IsKeyframe(const std::optional<Pose2D>& pose) {
  ++frames_since_keyframe_;
  bool take;
  if (localizer_->size() == 0) {
    take = true;
  } else if (pose && last_keyframe_pose_) {
    const double d = std::hypot(pose->x - last_keyframe_pose_->x, pose->y - last_keyframe_pose_->y);
    const double a = std::abs(std::remainder(pose->theta - last_keyframe_pose_->theta, 2 * M_PI));
    take = d >= options_.keyframe_min_distance || a >= options_.keyframe_min_angle;
  } else {
    take = frames_since_keyframe_ >= static_cast<uint64_t>(options_.keyframe_every_n);
  }
  if (take) {
    frames_since_keyframe_ = 0;
    if (pose) last_keyframe_pose_ = pose;
  }
  return take;
}

MapperStep Mapper::Process(const ProcessedImage& image, int64_t stamp_ns,
                           const std::optional<Pose2D>& pose, bool insert,
                           const std::optional<Pose2D>& motion) {
  std::lock_guard<std::mutex> lock(mutex_);
  MapperStep step;
  const uint32_t n = static_cast<uint32_t>(localizer_->size());
  const uint32_t recent = insert ? static_cast<uint32_t>(options_.exclude_recent) : 0;
  const LocalizationOptions& verification = localizer_->options().retrieval.verification;
  // The recent past of this session only: an earlier session's keyframes are never "recent".
  const uint32_t exclude_from = std::max(session_start_, n > recent ? n - recent : 0);
  step.candidates = localizer_->Query(image, static_cast<size_t>(verification.candidates), true,
                                      std::min(exclude_from, n), n);
  if (insert && IsKeyframe(motion ? motion : pose))
    step.keyframe = localizer_->Add(image, stamp_ns, pose);

  // The verified candidates in the order a closure is chosen: the preset's choice first, then
  // by inliers.
  const std::vector<Candidate>& cands = step.candidates;
  std::vector<size_t> order;
  const int preferred = LoopClosureCandidate(cands, verification);
  if (preferred >= 0) order.push_back(static_cast<size_t>(preferred));
  std::vector<size_t> others;
  for (size_t i = 0; i < cands.size(); ++i) {
    if (cands[i].verified && static_cast<int>(i) != preferred) others.push_back(i);
  }
  std::stable_sort(others.begin(), others.end(), [&](size_t a, size_t b) {
    return cands[a].relative.inliers > cands[b].relative.inliers;
  });
  order.insert(order.end(), others.begin(), others.end());
  std::vector<ClosureObservation> observed;
  for (size_t i : order) {
    const Candidate& c = cands[i];
    observed.push_back({c.id, c.has_pose ? std::optional<Pose2D>(c.map_from_camera) : std::nullopt,
                        c.relative.floor_from_query, pose});
  }
  // With temporal consistency, the candidate that continues the run.
  std::optional<ClosureObservation> seen;
  if (!observed.empty()) {
    const size_t pick = options_.temporal.required > 1 ? temporal_.Pick(observed) : 0;
    seen = observed[pick];
    step.closure = static_cast<int>(order[pick]);
  }
  step.publish = temporal_.Next(seen);
  step.run = temporal_.run();
  if (step.closure >= 0) {
    const Candidate& c = cands[static_cast<size_t>(step.closure)];
    if (c.id < session_start_ && c.has_pose) {
      // The camera in the map: the keyframe's fixed pose and the relative one; the relative
      // pose's covariance turned from the keyframe's frame into the map's.
      PoseEstimate fix = c.relative;
      fix.floor_from_query = Compose(c.map_from_camera, c.relative.floor_from_query);
      const double co = std::cos(c.map_from_camera.theta), si = std::sin(c.map_from_camera.theta);
      const double r[3][3] = {{co, -si, 0}, {si, co, 0}, {0, 0, 1}};
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
          double v = 0;
          for (int k = 0; k < 3; ++k) {
            for (int l = 0; l < 3; ++l) v += r[i][k] * c.relative.covariance[3 * k + l] * r[j][l];
          }
          fix.covariance[3 * i + j] = v;
        }
      }
      step.fix = fix;
    }
  }
  return step;
}

}  // namespace gtbow
