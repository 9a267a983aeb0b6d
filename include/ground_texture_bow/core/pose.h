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
#include <string>
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

  // Throws std::invalid_argument naming the first bad field.
  void Check() const;
};

// A correspondence: pixel `query` in the query image shows the same floor point as pixel
// `database` in the database image; `weight` > 0 is its vote.
struct PointMatch {
  Vec2 query;
  Vec2 database;
  double weight = 1.0;
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
};

// Estimates the transform from `matches` and composes it with `floor_from_database`.
PoseEstimate EstimatePose(const std::vector<PointMatch>& matches, const Pose2D& floor_from_database,
                          const ImageGeometry& geometry, const PoseOptions& options);

// The matches of a query result (QueryResult::matches) as pixel pairs; pairs repeated over
// several shared rows are merged and their weights added.
std::vector<PointMatch> MatchesOf(const QueryResult& result,
                                  const std::vector<Keypoint>& query_keypoints,
                                  const std::vector<Keypoint>& database_keypoints);

struct LocalizationOptions {
  int candidates = 5;  // K: retrieved images verified in rank order
  PoseOptions pose;

  void Check() const;
};

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

// Where the localizer finds a database image's keypoints and pose.
struct MapAccess {
  std::function<const std::vector<Keypoint>&(uint32_t image)> keypoints;
  std::function<Pose2D(uint32_t image)> pose;
  // Optional: why an image cannot give a pose ("no pose", "other image size"); empty when it
  // can. Such candidates are skipped.
  std::function<std::string(uint32_t image)> unusable;
};

// Verifies one retrieved candidate: a pose from its matches with the map image's keypoints
// (`inlier_pixels`, when given, receives the query pixels of the inliers).
PoseEstimate VerifyCandidate(const QueryResult& candidate, const BowVector& query,
                             const MapAccess& map, const ImageGeometry& geometry,
                             const PoseOptions& options,
                             std::vector<Vec2>* inlier_pixels = nullptr);

// Verifies retrieved candidates (with their matches) in order until one gives a pose with
// enough inliers (VerifyCandidate).
Localization VerifyCandidates(const std::vector<QueryResult>& candidates, const BowVector& query,
                              const MapAccess& map, const ImageGeometry& geometry,
                              const LocalizationOptions& options);

// Global localization: retrieves the top K candidates of `query`, then verifies them in order
// (VerifyCandidates).
Localization Localize(const BowDatabase& database, const BowVector& query, const MapAccess& map,
                      const ImageGeometry& geometry, const LocalizationOptions& options);

}  // namespace gtbow
