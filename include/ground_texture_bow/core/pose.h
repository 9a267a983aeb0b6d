// Pose estimation from retrieval matches (paper §III-C) and global localization.
//
// The matches of a query with a database image are the keypoint pairs of the winning
// orientation bin: same word, same size bin. Between two downward images of the same floor the
// mapping is a 2-D rigid transform (the constant camera height fixes the scale), estimated by
// weighted RANSAC -- samples drawn and hypotheses scored by the soft-assignment weights -- and
// refined by least squares on the inliers. The query's floor pose then follows from the database
// image's ground-truth pose (docs/DATASET_FORMAT.md).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/features.h"
#include "ground_texture_bow/core/geometry.h"

namespace gtbow {

struct PoseOptions {
  int max_iterations = 1000;      // RANSAC hypotheses at most
  double confidence = 0.999;      // stop once an all-inlier sample was this likely drawn
  double inlier_threshold = 3.0;  // pixels: residual of an inlier
  int min_inliers = 6;   // fewer inliers: no estimate (6 of 2-point-consistent matches within 3 px:
                         // no false pose seen)
  bool weighted = true;  // paper: weighted sampling and scoring; false: plain RANSAC
  int refine_iterations = 3;  // least-squares refinement rounds (inliers re-selected)
  uint64_t seed = 1;          // sampling seed (estimates are deterministic)

  // Checks a pose must pass besides min_inliers (issue 15: a wrong pose must be as rare as the
  // math allows). Each is off at 0, the paper's RANSAC alone.
  // An inlier must also turn its keypoint's orientation by the estimated rotation, within this
  // (radians; matches without orientations are exempt). Used inside RANSAC, so it shapes which
  // hypothesis wins, not only whether it is accepted.
  double angle_tolerance = 0.0;
  // Inliers needed grow with the matches: at least this fraction of them.
  double min_inlier_fraction = 0.0;
  // The inliers must span the image: the smaller principal standard deviation of their query
  // pixels at least this (pixels). Clustered inliers leave the rotation unconstrained.
  double min_spread = 0.0;
  // The rotation's standard deviation from the covariance at most this (radians).
  double max_theta_sigma = 0.0;
  // A second hypothesis, RANSAC over the matches the best one leaves out, with at least this
  // fraction of the best's inliers makes the pose ambiguous: refused.
  double max_second_ratio = 0.0;

  // Throws std::invalid_argument naming the first bad field.
  void Check() const;
};

// A correspondence: pixel `query` in the query image shows the same floor point as pixel
// `database` in the database image; `weight` > 0 is its vote.
struct PointMatch {
  Vec2 query;
  Vec2 database;
  double weight = 1.0;
  // The change of the keypoint's orientation from the query to the database image (radians);
  // NaN when unknown. A rigid map turns it by its rotation.
  double rotation = std::numeric_limits<double>::quiet_NaN();
};

// The rigid transform taking centred query pixels to centred database pixels:
// database - c = R(theta) (query - c) + t, with c the image centre ((W-1)/2, (H-1)/2).
struct Rigid2D {
  double theta = 0.0;  // radians
  Vec2 t;              // pixels
};

struct PoseEstimate {
  bool success = false;
  std::string reason;           // why there is no estimate (empty on success)
  Rigid2D database_from_query;  // pixels
  Pose2D floor_from_query;      // metres and radians, through the database image's pose
  int inliers = 0;
  double residual_rms = 0.0;  // pixels, over the inliers
  // Covariance of (x, y, theta) of floor_from_query, row-major: m^2, m rad, rad^2.
  std::array<double, 9> covariance{};
  std::vector<int> inlier_indices;  // into the matches given
  // Evidence of the estimate (filled whenever RANSAC found a hypothesis, also when a check
  // refused it), for a backend that weighs loop closures and for gtbow eval's diagnostics.
  int matches = 0;             // matches given
  double spread = 0.0;         // pixels: smaller principal standard deviation of the inliers
  double theta_sigma = 0.0;    // radians: standard deviation of the rotation (covariance)
  int second_inliers = 0;      // inliers of the best other hypothesis (max_second_ratio)
  double angle_agreement = 0;  // inliers whose orientation change agrees within 15 degrees
                               // (of those with orientations; 1 when none has one)
};

// Estimates the transform from `matches` and composes it with `floor_from_database`.
PoseEstimate EstimatePose(const std::vector<PointMatch>& matches, const Pose2D& floor_from_database,
                          const ImageGeometry& geometry, const PoseOptions& options);

// The matches of a query result (QueryResult::matches) as pixel pairs; pairs repeated over
// several shared rows are merged and their weights added.
std::vector<PointMatch> MatchesOf(const QueryResult& result,
                                  const std::vector<Keypoint>& query_keypoints,
                                  const std::vector<Keypoint>& database_keypoints);

// Where verification takes its matches from.
enum class MatchSource {
  kWords,        // the retrieval's own: pairs of the winning orientation bin (paper §III-C)
  kDescriptors,  // the descriptors of the pair, nearest neighbours with a ratio test
};
MatchSource ParseMatchSource(const std::string& name);  // "words" | "descriptors"
std::string MatchSourceName(MatchSource source);

struct LocalizationOptions {
  int candidates = 5;  // K: retrieved images verified in rank order
  PoseOptions pose;
  MatchSource matches = MatchSource::kWords;
  // kDescriptors: a query keypoint's nearest database descriptor is a match when it is closer
  // than this fraction of the second nearest (Lowe's ratio test) and the two are mutual
  // nearest neighbours.
  double descriptor_ratio = 0.8;
  // Consensus among the K candidates (0 = off: the first candidate that verifies gives the
  // pose, the paper's procedure). On: every candidate is verified and their poses compared with
  // the best supported one (most inliers); a pose that disagrees with it (beyond
  // consensus_distance or consensus_angle) is refused, and when the strongest disagreeing pose
  // has at least max_conflict_ratio x the best's inliers the place is ambiguous (a floor that
  // repeats itself) and every pose is refused. The best supported pose is the answer.
  double max_conflict_ratio = 0.0;
  double consensus_distance = 0.01;  // metres
  double consensus_angle = 0.0524;   // radians (3 degrees)
  // Guided matching (kDescriptors; 0 = off), for a query none of whose candidates verified and
  // none was refused by the consensus: a candidate with at least pose.min_inliers ratio-test
  // matches (fewer never reach RANSAC) whose RANSAC hypothesis had at least guided_seed_inliers
  // inliers but fewer than pose.min_inliers is matched again through that hypothesis. Each query
  // keypoint takes the nearest descriptor among the candidate's keypoints within guided_radius
  // pixels of where the hypothesis puts it, when within guided_max_distance (Hamming bits, or L2
  // for float descriptors), each candidate keypoint keeping the query keypoint nearest to it in
  // descriptor distance; no ratio test. The pose from those matches then passes every check of
  // `pose` and the consensus as any other. On a faint, aged floor the ratio test leaves too few
  // of the matches that lasted; near where they must be, they are told apart.
  double guided_radius = 0.0;         // pixels
  double guided_max_distance = 80.0;  // descriptor distance
  int guided_seed_inliers = 4;
  // The repeat check of guided matching (needs guided_radius > 0 and a map that can query its
  // own images, MapAccess::query_of and retrieve): a pose guided matching found is kept only
  // when its keyframe, queried against its own map (itself excluded; plain, then guided
  // verification of its first guided_repeat_candidates candidates), gives no pose that
  // disagrees with its own map pose beyond consensus_distance or consensus_angle. A floor that
  // holds a copy of itself elsewhere (a repeat, or the same pattern turned) makes such a keyframe
  // verify at the copy; guided matching, which has no ratio test, would then take a query of the
  // copy's place for one of the keyframe's; one such keyframe refuses every guided pose of the
  // query. Costs one retrieval, up to guided_repeat_candidates verifications (and, with
  // guided_repeat_ratio, one guided match) per guided pose.
  bool guided_repeat_check = false;
  int guided_repeat_candidates = 5;
  // 0: a keyframe that repeats elsewhere refuses as said. Above 0: the query is matched at the
  // copy too (guided, through the keyframe's hypothesis composed with the copy's), and the
  // keyframe's pose stands when the query holds fewer than this fraction of its inliers there
  // (its place is the keyframe's, the copy covering only part of it).
  double guided_repeat_ratio = 0.0;
  // The repeat check for plain poses too (needs guided_repeat_check, whose candidates it uses;
  // 0 = off): a query's best pose from plain matching (with consensus; without, its first
  // verified pose) with fewer inliers than this is checked as a guided pose is: its keyframe
  // queried against its own map, then the query matched at the copy (plain_repeat_ratio). When it
  // repeats elsewhere every pose of the query is refused. On a floor that holds a copy of a part
  // of itself, a query whose own place is not among its candidates can verify at the copy by
  // plain matching alone (the held-out photos' desert floor, 117 mm away). The same cost as the
  // guided check: a keyframe's copies are found once per map state (MapAccess::repeats), then one
  // guided match per copy and pose. At or below pose.min_inliers it never acts.
  int plain_repeat_below = 0;
  // Its contest at the copy: the pose is refused when the query, matched at the copy, holds at
  // least this fraction of the inliers that it holds at its keyframe, both counted by guided
  // matching through the pose's hypothesis (0: any copy refuses).
  double plain_repeat_ratio = 1.0;
  // Guided matching (and its repeat check) for a sequence query's combined view too (sequence.h;
  // CombinedViewOptions). Off, a combined view is verified without it: on the held-out photos
  // guided matching of combined views published two copies of a sand floor turned 180 degrees,
  // where the check's copy covered another part of the larger view.
  bool guided_combined = false;
  // An escalating query's first pass (FeatureOptions::query_escalate; EscalatedFix): its fix
  // stands only with at least this many inliers; a weaker one goes on to the full pass, as no
  // fix does (0: any fix stands). On the held-out photographs the first pass's weak fixes
  // included a copy of a floor turned 180 degrees (10 inliers; docs/RESULTS.md).
  int escalate_min_inliers = 0;
  // Guided matching of the query itself (not a config key): FirstPassOptions, and
  // CombinedViewOptions unless guided_combined, turn it off. The repeat checks still match guided
  // where they must.
  bool guided = true;

  void Check() const;
};

// The options that verify a sequence query's combined view (sequence.h): `options` without guided
// matching unless options.guided_combined.
LocalizationOptions CombinedViewOptions(const LocalizationOptions& options);

// The result of global localization, for the evaluation (gtbow eval) and the node
// (Localizer::Localize) alike: the query's pose is estimate.floor_from_query (in the map, for
// the node), with estimate.covariance and estimate.inliers.
struct Localization {
  bool success = false;
  std::string reason;  // why no candidate gave a pose (empty on success)
  uint32_t image = 0;  // the database image (keyframe) that gave the pose
  int rank = -1;       // its rank among the retrieved candidates (0 = first)
  float score = 0.0f;  // its retrieval score
  PoseEstimate estimate;
  std::vector<Vec2> inlier_pixels;  // query pixels of the inlier matches (for overlays)
};

// The options that verify the first pass of an escalating query (FeatureOptions::query_escalate):
// `options` without guided matching, which the full pass keeps.
LocalizationOptions FirstPassOptions(const LocalizationOptions& options);

// Which images of a stream try an escalating query's first pass (FeatureOptions::
// query_escalate_backoff): after a first pass that gave no fix that stands, the next 1, 3, 7, ...
// images (doubling with each such first pass in a row, at most `max_skip`) go straight to the
// full pass; a first pass that stands starts again from none. A robot's images follow each other
// over the same floor: where it has aged, most first passes would fail, and most are skipped.
// max_skip 0: every image tries the first pass. One per stream of images; not thread-safe.
class EscalationBackoff {
 public:
  explicit EscalationBackoff(int max_skip = 0);
  // For the next image: false sends it straight to the full pass (and counts it as skipped).
  bool TryFirstPass();
  // The outcome of the first pass just tried: whether its fix stood.
  void Record(bool stood);
  int max_skip() const { return max_skip_; }
  size_t skipped() const { return skipped_; }  // images sent straight to the full pass

 private:
  int max_skip_;
  int failures_ = 0;  // first passes in a row that gave no fix that stands
  int left_ = 0;      // images still to skip
  size_t skipped_ = 0;
};

// An escalating query's fix (what the node, the localize service and gtbow eval all do): with
// `escalate`, the first pass's fix when it has one with at least options.escalate_min_inliers
// inliers, else the full pass's; without, the full pass's. `full` runs only when needed. With a
// `backoff` (a stream's images, in order), the first pass runs only when it says so, and its
// outcome is recorded there. *escalated (if given) says whether the fix, or the failure, is the
// full pass's.
Localization EscalatedFix(bool escalate, const LocalizationOptions& options,
                          const std::function<Localization()>& first,
                          const std::function<Localization()>& full, bool* escalated,
                          EscalationBackoff* backoff = nullptr);

// The repeat checks' finding for each keyframe asked about (LocalizationOptions::
// guided_repeat_check, plain_repeat_below): the poses at which it verified elsewhere in its own
// map, its copies. They depend on the map, the image size and the verification options (not on
// the query, nor on `guided`), so a map keeps them across queries (MapAccess::repeats) and
// clears them whenever it changes; one cache serves one image size and one set of options (a
// Localizer's, an evaluation's preset). Thread-safe.
class RepeatCache {
 public:
  struct Copy {
    uint32_t image = 0;     // the map image it verified with
    PoseEstimate estimate;  // that verification (the keyframe as the query)
  };
  // The copies of `image`: found with `find` the first time (outside the lock), then kept.
  std::shared_ptr<const std::vector<Copy>> Get(uint32_t image,
                                               const std::function<std::vector<Copy>()>& find);
  void Clear();
  size_t size() const;  // keyframes whose copies are kept

 private:
  mutable std::mutex mutex_;
  std::unordered_map<uint32_t, std::shared_ptr<const std::vector<Copy>>> copies_;
};

// Where the localizer finds a database image's keypoints and pose.
struct MapAccess {
  std::function<std::vector<Keypoint>(uint32_t image)> keypoints;
  // Its descriptors (row i: keypoint i); needed only for MatchSource::kDescriptors.
  std::function<cv::Mat(uint32_t image)> descriptors;
  std::function<Pose2D(uint32_t image)> pose;
  // Optional: why an image cannot give a pose ("no pose", "other image size"); empty when it
  // can. Such candidates are skipped.
  std::function<std::string(uint32_t image)> unusable;
  // Optional, for the repeat check (LocalizationOptions::guided_repeat_check): a map image as a
  // query (its keypoints as the map keeps them, its descriptors, encoded), and the map's
  // retrieval for such a query: its `k` best, best first, without the image `self` itself.
  std::function<BowVector(uint32_t image)> query_of;
  std::function<std::vector<QueryResult>(const BowVector& query, uint32_t self, size_t k)> retrieve;
  // Optional: where the repeat checks keep each keyframe's copies between queries (without it
  // they are found again for every pose checked). Its owner clears it when the map changes.
  RepeatCache* repeats = nullptr;
};

// Matches of two images' descriptors (CV_8U: Hamming; CV_32F: L2): mutual nearest neighbours
// passing the ratio test, with their keypoints' pixels and orientation changes (weight 1).
std::vector<PointMatch> DescriptorMatches(const std::vector<Keypoint>& query_keypoints,
                                          const cv::Mat& query_descriptors,
                                          const std::vector<Keypoint>& database_keypoints,
                                          const cv::Mat& database_descriptors, double ratio);

// Verifies one retrieved candidate: a pose from its matches (options.matches says which) with
// the map image (`inlier_pixels`, when given, receives the query pixels of the inliers).
// Descriptor matching needs query.source_descriptors and map.descriptors.
PoseEstimate VerifyCandidate(const QueryResult& candidate, const BowVector& query,
                             const MapAccess& map, const ImageGeometry& geometry,
                             const LocalizationOptions& options,
                             std::vector<Vec2>* inlier_pixels = nullptr);

// The guided matches of `query` with a database image through `database_from_query` (the
// rigid transform of centred pixels, PoseEstimate::database_from_query): see
// LocalizationOptions::guided_radius.
std::vector<PointMatch> GuidedMatches(const std::vector<Keypoint>& query_keypoints,
                                      const cv::Mat& query_descriptors,
                                      const std::vector<Keypoint>& database_keypoints,
                                      const cv::Mat& database_descriptors,
                                      const Rigid2D& database_from_query,
                                      const ImageGeometry& geometry, double radius,
                                      double max_distance);

// Applies LocalizationOptions::max_conflict_ratio's consensus to estimates[k] (verified or
// not), whose poses in one common frame are poses[k] (nullopt: not comparable, left alone).
// Refused estimates get success = false and a reason naming the conflict.
void ResolveConflicts(const std::vector<std::optional<Pose2D>>& poses,
                      std::vector<PoseEstimate>* estimates, const LocalizationOptions& options);

// Verifies each of the top K candidates (consensus applied when on); `inlier_pixels`, when
// given, receives the query pixels of each one's inliers.
std::vector<PoseEstimate> VerifyEach(const std::vector<QueryResult>& candidates,
                                     const BowVector& query, const MapAccess& map,
                                     const ImageGeometry& geometry,
                                     const LocalizationOptions& options,
                                     std::vector<std::vector<Vec2>>* inlier_pixels = nullptr);

// Verifies retrieved candidates (with their matches): without consensus in order until one
// gives a pose with enough inliers; with it, all of them (VerifyEach), and the best supported
// consistent pose is the answer.
Localization VerifyCandidates(const std::vector<QueryResult>& candidates, const BowVector& query,
                              const MapAccess& map, const ImageGeometry& geometry,
                              const LocalizationOptions& options);

// Global localization: retrieves the top K candidates of `query`, then verifies them in order
// (VerifyCandidates).
Localization Localize(const BowDatabase& database, const BowVector& query, const MapAccess& map,
                      const ImageGeometry& geometry, const LocalizationOptions& options);

}  // namespace gtbow
