// A small 2-D pose-graph backend (issue 15, part 5): wheel odometry plus the localizer's loop
// closures, optimised with Ceres. ROS-free; the node (src/ros/pose_graph_backend.cpp) feeds it.
//
// Nodes are robot (base frame) poses at the stamps loop closures and fixes refer to, plus one at
// the first odometry sample, which anchors the map frame (map = odom at the start) unless the
// graph is anchored by fixes: a session on a map made before (anchor_at_start false) starts
// with no map frame, and its first accepted fix (a verified match to that map's keyframes,
// whose poses are fixed) places it; fixes are unary edges on the base's pose. Odometry
// between consecutive nodes is interpolated from the odometry samples and becomes an edge whose
// variance grows with the distance driven and the angle turned. Loop closures are edges with
// their own covariance. Two defences against wrong closures:
//   - pairwise consistency: a closure enters the graph only once another closure nearby (both
//     ends within consistency_window metres of driving) agrees with it through odometry: the
//     cycle closure * odometry * closure'^-1 * odometry must be the identity within its
//     covariance (chi-square gate). A wrong closure is rarely confirmed by a second one
//     that is wrong the same way, while a true revisit produces a run of closures;
//   - a robust loss (Cauchy or Huber, in standard deviations) on every closure edge.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "ground_texture_bow/core/geometry.h"

namespace gtbow {
namespace backend {

struct PoseGraphOptions {
  // Odometry edge standard deviations: sqrt(d) scaling for the distance d driven (a random
  // walk per metre), plus a share of the angle turned (track-width error).
  double odom_sigma_xy = 0.003;        // m per sqrt(m) driven
  double odom_sigma_theta = 0.002;     // rad per sqrt(m) driven
  double odom_sigma_turn = 0.005;      // rad per rad turned
  double odom_min_sigma_xy = 1e-5;     // m: floor for very short edges
  double odom_min_sigma_theta = 1e-5;  // rad
  // Added in quadrature to each closure's covariance: the localizer's covariance is the
  // RANSAC fit's and ignores what a rigid planar model cannot see (height and tilt changes
  // of the camera scale the image by up to about 2%).
  double closure_min_sigma_xy = 3e-4;      // m
  double closure_min_sigma_theta = 0.003;  // rad
  std::string loss = "cauchy";             // none, huber or cauchy
  double loss_scale = 3.0;                 // standard deviations where the loss starts to flatten
  bool consistency_check = true;
  double consistency_window = 0.5;  // m of driving between the ends of two closures
  double consistency_chi2 = 16.27;  // gate on the cycle error (3 dof, 99.9%)
  int max_iterations = 100;
  // true: the map frame is the odometry frame at the first sample (a new map). false: it is a
  // map's made before, given by fixes (AddFix): nothing is placed before the first accepted fix.
  bool anchor_at_start = true;
  size_t max_odometry_samples = 5000000;  // refuse to grow beyond (memory bound)

  void Check() const;  // throws std::invalid_argument naming the first bad field
};

// A loop closure in the base frame: the base at `query_ns` seen from the base at `match_ns`.
struct Closure {
  int64_t match_ns = 0;
  int64_t query_ns = 0;
  Pose2D match_from_query;
  std::array<double, 9> covariance{};  // row-major x, y, theta
};

// The base's pose in the map frame at `stamp_ns`, from a verified match to a keyframe whose pose
// is fixed (a map made before this session).
struct Fix {
  int64_t stamp_ns = 0;
  Pose2D map_from_base;
  std::array<double, 9> covariance{};  // row-major x, y, theta
};

enum class ClosureState { kPending, kAccepted, kRejected };

struct SolveReport {
  bool ran = false;
  bool converged = false;
  int iterations = 0;
  double initial_cost = 0.0;
  double final_cost = 0.0;
  double seconds = 0.0;
  size_t nodes = 0;
  size_t closure_edges = 0;
  size_t downweighted = 0;  // accepted closures whose residual exceeds loss_scale sigmas
  std::string message;
};

class PoseGraph {
 public:
  explicit PoseGraph(const PoseGraphOptions& options);

  // Odometry samples in increasing time (equal stamps replace nothing and are refused).
  // Throws std::invalid_argument for a non-finite pose or a stamp not after the last one.
  void AddOdometry(int64_t stamp_ns, const Pose2D& odom_from_base);
  bool HasOdometry() const { return !odom_.empty(); }
  int64_t FirstStamp() const;
  int64_t LastStamp() const;
  // True when stamp_ns lies within the odometry received so far.
  bool Covers(int64_t stamp_ns) const;

  // A closure whose stamps the odometry covers (else std::invalid_argument, as for a
  // non-finite pose or a covariance that is not symmetric positive definite). Returns the
  // closure's state: accepted (in the graph), pending (waiting for a consistent partner) or
  // rejected (matches two stamps closer than the localizer could mean). The closure's id is
  // the number of closures added before it (closures_added() - 1 after the call); one the call
  // throws for gets none.
  ClosureState AddClosure(const Closure& closure);
  size_t closures_added() const { return closures_.size(); }
  // A closure's state now (a pending one becomes accepted when a later closure confirms it).
  // Throws std::out_of_range for an id not yet given.
  ClosureState State(size_t id) const;

  // A fix whose stamp the odometry covers (else std::invalid_argument, as for a non-finite pose
  // or a covariance that is not symmetric positive definite). With the consistency check it is
  // pending until another fix within consistency_window of driving agrees with it through
  // odometry, then both are accepted; the first accepted fix anchors a graph that waits for one
  // (anchor_at_start false). Returns its state; its id is fixes_added() - 1.
  ClosureState AddFix(const Fix& fix);
  size_t fixes_added() const { return fixes_.size(); }
  size_t fixes_accepted() const { return fixes_accepted_; }
  size_t fixes_pending() const { return fixes_pending_; }
  ClosureState FixState(size_t id) const;  // std::out_of_range for an id not yet given
  // Whether the map frame is known: from the start, or since the first accepted fix. Poses,
  // the trajectory and map -> odom mean nothing before (they are odometry).
  bool anchored() const { return options_.anchor_at_start || anchored_at_ns_ != 0; }
  // The stamp of the fix that anchored the graph, the second of the first two that agree (0:
  // anchored at the start, or not yet).
  int64_t anchored_at_ns() const { return anchored_at_ns_; }

  // Optimises the graph (warm-started from the last solution). Cheap when nothing changed.
  SolveReport Optimize();
  bool dirty() const { return dirty_; }

  // The optimised pose of the base at any stamp the odometry covers: the odometry between
  // the neighbouring nodes, corrected by both and blended by distance driven.
  Pose2D PoseAt(int64_t stamp_ns) const;
  // Every odometry sample: stamp, optimised pose in the map, odometry pose.
  struct TrajectoryPoint {
    int64_t stamp_ns;
    Pose2D map_from_base;
    Pose2D odom_from_base;
  };
  std::vector<TrajectoryPoint> Trajectory() const;
  // map -> odom at the newest node (identity before the first closure).
  Pose2D MapFromOdom() const;

  size_t nodes() const { return nodes_.size(); }
  size_t accepted() const { return accepted_; }
  size_t pending() const { return pending_; }
  size_t rejected() const { return rejected_; }
  const PoseGraphOptions& options() const { return options_; }

 private:
  struct Sample {
    int64_t t;
    Pose2D odom;
    double dist;  // metres driven since the first sample
  };
  struct Node {
    Pose2D odom;
    double dist = 0.0;
    double est[3] = {0, 0, 0};  // map_from_base x, y, theta
  };
  struct StoredClosure {
    Closure c;
    ClosureState state;
    double match_dist, query_dist;
  };
  struct StoredFix {
    Fix f;
    ClosureState state;
    double dist;
  };

  Sample Interpolate(int64_t t) const;
  Node& NodeAt(int64_t t);
  bool Consistent(const StoredClosure& a, const StoredClosure& b) const;
  bool Consistent(const StoredFix& a, const StoredFix& b) const;
  void Accept(StoredClosure* s);
  void Accept(StoredFix* s);
  std::array<double, 9> OdometryCovariance(double distance, double turn) const;

  PoseGraphOptions options_;
  std::vector<Sample> odom_;
  std::map<int64_t, Node> nodes_;
  std::vector<StoredClosure> closures_;
  std::vector<StoredFix> fixes_;
  int64_t anchored_at_ns_ = 0;
  size_t fixes_accepted_ = 0, fixes_pending_ = 0;
  size_t accepted_ = 0, pending_ = 0, rejected_ = 0;
  bool dirty_ = false;
};

}  // namespace backend
}  // namespace gtbow
