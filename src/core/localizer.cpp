#include "ground_texture_bow/core/localizer.h"

#include <cmath>
#include <cstring>
#include <mutex>
#include <stdexcept>

#include "ground_texture_bow/core/binary_io.h"

namespace gtbow {

namespace {

constexpr char kMapMagic[8] = {'G', 'T', 'B', 'W', 'M', 'A', 'P', '\0'};
constexpr uint32_t kMapVersion = 1;
constexpr uint64_t kMaxKeypoints = 1u << 16;  // per keyframe (keypoint ids are 16-bit)

void PutKeypoints(BinaryWriter* w, const std::vector<Keypoint>& k) { w->PutVector(k); }

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
}

Localizer::Localizer(std::shared_ptr<Vocabulary> vocabulary, std::string vocabulary_path,
                     const LocalizerOptions& options)
    : vocabulary_(std::move(vocabulary)),
      vocabulary_path_(std::move(vocabulary_path)),
      options_(options) {
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
  vocabulary_->set_checks(vo.checks);
  encoder_ = std::make_unique<BowEncoder>(*vocabulary_, options_.retrieval.bow);
  encoder_->set_threads(options_.threads);
  database_ = std::make_unique<BowDatabase>(encoder_->num_rows(), options_.retrieval.bow,
                                            vocabulary_->fingerprint());
  database_->set_query_threads(options_.threads);
}

ImageGeometry Localizer::GeometryOf(int width, int height) const {
  return {width, height, options_.meters_per_pixel};
}

ProcessedImage Localizer::Process(const cv::Mat& gray) const {
  if (gray.empty()) throw std::invalid_argument("empty image");
  if (gray.type() != CV_8UC1) {
    throw std::invalid_argument("expected an 8-bit single-channel image");
  }
  CheckImageSize(gray.cols, gray.rows);
  // One extractor per call: OpenCV's detectors are not documented as safe to share.
  const FeatureExtractor extractor(options_.retrieval.features);
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

uint32_t Localizer::Add(const ProcessedImage& image, int64_t stamp_ns,
                        const std::optional<Pose2D>& pose) {
  if (pose && !(std::isfinite(pose->x) && std::isfinite(pose->y) && std::isfinite(pose->theta))) {
    throw std::invalid_argument("keyframe pose has a non-finite value");
  }
  if (image.features.size() > kMaxKeypoints) {
    throw std::invalid_argument("more than 65536 keypoints in one image");
  }
  std::unique_lock<std::shared_mutex> lock(mutex_);
  const uint32_t id = database_->Add(image.bow);
  Keyframe k;
  k.id = id;
  k.stamp_ns = stamp_ns;
  k.has_pose = pose.has_value();
  if (pose) k.map_from_camera = *pose;
  k.width = image.width;
  k.height = image.height;
  k.keypoints = image.features.keypoints;
  k.descriptors = image.features.descriptors.clone();
  if (keyframes_.size() != id) {
    throw std::logic_error("keyframe ids out of step with the database");
  }
  keyframes_.push_back(std::move(k));
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

MapAccess Localizer::RelativeAccess() const {
  MapAccess map;
  map.keypoints = [this](uint32_t id) -> const std::vector<Keypoint>& {
    return keyframes_.at(id).keypoints;
  };
  map.descriptors = [this](uint32_t id) { return keyframes_.at(id).descriptors; };
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
  for (const QueryResult& r : results) {
    if (r.image >= exclude_from && r.image < exclude_to) continue;
    const Keyframe& kf = keyframes_.at(r.image);
    Candidate c;
    c.id = r.image;
    c.score = r.score;
    c.stamp_ns = kf.stamp_ns;
    c.has_pose = kf.has_pose;
    c.map_from_camera = kf.map_from_camera;
    if (verify) {
      if (kf.width != width || kf.height != height) {
        c.relative.reason = "the images differ in size";
      } else {
        // The relative pose: the match image at the origin.
        c.relative = VerifyCandidate(r, bow, RelativeAccess(), GeometryOf(width, height),
                                     options_.retrieval.verification, &c.inliers);
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
  Keyframe kf;
  {
    std::shared_lock<std::shared_mutex> lock(mutex_);
    if (id >= keyframes_.size()) {
      throw std::out_of_range("no keyframe " + std::to_string(id) + " (the map has " +
                              std::to_string(keyframes_.size()) + ")");
    }
    kf.keypoints = keyframes_[id].keypoints;
    kf.descriptors = keyframes_[id].descriptors;
    kf.width = keyframes_[id].width;
    kf.height = keyframes_[id].height;
  }
  ImageFeatures f;
  f.keypoints = std::move(kf.keypoints);
  f.descriptors = kf.descriptors;
  const BowVector bow = encoder_->Encode(f);  // outside the lock: the heavy part
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return QueryLocked(bow, kf.width, kf.height, k, verify, id, id + 1);
}

Localization Localizer::Localize(const ProcessedImage& image) const {
  Localization none;
  if (image.bow.source.empty()) {
    none.reason = "the image has no features";
    return none;
  }
  std::shared_lock<std::shared_mutex> lock(mutex_);
  if (keyframes_.empty()) {
    none.reason = "the map is empty";
    return none;
  }
  // The evaluation's own verification (pose.cpp), over this map's keyframes.
  MapAccess map = RelativeAccess();
  map.pose = [this](uint32_t id) { return keyframes_.at(id).map_from_camera; };
  map.unusable = [&](uint32_t id) -> std::string {
    const Keyframe& kf = keyframes_.at(id);
    if (!kf.has_pose) return "no pose";
    if (kf.width != image.width || kf.height != image.height) return "other image size";
    return "";
  };
  const auto results = database_->Query(
      image.bow, static_cast<size_t>(options_.retrieval.verification.candidates), true);
  return VerifyCandidates(results, image.bow, map, GeometryOf(image.width, image.height),
                          options_.retrieval.verification);
}

namespace {

// One keyframe's record in the map file, and its size in bytes (to announce the payload's size
// before streaming it).
void PutKeyframe(BinaryWriter* w, const Keyframe& k) {
  w->Put<int64_t>(k.stamp_ns);
  w->Put<uint8_t>(k.has_pose ? 1 : 0);
  w->Put<double>(k.map_from_camera.x);
  w->Put<double>(k.map_from_camera.y);
  w->Put<double>(k.map_from_camera.theta);
  w->Put<int32_t>(k.width);
  w->Put<int32_t>(k.height);
  PutKeypoints(w, k.keypoints);
  const cv::Mat d = k.descriptors.isContinuous() ? k.descriptors : k.descriptors.clone();
  w->Put<int32_t>(d.rows);
  w->Put<int32_t>(d.cols);
  w->Put<int32_t>(d.type());
  w->PutArray(d.data, d.empty() ? 0 : d.total() * d.elemSize());
}

uint64_t KeyframeBytes(const Keyframe& k) {
  const uint64_t descriptors =
      k.descriptors.empty() ? 0 : k.descriptors.total() * k.descriptors.elemSize();
  return 8 + 1 + 3 * 8 + 2 * 4 + (8 + k.keypoints.size() * sizeof(Keypoint)) + 3 * 4 +
         (8 + descriptors);
}

}  // namespace

void Localizer::Save(const std::filesystem::path& path) const {
  // Streamed into the file piece by piece (the database's rows, then one keyframe at a time):
  // a save needs no second copy of the map in memory.
  BinaryWriter head, w;
  std::unique_ptr<FramedFileWriter> file;
  {
    std::shared_lock<std::shared_mutex> lock(mutex_);
    head.PutString(vocabulary_path_);
    head.Put<uint64_t>(vocabulary_->fingerprint());
    head.PutString(FormatRetrievalConfig(options_.retrieval));
    head.Put<double>(options_.meters_per_pixel);
    uint64_t keyframe_bytes = 8;
    for (const Keyframe& k : keyframes_) keyframe_bytes += KeyframeBytes(k);
    database_->SerializeTo(
        [&](uint64_t database_bytes) {
          head.Put<uint64_t>(database_bytes);  // the database as one string (PutString's layout)
          file = std::make_unique<FramedFileWriter>(
              path, kMapMagic, kMapVersion, head.buffer().size() + database_bytes + keyframe_bytes);
          file->Write(head.buffer());
        },
        [&](const void* data, size_t size) { file->Write(data, size); });
    w.Put<uint64_t>(keyframes_.size());
    for (const Keyframe& k : keyframes_) {
      PutKeyframe(&w, k);
      if (w.buffer().size() >= (1u << 20)) {
        file->Write(w.buffer());
        w.buffer().clear();
      }
    }
    file->Write(w.buffer());
  }
  file->Commit();  // flush and rename without holding the map
}

std::string Localizer::VocabularyPathOf(const std::filesystem::path& path) {
  const FramedPayload payload = ReadFramedFile(path, kMapMagic, kMapVersion, "map");
  BinaryReader r(payload.data(), payload.size(), path.string());
  return r.GetString(1u << 16);
}

void Localizer::Load(const std::filesystem::path& path) {
  const FramedPayload payload = ReadFramedFile(path, kMapMagic, kMapVersion, "map");
  const std::string source = path.string();
  BinaryReader r(payload.data(), payload.size(), source);
  r.GetString(1u << 16);  // vocabulary path: informative (VocabularyPathOf)
  if (r.Get<uint64_t>() != vocabulary_->fingerprint()) {
    r.Fail("the map was built with another vocabulary than " + vocabulary_path_);
  }
  const std::string config = r.GetString(1u << 20);
  if (config != FormatRetrievalConfig(options_.retrieval)) {
    // Only the BoW options shape the stored index (the database checks them); feature
    // options change what new images look like. Both must match for answers to be consistent.
    // A map written before a key existed has that key's default.
    std::string diff;
    try {
      diff = RetrievalConfigDifference(ParseRetrievalConfig(config, "the map's options"), "the map",
                                       options_.retrieval, "this node");
    } catch (const std::exception& e) {
      r.Fail(std::string("the map's retrieval options cannot be read: ") + e.what());
    }
    if (!diff.empty()) {
      r.Fail("the map was built with other retrieval options (another preset or extractor): " +
             diff);
    }
  }
  const double mpp = r.Get<double>();
  if (mpp != options_.meters_per_pixel) {
    r.Fail("the map was built with meters_per_pixel " + std::to_string(mpp) + ", this node uses " +
           std::to_string(options_.meters_per_pixel));
  }
  const std::string db_blob = r.GetString(payload.size());
  auto db = std::make_unique<BowDatabase>(encoder_->num_rows(), options_.retrieval.bow,
                                          vocabulary_->fingerprint());
  db->set_query_threads(options_.threads);
  db->Deserialize(db_blob.data(), db_blob.size(), source + " (database)");
  const uint64_t n = r.Get<uint64_t>();
  if (n != db->next_id()) r.Fail("keyframe count does not match the database");
  std::vector<Keyframe> keyframes;
  keyframes.reserve(n);
  for (uint64_t i = 0; i < n; ++i) {
    Keyframe k;
    k.id = static_cast<uint32_t>(i);
    k.stamp_ns = r.Get<int64_t>();
    k.has_pose = r.Get<uint8_t>() != 0;
    k.map_from_camera.x = r.Get<double>();
    k.map_from_camera.y = r.Get<double>();
    k.map_from_camera.theta = r.Get<double>();
    k.width = r.Get<int32_t>();
    k.height = r.Get<int32_t>();
    k.keypoints = r.GetVector<Keypoint>(kMaxKeypoints);
    const int rows = r.Get<int32_t>(), cols = r.Get<int32_t>(), type = r.Get<int32_t>();
    const auto bytes = r.GetVector<uint8_t>(kMaxKeypoints * 512);
    if (rows < 0 || cols < 0 || static_cast<size_t>(rows) != k.keypoints.size() ||
        (type != CV_8U && type != CV_32F) ||
        bytes.size() != static_cast<size_t>(rows) * cols * (type == CV_8U ? 1 : 4) ||
        k.width <= 0 || k.height <= 0) {
      r.Fail("keyframe " + std::to_string(i) + " is malformed");
    }
    const Pose2D& p = k.map_from_camera;
    if (k.has_pose && !(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.theta))) {
      r.Fail("keyframe " + std::to_string(i) + " has a non-finite pose");
    }
    for (const Keypoint& kp : k.keypoints) {
      if (!(std::isfinite(kp.x) && std::isfinite(kp.y) && std::isfinite(kp.angle) &&
            std::isfinite(kp.size))) {
        r.Fail("keyframe " + std::to_string(i) + " has a non-finite keypoint");
      }
    }
    // Descriptors as this node's extractor makes them (ORB: 32 bytes; SIFT: 128 floats).
    const bool sift = options_.retrieval.features.type == FeatureType::kSift;
    if (rows > 0 && (type != (sift ? CV_32F : CV_8U) || cols != (sift ? 128 : 32))) {
      r.Fail("keyframe " + std::to_string(i) + " has descriptors of another kind (" +
             std::to_string(cols) + " columns) than this node's features");
    }
    if (rows > 0) {
      k.descriptors.create(rows, cols, type);
      std::memcpy(k.descriptors.data, bytes.data(), bytes.size());
    }
    keyframes.push_back(std::move(k));
  }
  if (r.remaining() != 0) r.Fail("trailing bytes after the keyframes");
  std::unique_lock<std::shared_mutex> lock(mutex_);
  database_ = std::move(db);
  keyframes_ = std::move(keyframes);
}

void Localizer::Reset() {
  auto db = std::make_unique<BowDatabase>(encoder_->num_rows(), options_.retrieval.bow,
                                          vocabulary_->fingerprint());
  db->set_query_threads(options_.threads);
  std::unique_lock<std::shared_mutex> lock(mutex_);
  database_ = std::move(db);
  keyframes_.clear();
}

size_t Localizer::size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return keyframes_.size();
}

std::optional<Keyframe> Localizer::KeyframeInfo(uint32_t id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  if (id >= keyframes_.size()) return std::nullopt;
  Keyframe k = keyframes_[id];
  k.descriptors = cv::Mat();
  return k;
}

std::vector<Keyframe> Localizer::Keyframes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<Keyframe> out;
  out.reserve(keyframes_.size());
  for (const Keyframe& k : keyframes_) {
    Keyframe c;
    c.id = k.id;
    c.stamp_ns = k.stamp_ns;
    c.has_pose = k.has_pose;
    c.map_from_camera = k.map_from_camera;
    c.width = k.width;
    c.height = k.height;
    out.push_back(std::move(c));
  }
  return out;
}

}  // namespace gtbow
