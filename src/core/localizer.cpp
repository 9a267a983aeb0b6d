#include "ground_texture_bow/core/localizer.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <stdexcept>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/sequence.h"
#include "keyframe_store.h"

namespace gtbow {

namespace {

constexpr uint64_t kMaxKeypoints = 1u << 16;  // per keyframe (keypoint ids are 16-bit)

void CheckImageSize(int width, int height) {
  const std::string size = std::to_string(width) + "x" + std::to_string(height);
  if (width < Localizer::kMinImageSide || height < Localizer::kMinImageSide) {
    throw std::invalid_argument("image " + size + " is too small for features (at least " +
                                std::to_string(Localizer::kMinImageSide) + " pixels a side)");
  }
  if (static_cast<double>(width) * height > Localizer::kMaxImagePixels) {
    throw std::invalid_argument("image " + size + " has more than " +
                                std::to_string(Localizer::kMaxImagePixels / 1000000) +
                                " megapixels");
  }
}

}  // namespace

void LocalizerOptions::Check() const {
  retrieval.Check();
  if (!(meters_per_pixel > 0.0) || !std::isfinite(meters_per_pixel)) {
    throw std::invalid_argument("meters_per_pixel must be positive and finite");
  }
  if (threads < 1 || threads > 64) throw std::invalid_argument("threads must be in 1..64");
  if (!(save_rate_mb == 0.0 || save_rate_mb >= 1.0) || !std::isfinite(save_rate_mb)) {
    throw std::invalid_argument("save_rate_mb must be 0 (unpaced) or at least 1 MB/s");
  }
}

Localizer::Localizer(std::shared_ptr<Vocabulary> vocabulary, std::string vocabulary_path,
                     const LocalizerOptions& options)
    : vocabulary_(std::move(vocabulary)),
      vocabulary_path_(std::move(vocabulary_path)),
      options_(options),
      meters_per_pixel_(options.meters_per_pixel) {
  if (!vocabulary_) throw std::invalid_argument("Localizer: no vocabulary");
  options_.Check();
  // The extractor first: a preset for other features (SIFT, say) also asks for another metric,
  // and the features are the root of the difference.
  CheckVocabularyExtractor(*vocabulary_, vocabulary_path_, options_.retrieval.features);
  const VocabularyOptions& vo = options_.retrieval.vocabulary;
  if (vo.kind != vocabulary_->kind() || vo.metric != vocabulary_->metric()) {
    throw std::invalid_argument(
        "the preset asks for a " + VocabularyKindName(vo.kind) + "/" + MetricName(vo.metric) +
        " vocabulary (vocabulary.kind, " + "vocabulary.metric), " + vocabulary_path_ + " is " +
        VocabularyKindName(vocabulary_->kind()) + "/" + MetricName(vocabulary_->metric()));
  }
  vocabulary_->set_search(vo.ann, vo.nprobe);
  vocabulary_->set_search_bound(vo.ivf_bound);
  vocabulary_->set_checks(vo.checks);
  encoder_ = std::make_unique<BowEncoder>(*vocabulary_, options_.retrieval.bow);
  encoder_->set_threads(options_.threads);
  const bool sift = options_.retrieval.features.type == FeatureType::kSift;
  descriptor_cols_ = sift ? 128 : 32;
  descriptor_type_ = sift ? CV_32F : CV_8U;
  verification_ = options_.retrieval.verification;
  if (!options_.keep_descriptors) {
    // Without descriptors in the map: the retrieval's word pairs, and neither guided matching
    // nor its repeat checks (both match descriptors).
    verification_.matches = MatchSource::kWords;
    verification_.guided_radius = 0.0;
    verification_.guided_repeat_check = false;
    verification_.plain_repeat_below = 0;
  }
  database_ = NewDatabase();
  keyframes_ = NewStore();
}

Localizer::~Localizer() = default;

std::unique_ptr<BowDatabase> Localizer::NewDatabase() const {
  auto db = std::make_unique<BowDatabase>(encoder_->num_rows(), options_.retrieval.bow,
                                          vocabulary_->fingerprint());
  db->set_query_threads(options_.threads);
  return db;
}

size_t Localizer::PayloadStride() const {
  return sizeof(detail::PackedKeypoint) +
         (options_.keep_descriptors
              ? static_cast<size_t>(descriptor_cols_) * CV_ELEM_SIZE(descriptor_type_)
              : 0);
}

std::unique_ptr<detail::KeyframeStore> Localizer::NewStore() const {
  return std::make_unique<detail::KeyframeStore>(PayloadStride());
}

ImageGeometry Localizer::GeometryOf(int width, int height) const {
  return {width, height, meters_per_pixel()};
}

ProcessedImage Localizer::Process(const cv::Mat& gray, ImageUse use) const {
  if (gray.empty()) throw std::invalid_argument("empty image");
  if (gray.type() != CV_8UC1) {
    throw std::invalid_argument("expected an 8-bit single-channel image");
  }
  CheckImageSize(gray.cols, gray.rows);
  // One extractor per call: OpenCV's detectors are not documented as safe to share.
  const FeatureExtractor extractor(use == ImageUse::kQuery
                                       ? QueryFeatureOptions(options_.retrieval.features)
                                       : options_.retrieval.features);
  return Encode(extractor.Extract(gray), gray.cols, gray.rows);
}

ProcessedImage Localizer::Encode(ImageFeatures features, int width, int height) const {
  CheckImageSize(width, height);
  ProcessedImage p;
  p.features = std::move(features);
  p.bow = encoder_->Encode(p.features);
  p.width = width;
  p.height = height;
  return p;
}

ProcessedImage Localizer::Combine(const std::vector<const ProcessedImage*>& images,
                                  const std::vector<Pose2D>& poses) const {
  if (images.empty()) throw std::invalid_argument("a sequence query needs at least one image");
  std::vector<const ImageFeatures*> views;
  for (const ProcessedImage* im : images) {
    if (im->width != images[0]->width || im->height != images[0]->height) {
      throw std::invalid_argument("a sequence query's images differ in size (" +
                                  std::to_string(im->width) + " x " + std::to_string(im->height) +
                                  " and " + std::to_string(images[0]->width) + " x " +
                                  std::to_string(images[0]->height) + ")");
    }
    views.push_back(&im->features);
  }
  const ImageGeometry g = GeometryOf(images[0]->width, images[0]->height);
  ProcessedImage out = Encode(CombineViews(views, poses, g), g.width, g.height);
  out.combined = true;
  return out;
}

uint32_t Localizer::Add(const ProcessedImage& image, int64_t stamp_ns,
                        const std::optional<Pose2D>& pose, KeyframeSource source) {
  if (pose && !(std::isfinite(pose->x) && std::isfinite(pose->y) && std::isfinite(pose->theta))) {
    throw std::invalid_argument("keyframe pose has a non-finite value");
  }
  if (image.features.size() > kMaxKeypoints) {
    throw std::invalid_argument("more than 65536 keypoints in one image");
  }
  if (image.features.size() > static_cast<size_t>(options_.retrieval.features.num_features)) {
    throw std::invalid_argument(
        "a keyframe with " + std::to_string(image.features.size()) +
        " keypoints, more than features.num_features " +
        std::to_string(options_.retrieval.features.num_features) +
        " (an image processed as a query: process it as a keyframe to add it)");
  }
  CheckImageSize(image.width, image.height);
  const cv::Mat& d = image.features.descriptors;
  if (options_.keep_descriptors && !image.features.keypoints.empty() &&
      (d.rows != static_cast<int>(image.features.size()) || d.cols != descriptor_cols_ ||
       d.type() != descriptor_type_)) {
    throw std::invalid_argument("keyframe descriptors do not match its keypoints and extractor");
  }
  // Packed outside the lock: the store keeps what the file keeps.
  detail::KeyframeRecord record;
  record.stamp_ns = stamp_ns;
  if (source == KeyframeSource::kMaintenance) record.flags |= detail::KeyframeRecord::kMaintained;
  if (pose) {
    record.flags |= detail::KeyframeRecord::kHasPose;
    record.x = pose->x;
    record.y = pose->y;
    record.theta = pose->theta;
  }
  record.width = static_cast<uint32_t>(image.width);
  record.height = static_cast<uint32_t>(image.height);
  record.num_keypoints = static_cast<uint32_t>(image.features.size());
  const std::string payload =
      detail::MakePayload(image.features.keypoints, options_.keep_descriptors ? d : cv::Mat(),
                          record.width, record.height);
  std::unique_lock<std::shared_mutex> lock(mutex_);
  repeats_.Clear();  // the map changes: the copies its repeat checks kept too
  const uint32_t id = database_->Add(image.bow);
  if (keyframes_->size() != id) {
    throw std::logic_error("keyframe ids out of step with the database");
  }
  keyframes_->Append(record, payload);
  return id;
}

int LoopClosureCandidate(const std::vector<Candidate>& candidates,
                         const LocalizationOptions& options) {
  int best = -1;
  for (size_t i = 0; i < candidates.size(); ++i) {
    if (!candidates[i].verified) continue;
    if (options.max_conflict_ratio <= 0.0) return static_cast<int>(i);
    if (best < 0 || candidates[i].relative.inliers > candidates[best].relative.inliers)
      best = static_cast<int>(i);
  }
  return best;
}

detail::KeyframeView Localizer::View(uint32_t id) const { return keyframes_->Get(id); }

std::optional<Pose2D> Localizer::PoseOf(uint32_t id, const detail::KeyframeRecord& record) const {
  if (moved_ && id < moved_->size() && !std::isnan((*moved_)[id].x)) return (*moved_)[id];
  if ((record.flags & detail::KeyframeRecord::kHasPose) == 0) return std::nullopt;
  return Pose2D{record.x, record.y, record.theta};
}

size_t Localizer::UpdateKeyframePoses(const std::vector<KeyframePose>& poses) {
  for (const KeyframePose& p : poses) {
    if (!(std::isfinite(p.map_from_camera.x) && std::isfinite(p.map_from_camera.y) &&
          std::isfinite(p.map_from_camera.theta))) {
      throw std::invalid_argument("the pose given to keyframe " + std::to_string(p.id) +
                                  " has a non-finite value");
    }
  }
  // The new table is built outside the map's lock (a copy of a million poses takes
  // milliseconds) and swapped in under it, unless the map changed meanwhile.
  std::lock_guard<std::mutex> one(update_mutex_);
  for (;;) {
    std::shared_ptr<const std::vector<Pose2D>> old;
    uint64_t generation;
    std::vector<uint8_t> known(poses.size(), 0);  // the id exists with this stamp
    size_t size;
    {
      std::shared_lock<std::shared_mutex> lock(mutex_);
      old = moved_;
      generation = generation_;
      size = keyframes_->size();
      for (size_t i = 0; i < poses.size(); ++i) {
        known[i] = poses[i].id < size && View(poses[i].id).record->stamp_ns == poses[i].stamp_ns;
      }
    }
    auto table = std::make_shared<std::vector<Pose2D>>(old ? *old : std::vector<Pose2D>());
    table->resize(size, Pose2D{std::nan(""), 0, 0});
    size_t applied = 0;
    for (size_t i = 0; i < poses.size(); ++i) {
      if (!known[i]) continue;  // a keyframe added without a pose gets one too
      (*table)[poses[i].id] = poses[i].map_from_camera;
      ++applied;
    }
    std::unique_lock<std::shared_mutex> lock(mutex_);
    if (generation_ != generation || moved_ != old) continue;  // a reset or load: again
    if (applied > 0) {
      repeats_.Clear();  // the poses move: the copies its repeat checks kept too
      moved_ = std::move(table);
      poses_optimised_ = true;
    }
    return applied;
  }
}

void Localizer::SetPoseFrame(const std::string& frame) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  pose_frame_ = frame;
}

std::string Localizer::pose_frame() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return pose_frame_;
}

bool Localizer::poses_optimised() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return poses_optimised_;
}

std::string Localizer::Damaged(uint32_t id) const {
  const detail::KeyframeView v = View(id);
  if (v.verify && Checksum64(v.payload, v.payload_bytes) != v.record->payload_checksum) {
    return "keyframe " + std::to_string(id) +
           "'s stored keypoints and descriptors fail their checksum";
  }
  return "";
}

// GTBOW_PREFETCH_PAYLOADS=0 turns the prefetch off, for side-by-side measurements (bench-map).
void Localizer::PrefetchPayloads(const std::vector<QueryResult>& results, size_t n) const {
  static const bool on = [] {
    const char* v = std::getenv("GTBOW_PREFETCH_PAYLOADS");
    return v == nullptr || std::string(v) != "0";
  }();
  if (!on) return;
  for (size_t i = 0; i < std::min(n, results.size()); ++i) {
    const detail::KeyframeView v = View(results[i].image);
    if (v.verify) AdviseWillNeed(v.payload, v.payload_bytes);
  }
}

ImageFeatures Localizer::StoredFeatures(const detail::KeyframeView& v) const {
  ImageFeatures f;
  f.keypoints = detail::PayloadKeypoints(v);
  f.descriptors = detail::PayloadDescriptors(v, descriptor_cols_, descriptor_type_).clone();
  return f;
}

MapAccess Localizer::RelativeAccess() const {
  MapAccess map;
  map.keypoints = [this](uint32_t id) { return detail::PayloadKeypoints(View(id)); };
  map.descriptors = [this](uint32_t id) {
    return detail::PayloadDescriptors(View(id), descriptor_cols_, descriptor_type_);
  };
  map.pose = [](uint32_t) { return Pose2D{}; };
  return map;
}

std::vector<Candidate> Localizer::QueryLocked(const BowVector& bow, int width, int height, size_t k,
                                              bool verify, uint32_t exclude_from,
                                              uint32_t exclude_to) const {
  std::vector<Candidate> out;
  if (bow.source.empty() || k == 0) return out;
  const size_t excluded = exclude_to > exclude_from ? exclude_to - exclude_from : 0;
  const auto results = database_->Query(bow, k + excluded, verify);
  if (verify) PrefetchPayloads(results, k + excluded);
  for (const QueryResult& r : results) {
    if (r.image >= exclude_from && r.image < exclude_to) continue;
    const detail::KeyframeRecord& kf = *View(r.image).record;
    Candidate c;
    c.id = r.image;
    c.score = r.score;
    c.stamp_ns = kf.stamp_ns;
    const std::optional<Pose2D> pose = PoseOf(r.image, kf);
    c.has_pose = pose.has_value();
    if (pose) c.map_from_camera = *pose;
    if (verify) {
      std::string damaged;
      if (kf.width != static_cast<uint32_t>(width) || kf.height != static_cast<uint32_t>(height)) {
        c.relative.reason = "the images differ in size";
      } else if (!(damaged = Damaged(r.image)).empty()) {
        c.relative.reason = damaged;
      } else {
        // The relative pose: the match image at the origin.
        c.relative = VerifyCandidate(r, bow, RelativeAccess(), GeometryOf(width, height),
                                     verification_, &c.inliers);
        c.verified = c.relative.success;
      }
    }
    out.push_back(std::move(c));
    if (out.size() == k) break;
  }
  return out;
}

std::vector<Candidate> Localizer::Query(const ProcessedImage& image, size_t k, bool verify,
                                        uint32_t exclude_from, uint32_t exclude_to) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return QueryLocked(image.bow, image.width, image.height, k, verify, exclude_from, exclude_to);
}

std::vector<Candidate> Localizer::QueryKeyframe(uint32_t id, size_t k, bool verify) const {
  ImageFeatures f;
  int width = 0, height = 0;
  {
    std::shared_lock<std::shared_mutex> lock(mutex_);
    if (id >= keyframes_->size()) {
      throw std::out_of_range("no keyframe " + std::to_string(id) + " (the map has " +
                              std::to_string(keyframes_->size()) + ")");
    }
    if (!options_.keep_descriptors) {
      throw std::invalid_argument(
          "this map keeps no keyframe descriptors (keep_descriptors false): keyframe " +
          std::to_string(id) + " cannot be queried again");
    }
    const std::string damaged = Damaged(id);
    if (!damaged.empty()) throw std::runtime_error(damaged);
    const detail::KeyframeView v = View(id);
    f = StoredFeatures(v);
    width = static_cast<int>(v.record->width);
    height = static_cast<int>(v.record->height);
  }
  const BowVector bow = encoder_->Encode(f);  // outside the lock: the heavy part
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return QueryLocked(bow, width, height, k, verify, id, id + 1);
}

Localization Localizer::Localize(const ProcessedImage& image) const {
  Localization none;
  if (image.bow.source.empty()) {
    none.reason = "the image has no features";
    return none;
  }
  std::shared_lock<std::shared_mutex> lock(mutex_);
  if (keyframes_->size() == 0) {
    none.reason = "the map is empty";
    return none;
  }
  // The evaluation's own verification (pose.cpp), over this map's keyframes.
  MapAccess map = RelativeAccess();
  map.pose = [this](uint32_t id) { return PoseOf(id, *View(id).record).value_or(Pose2D{}); };
  map.unusable = [&](uint32_t id) -> std::string {
    const detail::KeyframeRecord& kf = *View(id).record;
    if (!PoseOf(id, kf)) return "no pose";
    if (kf.width != static_cast<uint32_t>(image.width) ||
        kf.height != static_cast<uint32_t>(image.height))
      return "other image size";
    return Damaged(id);
  };
  // A sequence query's combined view: without guided matching unless guided_combined; an
  // escalating query's first pass without it.
  const LocalizationOptions lo = image.combined     ? CombinedViewOptions(verification_)
                                 : image.first_pass ? FirstPassOptions(verification_)
                                                    : verification_;
  if (lo.guided_repeat_check) {
    // A keyframe as a query (its stored keypoints and descriptors, encoded; QueryKeyframe's),
    // for the repeat check of guided matching; mutex_ is held (shared) throughout.
    map.query_of = [this](uint32_t id) {
      if (!options_.keep_descriptors) return BowVector();
      return encoder_->Encode(StoredFeatures(View(id)));
    };
    map.retrieve = [this](const BowVector& q, uint32_t self, size_t k) {
      auto r = database_->Query(q, k + 1, true);
      r.erase(std::remove_if(r.begin(), r.end(),
                             [self](const QueryResult& x) { return x.image == self; }),
              r.end());
      PrefetchPayloads(r, r.size());
      return r;
    };
    map.repeats = &repeats_;
  }
  const auto results = database_->Query(image.bow, static_cast<size_t>(lo.candidates), true);
  PrefetchPayloads(results, results.size());
  return VerifyCandidates(results, image.bow, map, GeometryOf(image.width, image.height), lo);
}

Localization Localizer::LocalizeImage(const cv::Mat& gray, ProcessedImage* image, bool* escalated,
                                      EscalationBackoff* backoff) const {
  ProcessedImage used;
  const Localization fix = EscalatedFix(
      escalates(), verification_,
      [&] {
        used = Process(gray, ImageUse::kKeyframe);
        used.first_pass = true;
        return Localize(used);
      },
      [&] {
        used = Process(gray, ImageUse::kQuery);
        return Localize(used);
      },
      escalated, backoff);
  if (image != nullptr) *image = std::move(used);
  return fix;
}

void Localizer::Reset() {
  std::shared_ptr<BowDatabase> db = NewDatabase();
  auto store = NewStore();
  std::unique_lock<std::shared_mutex> lock(mutex_);
  repeats_.Clear();  // the map changes: the copies its repeat checks kept too
  database_.swap(db);
  keyframes_.swap(store);
  moved_.reset();
  poses_optimised_ = false;
  ++generation_;
  lock.unlock();  // the old map is freed without holding up callers
}

bool Localizer::Retire(uint32_t id) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  if (id >= keyframes_->size() || !database_->Remove(id)) return false;
  repeats_.Clear();  // the map changes: the copies its repeat checks kept too
  return true;
}

void Localizer::SetMetersPerPixel(double meters_per_pixel) {
  if (!(meters_per_pixel > 0.0) || !std::isfinite(meters_per_pixel)) {
    throw std::invalid_argument("meters_per_pixel must be positive and finite, not " +
                                std::to_string(meters_per_pixel));
  }
  std::unique_lock<std::shared_mutex> lock(mutex_);
  repeats_.Clear();  // the map changes: the copies its repeat checks kept too
  if (meters_per_pixel == meters_per_pixel_.load()) return;
  if (keyframes_->size() > 0) {
    throw std::logic_error("the map holds " + std::to_string(keyframes_->size()) +
                           " keyframes made at " + std::to_string(meters_per_pixel_.load()) +
                           " m/px; its scale cannot change to " + std::to_string(meters_per_pixel));
  }
  meters_per_pixel_ = meters_per_pixel;
}

size_t Localizer::size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return keyframes_->size();
}

size_t Localizer::live_size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return database_->size();
}

size_t Localizer::HeapBytes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return database_->MemoryBytes() - database_->MappedBytes() + keyframes_->MemoryBytes();
}

namespace {

Keyframe KeyframeOf(uint32_t id, const detail::KeyframeRecord& r, const std::optional<Pose2D>& pose,
                    bool retired) {
  Keyframe k;
  k.id = id;
  k.retired = retired;
  k.maintained = (r.flags & detail::KeyframeRecord::kMaintained) != 0;
  k.stamp_ns = r.stamp_ns;
  k.has_pose = pose.has_value();
  if (pose) k.map_from_camera = *pose;
  k.width = static_cast<int>(r.width);
  k.height = static_cast<int>(r.height);
  return k;
}

}  // namespace

std::optional<Keyframe> Localizer::KeyframeInfo(uint32_t id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  if (id >= keyframes_->size()) return std::nullopt;
  const detail::KeyframeView v = View(id);
  Keyframe k = KeyframeOf(id, *v.record, PoseOf(id, *v.record), !database_->Contains(id));
  if (Damaged(id).empty()) k.keypoints = detail::PayloadKeypoints(v);
  return k;
}

std::vector<Keyframe> Localizer::Keyframes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<Keyframe> out;
  out.reserve(keyframes_->size());
  for (uint32_t id = 0; id < keyframes_->size(); ++id) {
    const detail::KeyframeRecord& r = *View(id).record;
    out.push_back(KeyframeOf(id, r, PoseOf(id, r), !database_->Contains(id)));
  }
  return out;
}

std::vector<Keypoint> StoredKeypoints(const std::vector<Keypoint>& keypoints, int width,
                                      int height) {
  const double step = detail::CoordinateStep(static_cast<uint32_t>(std::max(width, 0)),
                                             static_cast<uint32_t>(std::max(height, 0)));
  std::vector<Keypoint> out;
  out.reserve(keypoints.size());
  for (const Keypoint& k : keypoints) {
    out.push_back(detail::UnpackKeypoint(detail::PackKeypoint(k, step), step));
  }
  return out;
}

}  // namespace gtbow
