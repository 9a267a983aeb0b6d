// The online map behind the ROS localizer, ROS-free: keyframes (features, stamp, optional pose)
// in a BoW database (paper §III), loop-closure candidates with verified relative transforms,
// global localization against posed keyframes, and a map file that is written atomically.
//
// Images here are the floor seen from ABOVE: pixel (u, v) maps to the map plane through a
// rotation (geometry.h's FloorFromImage). A real downward camera's optical frame sees the floor
// mirrored; the ROS layer flips its rows before calling in (ros/conversions.h).
//
// Thread safety: every method may be called from any thread. Process() takes no lock (the
// heavy part: extraction and word assignment); the others hold mutex_ only for the bookkeeping
// and one query, so a caller never waits longer than one query plus one insertion.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <shared_mutex>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "ground_texture_bow/core/bow.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/features.h"
#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/core/pose.h"
#include "ground_texture_bow/core/vocabulary.h"

namespace gtbow {

struct LocalizerOptions {
  RetrievalConfig retrieval;          // a preset: features, word search, BoW options and
                                      // verification (K candidates, RANSAC, checks)
  double meters_per_pixel = 0.00025;  // ground sampling distance, metres per pixel (> 0)
  int threads = 1;                    // threads one image may use: descriptor assignment and
                                      // the query's blocks (1..64); answers do not depend on it
  // Keep each keyframe's descriptors (32 bytes per ORB keypoint, about 8 KB a keyframe) in the
  // map. They are needed by QueryKeyframe and by verification from descriptor matches
  // (verification.matches: descriptors); without them such verification uses word pairs
  // (effective_matches()). Warehouse maps drop them to fit (docs/RESULTS.md, issue 17).
  bool keep_descriptors = true;

  // Throws std::invalid_argument naming the first bad field.
  void Check() const;
};

// One database image. `map_from_camera` is the pose of the image (centre and u axis, as
// geometry.h's Pose2D) in the map, metres and radians; valid only with has_pose.
struct Keyframe {
  uint32_t id = 0;
  int64_t stamp_ns = 0;  // acquisition time, nanoseconds since the epoch
  bool has_pose = false;
  Pose2D map_from_camera;
  int width = 0;  // image size, pixels
  int height = 0;
  std::vector<Keypoint> keypoints;
  cv::Mat descriptors;  // kept so that a keyframe can be queried again by id
};

// An image ready to insert or query: its features and BoW vector.
struct ProcessedImage {
  ImageFeatures features;
  BowVector bow;
  int width = 0;
  int height = 0;
};

// A retrieved keyframe. With verification, `relative` holds match_from_query: the query
// image's pose in the match image's frame (metres, radians; floor_from_query of
// pose.h with the match at the origin) and its covariance.
struct Candidate {
  uint32_t id = 0;
  float score = 0.0f;
  int64_t stamp_ns = 0;
  bool has_pose = false;
  Pose2D map_from_camera;     // the keyframe's pose (has_pose)
  bool verified = false;      // verification was asked for and succeeded
  PoseEstimate relative;      // match_from_query (when verification was asked for)
  std::vector<Vec2> inliers;  // query pixels of the verified matches (for overlays)
};

// The candidate a loop closure is published for: the first verified one, or with the
// consensus on (LocalizationOptions::max_conflict_ratio) the verified one with the most inliers;
// -1 when none verified. The consensus itself is not applied to loop-closure candidates (Query):
// their keyframes' poses are usually odometry, and keyframes of two passes over the same place
// disagree by the drift between them (issue 15: measured on a drive, it refused most true
// closures). Global localization (Localize), against a map's poses, applies it; for loop
// closures the backend's consistency check and ~temporal_consistency take that role.
int LoopClosureCandidate(const std::vector<Candidate>& candidates,
                         const LocalizationOptions& options);

class Localizer {
 public:
  // `vocabulary_path` is recorded in saved maps (the map refers to the vocabulary, it does not
  // contain it). The vocabulary's search settings are set from options.retrieval.
  Localizer(std::shared_ptr<Vocabulary> vocabulary, std::string vocabulary_path,
            const LocalizerOptions& options);
  Localizer(const Localizer&) = delete;
  Localizer& operator=(const Localizer&) = delete;

  // Image sizes Process accepts: smaller images hold no feature (ORB's border alone is 31
  // pixels); larger ones would only cost memory and time (a 20-megapixel image is processed).
  static constexpr int kMinImageSide = 32;
  static constexpr int kMaxImagePixels = 64000000;

  // Extracts features and encodes them. Throws std::invalid_argument for an empty image, one
  // that is not 8-bit single-channel, or one outside the sizes above; an image without
  // features gives an empty vector.
  ProcessedImage Process(const cv::Mat& gray) const;
  // The same for features extracted elsewhere (a feature cache): encodes them for an image of
  // width x height pixels. Throws std::invalid_argument for sizes Process refuses.
  ProcessedImage Encode(ImageFeatures features, int width, int height) const;

  // Inserts a keyframe; returns its id.
  uint32_t Add(const ProcessedImage& image, int64_t stamp_ns, const std::optional<Pose2D>& pose);

  // The top `k` keyframes for an image, best first, optionally verified (relative poses).
  // Keyframes with ids in [exclude_from, exclude_to) are skipped (e.g. the query's own
  // recent past, which trivially overlaps it).
  std::vector<Candidate> Query(const ProcessedImage& image, size_t k, bool verify,
                               uint32_t exclude_from = 0, uint32_t exclude_to = 0) const;
  // The same for a stored keyframe (itself excluded). Throws std::out_of_range for an unknown id.
  std::vector<Candidate> QueryKeyframe(uint32_t id, size_t k, bool verify) const;

  // Global localization: verifies the top K candidates in rank order, skipping keyframes without
  // a pose, until one gives a pose with enough inliers (VerifyCandidates, as gtbow eval does).
  // The fix is estimate.floor_from_query, in the map frame; image is the keyframe.
  Localization Localize(const ProcessedImage& image) const;

  // Writes the map (vocabulary path and fingerprint, options, database, keyframes) atomically:
  // a failure leaves any existing file untouched. Throws std::runtime_error naming the path.
  void Save(const std::filesystem::path& path) const;
  // Replaces the map with a saved one. Throws std::runtime_error naming the file when it is
  // damaged, of another version, or made with another vocabulary or other BoW options; the
  // current map is kept then.
  void Load(const std::filesystem::path& path);
  // The vocabulary path recorded in a map file (to load the right vocabulary before Load).
  static std::string VocabularyPathOf(const std::filesystem::path& path);

  void Reset();  // forgets every keyframe

  size_t size() const;                                      // keyframes
  std::optional<Keyframe> KeyframeInfo(uint32_t id) const;  // a copy, without descriptors
  std::vector<Keyframe> Keyframes() const;                  // every keyframe, without features
  const Vocabulary& vocabulary() const { return *vocabulary_; }
  const std::string& vocabulary_path() const { return vocabulary_path_; }
  const LocalizerOptions& options() const { return options_; }

 private:
  ImageGeometry GeometryOf(int width, int height) const;
  // The keyframes' keypoints and descriptors, each pose at the origin (relative poses); under
  // mutex_.
  MapAccess RelativeAccess() const;
  std::vector<Candidate> QueryLocked(const BowVector& bow, int width, int height, size_t k,
                                     bool verify, uint32_t exclude_from, uint32_t exclude_to) const;

  std::shared_ptr<Vocabulary> vocabulary_;
  std::string vocabulary_path_;
  LocalizerOptions options_;
  std::unique_ptr<BowEncoder> encoder_;
  mutable std::shared_mutex mutex_;        // guards database_ and keyframes_
  std::unique_ptr<BowDatabase> database_;  // guarded by mutex_
  std::vector<Keyframe> keyframes_;        // by id; guarded by mutex_
};

}  // namespace gtbow
