// gtbow eval's results: what one preset measured on one dataset (eval_command.cpp measures,
// eval_report.cpp writes results.json and summary.md).
#pragma once

#include <cmath>
#include <string>
#include <vector>

#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/core/maintenance.h"
#include "ground_texture_bow/core/pose.h"
#include "ground_texture_bow/core/sequence.h"
#include "ground_texture_bow/eval/dataset.h"
#include "ground_texture_bow/eval/metrics.h"
#include "image_source.h"
#include "timing.h"

namespace gtbow {
namespace tools {

inline constexpr size_t kScalingQueries = 20;
inline constexpr size_t kRecallN[] = {1, 2, 5, 10, 20, 50, 100};
inline constexpr double kSuccessMeters = 0.0048;
inline constexpr double kSuccessRadians = 1.5 * M_PI / 180.0;

// The evaluation's criterion of a right pose: within kSuccessMeters and kSuccessRadians of the
// ground truth.
inline bool IsCorrectPose(const Pose2D& estimate, const Pose2D& truth) {
  return std::hypot(estimate.x - truth.x, estimate.y - truth.y) <= kSuccessMeters &&
         std::abs(WrapAngle(estimate.theta - truth.theta)) <= kSuccessRadians;
}

// The paper's Table I rows and the presets (under config/) that reproduce them.
inline constexpr std::pair<const char*, const char*> kAblation[] = {
    {"DBoW", "dbow_baseline.yaml"},
    {"DBoW + SB", "ablation/dbow_sb.yaml"},
    {"DBoW + AKM", "ablation/dbow_akm.yaml"},
    {"DBoW + AKM + SA (r=3)", "ablation/dbow_akm_sa.yaml"},
    {"DBoW + OV", "ablation/dbow_ov.yaml"},
    {"Ours Fast", "fast.yaml"},
    {"Ours", "high_accuracy.yaml"},
};

struct EvalArgs {
  std::string dataset;
  std::string vocab;
  std::vector<std::string> presets;
  std::string out = "gtbow_eval";
  std::vector<std::string> query_splits;
  size_t max_queries = 0;
  size_t timing_queries = 100;
  // Kernels timed side by side (SetSimdLimit names): each timed query runs under each of them
  // in turn, the order rotating from query to query.
  std::vector<std::string> timing_kernels;
  // The presets timed side by side: each timed query runs through every preset in turn, the
  // order rotating from query to query (TimingRotation in eval_command.cpp).
  bool timing_alternate = false;
  // The timed queries in the splits' order (the first timing_queries), not a random sample: a
  // stream of images, as a drive's split holds them (an escalating preset's backoff).
  bool timing_in_order = false;
  int candidates = 0;   // 0: each preset's verification.candidates
  int min_inliers = 0;  // 0: each preset's verification.min_inliers
  // Sequence queries: each query with the sequence - 1 images of its trail (gtbow synth
  // --query-trail), combined through their odometry (Localizer::Combine); 1 = single images.
  int sequence = 1;
  bool sequence_always = false;  // the combined view only, not the query alone first
  // Metres of odometry a trail image may be from its query to be combined (the node's
  // ~sequence_max_span; ImagesInSpan): the trail's images from the first one beyond it are left
  // out.
  double sequence_max_span = SequenceOptions().max_span;
  // A maintained map: these splits (sessions, in order) localize against the map and keep it up
  // (maintenance.h) before the query splits are evaluated; empty = the map as built.
  std::vector<std::string> maintain;
  MaintenanceOptions maintenance;
  int threads = 0;
  std::string cache = DefaultCacheDir().string();
  bool no_cache = false;
  bool no_plots = false;
  bool ablation = false;
  int words = 0;
  std::string dump_rankings;
  std::string dump_poses;
  bool exact_keypoints = false;  // verify against unquantised map keypoints (ablation)
  bool quiet = false;
};

struct SplitResult {
  std::string name;
  double day = NAN;
  size_t queries = 0, counted = 0, no_relevant = 0;
  // Queries an escalating preset (features.query_escalate) localized with its full pass: the
  // first pass, as a keyframe is extracted, gave no fix with escalate_min_inliers inliers.
  size_t escalated = 0;
  // Queries its backoff (features.query_escalate_backoff) sent straight to the full pass, the
  // split's images taken in order as a stream.
  size_t first_passes_skipped = 0;
  double map = 0;
  std::vector<double> recall;  // at kRecallN
  Separation separation;
  std::vector<double> rel_scores, irr_scores;
  // Diagnostic: separation against false results with no overlap at all (near misses, 0-25%
  // overlap, share real texture and bound the protocol's separation on dense maps).
  std::vector<double> disjoint_scores;
  Separation separation_disjoint;
  size_t localized = 0;                 // within 4.8 mm and 1.5 degrees
  size_t estimated = 0;                 // gave a pose at all
  std::vector<double> err_mm, err_deg;  // of every estimate
  // What a SLAM backend reads. Every one of the top K candidates verified (not only until the
  // first pose): how many gave a pose, and how many of those were wrong (beyond 4.8 mm or
  // 1.5 degrees).
  size_t verified_poses = 0, wrong_verified_poses = 0;
  // Precision-recall over the queries with a relevant image: the top-1 result accepted by its
  // BoW score; the loop closure the node publishes (the first verified candidate) accepted by
  // its inlier count.
  PrecisionRecall pr_bow, pr_verified;
};

struct ScalingPoint {
  size_t images = 0;
  TimingStats insert;  // over the last (up to) 1,000 insertions
  TimingStats query;   // kScalingQueries queries with matches, top K
};

// One maintenance session of --maintain.
struct MaintenanceSession {
  std::string split;
  double day = NAN;
  size_t images = 0, fixes = 0, correct = 0;  // its localization against the map as it was
  size_t added = 0, retired = 0;              // keyframes
  size_t added_wrong = 0;                     // added at a pose outside the success tolerance
  std::vector<double> added_error_mm;         // each added keyframe's position error
  std::vector<double> added_error_deg;        // and heading error
  size_t keyframes_after = 0;                 // live keyframes after the session
};

struct MaintenanceResult {
  MaintenanceOptions options;
  std::vector<MaintenanceSession> sessions;
};

struct PresetResult {
  std::vector<ScalingPoint> scaling;
  std::string name, file;
  std::string table_row;  // the paper's Table I row this preset reproduces (--ablation)
  std::string vocab_desc;
  std::vector<SplitResult> splits;
  TimingStats extract, transform, insert, query, pose, total;
  // --timing-kernels: the same stages under each kernel, interleaved query by query.
  struct KernelTiming {
    std::string requested, hamming, l2_bytes;  // as asked, and the kernels that ran
    TimingStats extract, transform, insert, query, pose, total;
  };
  std::vector<KernelTiming> by_kernel;
  size_t timed = 0;
  size_t timed_first_passes_skipped = 0;  // of an escalating preset's timed queries (backoff)
  bool timed_side_by_side = false;  // --timing-alternate: timed in turn with the other presets
  bool timed_in_order = false;      // --timing-in-order
  size_t db_images = 0;
  RetrievalConfig config;
  MaintenanceResult maintenance;  // --maintain
};

// results.json: every number; summary.md: ours next to the paper's.
std::string ToJson(const EvalArgs& a, const Dataset& ds, const std::vector<PresetResult>& results);
std::string ToMarkdown(const EvalArgs& a, const std::vector<PresetResult>& results);

}  // namespace tools
}  // namespace gtbow
