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
#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
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
  // The pace of Save's writer, MB/s (0: as fast as the disk allows). A save of a warehouse map
  // (gigabytes) written at full speed slows the queries and insertions running beside it on a
  // small computer; paced, they keep about their speed and the save takes longer (6.4 GB: 33-46 s
  // at 200 MB/s, measured). Slower disks than the pace are not slowed further (docs/RESULTS.md,
  // "The writer paced"). 0, or at least 1 MB/s.
  double save_rate_mb = 200;

  // Throws std::invalid_argument naming the first bad field.
  void Check() const;
};

namespace detail {
class KeyframeStore;
struct KeyframeRecord;
struct KeyframeView;
}  // namespace detail

// One database image. `map_from_camera` is the pose of the image (centre and u axis, as
// geometry.h's Pose2D) in the map, metres and radians; valid only with has_pose.
struct Keyframe {
  uint32_t id = 0;
  int64_t stamp_ns = 0;  // acquisition time, nanoseconds since the epoch
  bool has_pose = false;
  Pose2D map_from_camera;
  int width = 0;  // image size, pixels
  int height = 0;
  bool maintained = false;          // added by map maintenance (KeyframeSource::kMaintenance)
  bool retired = false;             // Localizer::Retire took it out of the index
  std::vector<Keypoint> keypoints;  // as the map stores them (StoredKeypoints)
};

// Keypoints as a map stores them (8 bytes each): x and y in steps of max(width, height) / 65535
// pixels, orientation in steps of 2 pi / 4096, size in 1/16 pixel, pyramid level -1..14, no
// detector score. Verification reads a map's keypoints through this; gtbow eval applies it to
// its map images too, so that what it measures is what the node does.
std::vector<Keypoint> StoredKeypoints(const std::vector<Keypoint>& keypoints, int width,
                                      int height);

// How a Save went: how long it held the map's lock to seal what it writes, and to swap the heap
// copy for the written file afterwards (the only waits it imposes on Add and queries), and how
// long writing took (no lock held).
struct SaveStats {
  uint64_t keyframes = 0;
  uint64_t bytes = 0;
  double seal_ms = 0;   // lock held: tails sealed
  double write_ms = 0;  // no lock: the file written, flushed and mapped
  // The end of write_ms: the file flushed, synced, mapped and renamed (commit_ms), then the
  // index's pages mapped into the process (populate_ms).
  double commit_ms = 0, populate_ms = 0;
  double swap_ms = 0;  // lock held: the index and keyframes pointed at the file
  double free_ms = 0;  // no lock, after the swap: the heap copies the file replaced, freed
};

// What a map file's header says (Localizer::ReadMapInfo), for either format version.
struct MapFileInfo {
  uint32_t version = 0;  // 1: loaded whole, to convert; 2 and 3: memory-mapped (3 adds the
                         // frame of the poses and whether they were optimised)
  std::string vocabulary_path;
  uint64_t vocabulary_fingerprint = 0;
  std::string retrieval_config;  // FormatRetrievalConfig's text of the map's preset
  double meters_per_pixel = 0;
  uint64_t keyframes = 0;
  bool descriptors = false;  // the map keeps keyframe descriptors
  // The frame the keyframe poses are in ("" when the map does not say: version 1 and 2), and
  // whether a SLAM backend's optimisation placed them (Localizer::UpdateKeyframePoses) rather
  // than the poses the keyframes were added with (odometry or TF).
  std::string pose_frame;
  bool poses_optimised = false;
  uint64_t file_bytes = 0;
};

// A keyframe's new pose from a SLAM backend (Localizer::UpdateKeyframePoses): the keyframe is
// named by its id and its stamp, so that an update made for another map (one reset or loaded
// since) changes nothing.
struct KeyframePose {
  uint32_t id = 0;
  int64_t stamp_ns = 0;
  Pose2D map_from_camera;
};

// An image ready to insert or query: its features and BoW vector.
struct ProcessedImage {
  ImageFeatures features;
  BowVector bow;
  int width = 0;
  int height = 0;
  bool combined = false;  // a sequence query's combined view (Combine; CombinedViewOptions)
  // An escalating query's first pass (LocalizeImage; FirstPassOptions): extracted as a keyframe
  // is, verified without guided matching.
  bool first_pass = false;
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
  ~Localizer();
  Localizer(const Localizer&) = delete;
  Localizer& operator=(const Localizer&) = delete;

  // Image sizes Process accepts: smaller images hold no feature (ORB's border alone is 31
  // pixels); larger ones would only cost memory and time (a 20-megapixel image is processed).
  static constexpr int kMinImageSide = 32;
  static constexpr int kMaxImagePixels = 64000000;

  // What an image is processed for: a keyframe (mapping: it is queried, then added), or a
  // query alone (localization, the query services), extracted with
  // features.query_num_features keypoints when that is set.
  enum class ImageUse { kKeyframe, kQuery };
  // Extracts features and encodes them. Throws std::invalid_argument for an empty image, one
  // that is not 8-bit single-channel, or one outside the sizes above; an image without
  // features gives an empty vector.
  ProcessedImage Process(const cv::Mat& gray, ImageUse use = ImageUse::kKeyframe) const;
  // The same for features extracted elsewhere (a feature cache): encodes them for an image of
  // width x height pixels. Throws std::invalid_argument for sizes Process refuses.
  ProcessedImage Encode(ImageFeatures features, int width, int height) const;

  // Where a keyframe comes from: mapping (the node's mapping mode, gtbow map, gtbow slam), or a
  // maintained map's view of a changed floor placed at its fix (maintenance.h). Saved maps
  // record it (a map with maintained keyframes needs a build of this version or later).
  enum class KeyframeSource { kMapping, kMaintenance };
  // Inserts a keyframe; returns its id.
  uint32_t Add(const ProcessedImage& image, int64_t stamp_ns, const std::optional<Pose2D>& pose,
               KeyframeSource source = KeyframeSource::kMapping);

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

  // Global localization of an image that is only localized (the node's localization mode with
  // single images, the localize service, gtbow localize): Process(gray, kQuery) and Localize, or
  // with features.query_escalate the image processed as a keyframe and localized as a first pass
  // (without guided matching), and only when that gives no fix with escalate_min_inliers
  // inliers processed as a query and localized in full (EscalatedFix). gtbow localize takes a
  // map's recorded options, which hold neither query_num_features nor query_escalate. *image (if
  // given) receives the image the returned fix, or failure, is the localization of; *escalated
  // whether that was the full pass. With a `backoff` (the node's stream of images; from
  // NewBackoff), the first pass runs only when it says so (EscalationBackoff). Throws as Process
  // does.
  Localization LocalizeImage(const cv::Mat& gray, ProcessedImage* image = nullptr,
                             bool* escalated = nullptr, EscalationBackoff* backoff = nullptr) const;
  // Whether LocalizeImage escalates (features.query_escalate).
  bool escalates() const { return options_.retrieval.features.query_escalate; }
  // A stream's backoff for LocalizeImage (features.query_escalate_backoff).
  EscalationBackoff NewBackoff() const {
    return EscalationBackoff(options_.retrieval.features.query_escalate_backoff);
  }

  // A sequence query (sequence.h): images[0] is the newest image, the others the robot's images
  // just before it, poses[i] each one's pose in a common odometry frame (metres, radians, the
  // image poses of geometry.h). Their features are combined in images[0]'s frame (each place of
  // the floor once: CombineViews) and encoded as one image of images[0]'s size, which Localize and
  // Query take as they take one image: a fix is images[0]'s pose. Throws std::invalid_argument when
  // the sizes differ.
  ProcessedImage Combine(const std::vector<const ProcessedImage*>& images,
                         const std::vector<Pose2D>& poses) const;

  // Writes the map (vocabulary path and fingerprint, options, database, keyframes) atomically:
  // a failure leaves any existing file untouched. Throws std::runtime_error naming the path.
  // Insertion and queries go on while the file is written: the save holds the lock only to
  // seal what the map holds (a few array swaps) and, once written, to use the file's
  // memory-mapped copy instead of the heap's. Saves are serialised.
  // Format (version 2, docs/ARCHITECTURE.md): the index as the core's memory-mappable layout
  // and 64-byte keyframe records, with a checksum per 64 MB verified at Load on all cores; then
  // each keyframe's keypoints (StoredKeypoints, 8 bytes each) and, with keep_descriptors, its
  // descriptors, with a checksum per keyframe checked when the keyframe is read.
  // `paced`: written at options' save_rate_mb (a save beside the robot's work); false writes as
  // fast as the disk allows (a save at shutdown, the command-line tools).
  SaveStats Save(const std::filesystem::path& path, bool paced = true) const;
  // From now on every save, the one being written included, goes unpaced: for a node that shuts
  // down (its last save must not wait out a paced one of gigabytes).
  void StopPacingSaves() const { stop_pacing_ = true; }
  // Replaces the map with a saved one, memory-mapped (nothing is copied into the heap; new
  // keyframes go to a growable tail). Throws std::runtime_error naming the file when it is
  // damaged, of another version (a version-1 map: the message says how to convert it), or made
  // with another vocabulary, other BoW options or another keep_descriptors; the current map is
  // kept then. Returns the keyframes loaded. With `adopt_scale`, the map's meters_per_pixel
  // replaces this localizer's instead of having to equal it (a node whose scale comes from
  // the map or the camera, checked against the map's by the caller).
  size_t Load(const std::filesystem::path& path, bool adopt_scale = false);
  // Replaces the map with a version-1 map file (before issue 17), read whole into the heap; for
  // gtbow convert-map (load it, then Save). Load's checks otherwise.
  void ImportVersion1(const std::filesystem::path& path);
  // The header of a map file of either version. Throws std::runtime_error naming the file.
  static MapFileInfo ReadMapInfo(const std::filesystem::path& path);
  // The vocabulary path recorded in a map file (to load the right vocabulary before Load).
  static std::string VocabularyPathOf(const std::filesystem::path& path);

  void Reset();  // forgets every keyframe

  // Takes a keyframe out of the index (a maintained map's keyframe that a newer view of its place
  // replaced, maintenance.h): no query returns it again, and saved maps record it as retired.
  // Its id is not reused, and its record stays in the map file (KeyframeInfo still reads it,
  // with `retired`). Returns false for an unknown or already retired id.
  bool Retire(uint32_t id);

  // The poses a SLAM backend's optimisation gives the keyframes, in the map's pose frame: each
  // keyframe named by id and stamp gets its new pose (an entry whose id is unknown or whose stamp
  // differs is skipped). Later updates replace earlier ones; Save writes the poses as updated and
  // records that the map's poses were optimised. Returns the number of keyframes updated.
  // Throws std::invalid_argument, changing nothing, for a non-finite pose.
  size_t UpdateKeyframePoses(const std::vector<KeyframePose>& poses);
  // The frame the keyframe poses are in, recorded in saved maps (the node's ~map_frame; a loaded
  // map's own). Set before the first keyframe, or it names the frame of poses made elsewhere.
  void SetPoseFrame(const std::string& frame);
  std::string pose_frame() const;
  // Whether UpdateKeyframePoses updated any keyframe of this map (or the loaded map says so).
  bool poses_optimised() const;

  // The ground sampling distance images are verified with and maps are saved with: the
  // options' until SetMetersPerPixel or Load(..., adopt_scale) changes it.
  double meters_per_pixel() const { return meters_per_pixel_.load(); }
  // Sets it while the map is empty (a node that learns its scale from the camera's first
  // camera_info). Throws std::invalid_argument for a value that is not positive and finite, and
  // std::logic_error when keyframes made at another scale are in the map.
  void SetMetersPerPixel(double meters_per_pixel);

  size_t size() const;       // keyframes, retired ones included (ids run from 0 to size() - 1)
  size_t live_size() const;  // keyframes not retired
  std::optional<Keyframe> KeyframeInfo(uint32_t id) const;  // a copy
  std::vector<Keyframe> Keyframes() const;                  // every keyframe, without features
  const Vocabulary& vocabulary() const { return *vocabulary_; }
  const std::string& vocabulary_path() const { return vocabulary_path_; }
  // The options it was made with (meters_per_pixel: see meters_per_pixel()).
  const LocalizerOptions& options() const { return options_; }
  // Bytes of the map in the heap (index, keyframe records and payloads); a loaded map's
  // memory-mapped part is not counted.
  size_t HeapBytes() const;
  // How verification matches here: the preset's choice, except word pairs where it asks for
  // descriptors and the map keeps none.
  MatchSource effective_matches() const { return verification_.matches; }

 private:
  ImageGeometry GeometryOf(int width, int height) const;
  // The keyframes' keypoints and descriptors, each pose at the origin (relative poses); under
  // mutex_.
  MapAccess RelativeAccess() const;
  // A keyframe's stored keypoints and descriptors (copied), to encode it as a query
  // (QueryKeyframe, the repeat check); under mutex_.
  ImageFeatures StoredFeatures(const detail::KeyframeView& v) const;
  std::vector<Candidate> QueryLocked(const BowVector& bow, int width, int height, size_t k,
                                     bool verify, uint32_t exclude_from, uint32_t exclude_to) const;
  // A keyframe's view, or why it cannot be verified (a payload that fails its checksum); under
  // mutex_.
  detail::KeyframeView View(uint32_t id) const;
  // A keyframe's pose: the one UpdateKeyframePoses gave it, else its record's (none when it was
  // added without one); under mutex_.
  std::optional<Pose2D> PoseOf(uint32_t id, const detail::KeyframeRecord& record) const;
  std::string Damaged(uint32_t id) const;
  // Asks the disk for the first `n` results' payloads that live in a map file, all at once,
  // before verification reads them one by one (a loaded map's payloads are mostly not in
  // memory); under mutex_.
  void PrefetchPayloads(const std::vector<QueryResult>& results, size_t n) const;
  std::unique_ptr<BowDatabase> NewDatabase() const;
  std::unique_ptr<detail::KeyframeStore> NewStore() const;
  size_t PayloadStride() const;
  // Parses and checks a version-2 file's header against this localizer; returns the mapping.
  void CheckHeader(const MapFileInfo& info, const std::string& source, bool adopt_scale) const;

  std::shared_ptr<Vocabulary> vocabulary_;
  std::string vocabulary_path_;
  LocalizerOptions options_;
  LocalizationOptions verification_;  // options_.retrieval.verification, effective_matches()
  int descriptor_cols_ = 0;           // the extractor's descriptors: 32 x CV_8U or 128 x CV_32F
  int descriptor_type_ = 0;
  std::unique_ptr<BowEncoder> encoder_;
  mutable std::mutex save_mutex_;                 // one Save at a time
  mutable std::atomic<bool> stop_pacing_{false};  // StopPacingSaves
  mutable std::shared_mutex mutex_;               // guards database_, keyframes_ and generation_
  std::shared_ptr<BowDatabase> database_;  // guarded by mutex_ (a save keeps its own reference)
  std::unique_ptr<detail::KeyframeStore> keyframes_;  // by id; guarded by mutex_
  // The poses UpdateKeyframePoses gave, by id (x NaN: none), replaced as a whole (a save takes
  // the current one under the lock in O(1)); guarded by mutex_, as are the two below.
  std::shared_ptr<const std::vector<Pose2D>> moved_;
  std::string pose_frame_;
  bool poses_optimised_ = false;
  std::mutex update_mutex_;               // one UpdateKeyframePoses at a time
  std::atomic<double> meters_per_pixel_;  // set with mutex_ held; read anywhere
  uint64_t generation_ = 0;  // bumped by Load, ImportVersion1 and Reset; guarded by mutex_
  // The repeat checks' copies of keyframes (RepeatCache), cleared by every change of the map
  // (with mutex_ held exclusively; filled by localizations, which hold it shared).
  mutable RepeatCache repeats_;
};

}  // namespace gtbow
