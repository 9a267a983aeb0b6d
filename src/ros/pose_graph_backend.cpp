// pose_graph_backend: a small 2-D SLAM backend around the localizer (issue 15, part 5), an
// example of how a robot uses ~loop_closures and the test that they are good enough to fix
// wheel odometry.
//
// Inputs: nav_msgs/Odometry on `odom` (the base in the odometry frame), the localizer's
// ground_texture_bow/LoopClosure on `loop_closures`, and on `fixes` its ~pose in a session on
// an earlier map (~anchor: fixes): the base in map_frame from a match to that map's keyframes,
// whose poses are fixed; the first two agreeing fixes place the session in the map. A closure
// relates two camera poses in the camera's optical frame; the node turns it into a relation between
// base poses with the camera's mounting (TF base frame -> the closure's header frame, or
// ~camera_offset), and the pose graph (include/ground_texture_bow/backend/pose_graph.h) does the
// rest. Outputs: TF map -> odom, ~path (nav_msgs/Path of the graph's nodes), the optimised
// trajectory as CSV (~save_trajectory, and ~trajectory_csv at shutdown), and the keyframes'
// optimised poses: the localizer announces each keyframe it adds (its ~keyframes: id, image
// stamp, camera frame); after each optimisation the backend publishes on `keyframe_poses` the
// camera footprint in map_frame at each keyframe's stamp (PoseGraph::PoseAt and the camera's
// mounting) for every keyframe whose pose changed, so that the localizer's map, and the map
// file it saves, carries the optimised poses (launch/backend.launch wires both ways).
//
// Run the localizer in mapping mode with ~slam_backend (launch/backend.launch): it places each
// keyframe through the latest map -> odom and the odometry at the image's time, and its
// closures are relative poses between image stamps.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Odometry.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include "ground_texture_bow/KeyframePoses.h"
#include "ground_texture_bow/KeyframeStamp.h"
#include "ground_texture_bow/LoopClosure.h"
#include "ground_texture_bow/SaveTrajectory.h"
#include "ground_texture_bow/backend/pose_graph.h"
#include "ground_texture_bow/ros/conversions.h"

namespace {

using ground_texture_bow::LoopClosure;
using gtbow::Pose2D;
using gtbow::backend::ClosureState;
using gtbow::backend::PoseGraph;
using gtbow::backend::PoseGraphOptions;

int64_t Ns(const ros::Time& t) { return static_cast<int64_t>(t.toNSec()); }

std::string StampText(const ros::Time& t) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.3f", t.toSec());
  return buf;
}

// The closure as a relation between base poses: base_from_camera * C * base_from_camera^-1,
// C the camera footprint's relative pose (optical (x, y, theta) = footprint (x, -y, -theta):
// the optical y and z axes point against the footprint's). Covariance through the numeric
// Jacobian of that map.
gtbow::backend::Closure ToBaseClosure(const LoopClosure& msg, const Pose2D& e) {
  const Pose2D c{msg.match_from_query.x, -msg.match_from_query.y, -msg.match_from_query.theta};
  const double s[3] = {1.0, -1.0, -1.0};
  double cov_c[9];
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) cov_c[3 * i + j] = s[i] * s[j] * msg.covariance[3 * i + j];
  }
  auto f = [&](const Pose2D& p) { return gtbow::Compose(gtbow::Compose(e, p), gtbow::Inverse(e)); };
  const Pose2D b = f(c);
  double jac[9];
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    Pose2D plus = c, minus = c;
    (k == 0 ? plus.x : k == 1 ? plus.y : plus.theta) += h;
    (k == 0 ? minus.x : k == 1 ? minus.y : minus.theta) -= h;
    const Pose2D fp = f(plus), fm = f(minus);
    jac[0 * 3 + k] = (fp.x - fm.x) / (2 * h);
    jac[1 * 3 + k] = (fp.y - fm.y) / (2 * h);
    jac[2 * 3 + k] = gtbow::WrapAngle(fp.theta - fm.theta) / (2 * h);
  }
  gtbow::backend::Closure out;
  out.match_ns = Ns(msg.match_stamp);
  out.query_ns = Ns(msg.query_stamp);
  out.match_from_query = {b.x, b.y, gtbow::WrapAngle(b.theta)};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double v = 0.0;
      for (int k = 0; k < 3; ++k) {
        for (int l = 0; l < 3; ++l) v += jac[3 * i + k] * cov_c[3 * k + l] * jac[3 * j + l];
      }
      out.covariance[3 * i + j] = v;
    }
  }
  // Exactly symmetric, whatever the rounding of the product.
  for (int i = 0; i < 3; ++i) {
    for (int j = i + 1; j < 3; ++j) {
      const double m = 0.5 * (out.covariance[3 * i + j] + out.covariance[3 * j + i]);
      out.covariance[3 * i + j] = out.covariance[3 * j + i] = m;
    }
  }
  return out;
}

class Backend {
 public:
  Backend(ros::NodeHandle nh, ros::NodeHandle pnh)
      : nh_(nh), pnh_(pnh), graph_(ReadOptions(pnh)), tf_listener_(tf_buffer_) {
    pnh_.param<std::string>("map_frame", map_frame_, "map");
    pnh_.param<std::string>("odom_frame", odom_frame_, "");
    pnh_.param<std::string>("base_frame", base_frame_, "");
    pnh_.param<std::string>("camera_frame", camera_frame_, "");
    pnh_.param("publish_tf", publish_tf_, true);
    pnh_.param("optimize_rate", optimize_rate_, 1.0);
    pnh_.param("closure_wait", closure_wait_, 5.0);
    pnh_.param<std::string>("trajectory_csv", trajectory_csv_, "");
    std::vector<double> offset;
    if (pnh_.getParam("camera_offset", offset)) {
      if (offset.size() != 3 || !std::isfinite(offset[0]) || !std::isfinite(offset[1]) ||
          !std::isfinite(offset[2])) {
        throw std::invalid_argument(
            "~camera_offset must be [x, y, yaw]: the camera footprint in the base frame");
      }
      fixed_offset_ = Pose2D{offset[0], offset[1], offset[2]};
    }
    if (!(optimize_rate_ > 0)) throw std::invalid_argument("~optimize_rate must be > 0 (Hz)");
    if (!(closure_wait_ > 0)) throw std::invalid_argument("~closure_wait must be > 0 (s)");
    if (map_frame_.empty()) throw std::invalid_argument("~map_frame must not be empty");

    path_pub_ = pnh_.advertise<nav_msgs::Path>("path", 1, true);
    save_srv_ = pnh_.advertiseService("save_trajectory", &Backend::OnSave, this);
    timer_ = nh_.createTimer(ros::Duration(1.0 / optimize_rate_), &Backend::OnTimer, this);
    odom_sub_ = nh_.subscribe("odom", 2000, &Backend::OnOdometry, this);
    closure_sub_ = nh_.subscribe("loop_closures", 2000, &Backend::OnClosure, this);
    keyframe_sub_ = nh_.subscribe("keyframes", 2000, &Backend::OnKeyframe, this);
    fix_sub_ = nh_.subscribe("fixes", 2000, &Backend::OnFix, this);
    keyframe_poses_pub_ = nh_.advertise<ground_texture_bow::KeyframePoses>("keyframe_poses", 10);
    const PoseGraphOptions& o = graph_.options();
    ROS_INFO("pose_graph_backend: loss %s (%.1f sigma), consistency check %s, map frame %s%s",
             o.loss.c_str(), o.loss_scale, o.consistency_check ? "on" : "off", map_frame_.c_str(),
             o.anchor_at_start ? " (the odometry frame at the start)"
                               : " (an earlier map's: placed by the first fixes)");
  }

  // At shutdown: the final optimisation and ~trajectory_csv.
  void Finish() {
    if (trajectory_csv_.empty()) return;
    std::string error;
    Optimize();
    if (!WriteTrajectory(trajectory_csv_, &error)) {
      ROS_ERROR("pose_graph_backend: %s", error.c_str());
    } else {
      ROS_INFO("pose_graph_backend: trajectory written to %s", trajectory_csv_.c_str());
    }
  }

 private:
  static PoseGraphOptions ReadOptions(ros::NodeHandle& pnh) {
    PoseGraphOptions o;
    pnh.param("odom_sigma_xy", o.odom_sigma_xy, o.odom_sigma_xy);
    pnh.param("odom_sigma_theta", o.odom_sigma_theta, o.odom_sigma_theta);
    pnh.param("odom_sigma_turn", o.odom_sigma_turn, o.odom_sigma_turn);
    pnh.param("closure_min_sigma_xy", o.closure_min_sigma_xy, o.closure_min_sigma_xy);
    pnh.param("closure_min_sigma_theta", o.closure_min_sigma_theta, o.closure_min_sigma_theta);
    pnh.param("loss", o.loss, o.loss);
    pnh.param("loss_scale", o.loss_scale, o.loss_scale);
    pnh.param("consistency_check", o.consistency_check, o.consistency_check);
    pnh.param("consistency_window", o.consistency_window, o.consistency_window);
    pnh.param("consistency_chi2", o.consistency_chi2, o.consistency_chi2);
    pnh.param("max_iterations", o.max_iterations, o.max_iterations);
    std::string anchor = "start";
    pnh.param<std::string>("anchor", anchor, anchor);
    if (anchor != "start" && anchor != "fixes") {
      throw std::invalid_argument(
          "~anchor must be start (a new map) or fixes (a session on an "
          "earlier map), not '" +
          anchor + "'");
    }
    o.anchor_at_start = anchor == "start";
    o.Check();  // throws naming the bad parameter
    return o;
  }

  void OnOdometry(const nav_msgs::Odometry& msg) {
    const auto& p = msg.pose.pose;
    const Pose2D pose{
        p.position.x, p.position.y,
        gtbow_ros::YawOf(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)};
    if (!base_frame_.empty() && !msg.child_frame_id.empty() && msg.child_frame_id != base_frame_) {
      ROS_WARN_THROTTLE(5.0, "pose_graph_backend: odometry of '%s', expected ~base_frame '%s'",
                        msg.child_frame_id.c_str(), base_frame_.c_str());
    }
    if (odom_frame_.empty()) odom_frame_ = msg.header.frame_id;
    if (base_frame_.empty()) base_frame_ = msg.child_frame_id;
    try {
      graph_.AddOdometry(Ns(msg.header.stamp), pose);
    } catch (const std::exception& e) {
      ++bad_odometry_;
      ROS_WARN_THROTTLE(2.0, "pose_graph_backend: odometry at %s ignored: %s",
                        StampText(msg.header.stamp).c_str(), e.what());
      return;
    }
    DrainWaiting();
    // map -> odom from the first odometry on (the identity until a closure moves it): a
    // localizer placing keyframes through it needs it before the first optimisation.
    if (!last_tf_) PublishTf();  // (not before an earlier map's frame is placed)
  }

  // A keyframe the localizer added; a new stamp for a known id is a new map (reset or loaded).
  void OnKeyframe(const ground_texture_bow::KeyframeStamp& msg) {
    if (msg.header.stamp.isZero() ||
        (msg.header.frame_id.empty() && camera_frame_.empty() && !fixed_offset_)) {
      return Reject("keyframe " + std::to_string(msg.id) + ": zero stamp or no camera frame");
    }
    KeyframeEntry& k = keyframes_[msg.id];
    const int64_t stamp = Ns(msg.header.stamp);
    if (k.stamp_ns != stamp) k = KeyframeEntry{};
    k.stamp_ns = stamp;
    k.frame = camera_frame_.empty() ? msg.header.frame_id : camera_frame_;
  }

  // The camera footprint in map_frame at each keyframe's stamp that the odometry covers, for the
  // keyframes whose pose changed since it was last sent (or was never sent). Returns the stamp
  // of the message published (zero: none).
  ros::Time PublishKeyframePoses() {
    if (!graph_.anchored()) return ros::Time();  // no map frame yet
    ground_texture_bow::KeyframePoses msg;
    for (auto& [id, k] : keyframes_) {
      if (!graph_.Covers(k.stamp_ns)) continue;
      const std::optional<Pose2D> e = CameraOffset(k.frame);
      if (!e) continue;
      const Pose2D p = gtbow::Compose(graph_.PoseAt(k.stamp_ns), *e);
      constexpr double kSame = 1e-7;  // m and rad: below what a map's pose carries
      if (k.sent && std::abs(p.x - k.sent->x) < kSame && std::abs(p.y - k.sent->y) < kSame &&
          std::abs(gtbow::WrapAngle(p.theta - k.sent->theta)) < kSame) {
        continue;
      }
      k.sent = p;
      msg.ids.push_back(id);
      ros::Time t;
      t.fromNSec(static_cast<uint64_t>(k.stamp_ns));
      msg.stamps.push_back(t);
      msg.poses.push_back(
          gtbow_ros::ToPose2DMsg(gtbow::Pose2D{p.x, p.y, gtbow::WrapAngle(p.theta)}));
    }
    if (msg.ids.empty()) return ros::Time();
    msg.header.frame_id = map_frame_;
    msg.header.stamp = ros::Time::now();
    // Distinct stamps for consecutive messages, so that a caller can tell which one was applied.
    if (msg.header.stamp <= last_poses_stamp_) {
      msg.header.stamp = last_poses_stamp_ + ros::Duration(0, 1000);
    }
    last_poses_stamp_ = msg.header.stamp;
    keyframe_poses_pub_.publish(msg);
    return msg.header.stamp;
  }

  // The robot's base in map_frame from a match to an earlier map's keyframes (the localizer's
  // ~pose in a session on a loaded map).
  void OnFix(const geometry_msgs::PoseWithCovarianceStamped& msg) {
    ++fixes_received_;
    const std::string what = "fix at " + StampText(msg.header.stamp);
    if (msg.header.frame_id != map_frame_) {
      return Reject(what + ": in frame '" + msg.header.frame_id + "', not ~map_frame '" +
                    map_frame_ + "'");
    }
    if (msg.header.stamp.isZero()) return Reject(what + ": zero stamp");
    const auto& p = msg.pose.pose;
    gtbow::backend::Fix f;
    f.stamp_ns = Ns(msg.header.stamp);
    f.map_from_base = {
        p.position.x, p.position.y,
        gtbow_ros::YawOf(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)};
    const int idx[3] = {0, 1, 5};  // x, y, yaw of the 6 x 6 covariance
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j)
        f.covariance[3 * i + j] = msg.pose.covariance[6 * idx[i] + idx[j]];
    }
    for (double c : f.covariance) {
      if (!std::isfinite(c)) return Reject(what + ": non-finite covariance");
    }
    waiting_fixes_.push_back({f, ros::Time::now()});
    DrainWaiting();
  }

  void OnClosure(const LoopClosure& msg) {
    ++received_;
    const std::string what = "loop closure (query " + StampText(msg.query_stamp) + ", match " +
                             StampText(msg.match_stamp) + ")";
    if (msg.status != LoopClosure::VERIFIED) {
      return Reject(what + ": status " + std::to_string(msg.status) + ", not VERIFIED");
    }
    if (msg.query_stamp.isZero() || msg.match_stamp.isZero()) {
      return Reject(what + ": zero stamp");
    }
    const auto& m = msg.match_from_query;
    if (!std::isfinite(m.x) || !std::isfinite(m.y) || !std::isfinite(m.theta)) {
      return Reject(what + ": non-finite match_from_query");
    }
    for (double c : msg.covariance) {
      if (!std::isfinite(c)) return Reject(what + ": non-finite covariance");
    }
    if (msg.header.frame_id.empty() && !fixed_offset_) {
      return Reject(what + ": no camera frame in the header and no ~camera_offset");
    }
    waiting_.push_back({msg, ros::Time::now()});
    DrainWaiting();
  }

  void Reject(const std::string& why) {
    ++rejected_input_;
    ROS_WARN_THROTTLE(2.0, "pose_graph_backend: %s", why.c_str());
  }

  // The camera's footprint in the base frame: ~camera_offset, or TF base -> camera frame.
  std::optional<Pose2D> CameraOffset(const std::string& frame) {
    if (fixed_offset_) return fixed_offset_;
    auto it = offsets_.find(frame);
    if (it != offsets_.end()) return it->second;
    if (base_frame_.empty()) return std::nullopt;  // no odometry yet
    try {
      const auto t = tf_buffer_.lookupTransform(base_frame_, frame, ros::Time(0));
      const Pose2D e = gtbow_ros::FootprintFromTransform(t.transform);
      offsets_[frame] = e;
      ROS_INFO("pose_graph_backend: camera %s at (%.4f, %.4f, %.4f rad) in %s", frame.c_str(), e.x,
               e.y, e.theta, base_frame_.c_str());
      return e;
    } catch (const std::exception& e) {
      ROS_WARN_THROTTLE(5.0, "pose_graph_backend: no camera mounting %s -> %s yet: %s",
                        base_frame_.c_str(), frame.c_str(), e.what());
      return std::nullopt;
    }
  }

  // Closures enter the graph once the odometry covers both stamps and the mounting is known.
  void DrainWaiting() {
    const ros::Time now = ros::Time::now();
    while (!waiting_fixes_.empty()) {
      const gtbow::backend::Fix& f = waiting_fixes_.front().fix;
      ros::Time stamp;
      stamp.fromNSec(static_cast<uint64_t>(f.stamp_ns));
      if (!graph_.Covers(f.stamp_ns)) {
        if (graph_.HasOdometry() && f.stamp_ns < graph_.FirstStamp()) {
          waiting_fixes_.pop_front();
          Reject("fix at " + StampText(stamp) + ": before the first odometry");
          continue;
        }
        if ((now - waiting_fixes_.front().received).toSec() <= closure_wait_) break;
        waiting_fixes_.pop_front();
        Reject("fix at " + StampText(stamp) + ": no odometry for its stamp within ~closure_wait");
        continue;
      }
      const bool was = graph_.anchored();
      try {
        graph_.AddFix(f);
      } catch (const std::exception& ex) {
        Reject("fix at " + StampText(stamp) + ": " + ex.what());
      }
      if (!was && graph_.anchored()) {
        ros::Time at;
        at.fromNSec(static_cast<uint64_t>(graph_.anchored_at_ns()));
        ROS_INFO("pose_graph_backend: placed in %s by the fix at %s (%zu fixes so far)",
                 map_frame_.c_str(), StampText(at).c_str(), graph_.fixes_added());
      }
      waiting_fixes_.pop_front();
    }
    while (!waiting_.empty()) {
      const LoopClosure& msg = waiting_.front().msg;
      const std::string what = "loop closure (query " + StampText(msg.query_stamp) + ", match " +
                               StampText(msg.match_stamp) + ")";
      const bool expired = (now - waiting_.front().received).toSec() > closure_wait_;
      const int64_t q = Ns(msg.query_stamp), mt = Ns(msg.match_stamp);
      if (graph_.HasOdometry() && (q < graph_.FirstStamp() || mt < graph_.FirstStamp())) {
        waiting_.pop_front();
        Reject(what + ": before the first odometry");
        continue;
      }
      const std::optional<Pose2D> e =
          CameraOffset(camera_frame_.empty() ? msg.header.frame_id : camera_frame_);
      if (!graph_.Covers(q) || !graph_.Covers(mt) || !e) {
        if (!expired) return;  // in order: the next ones are no older
        waiting_.pop_front();
        Reject(what + (e ? ": no odometry for its stamps" : ": no camera mounting") +
               " within ~closure_wait");
        continue;
      }
      if (!camera_offset_) camera_offset_ = e;
      try {
        const ClosureState s = graph_.AddClosure(ToBaseClosure(msg, *e));
        ids_[{q, mt}].push_back(graph_.closures_added() - 1);
        if (s == ClosureState::kRejected) ++rejected_input_;
      } catch (const std::exception& ex) {
        Reject(what + ": " + ex.what());
      }
      waiting_.pop_front();
    }
  }

  gtbow::backend::SolveReport Optimize() {
    DrainWaiting();
    const auto r = graph_.Optimize();
    if (r.ran) {
      last_downweighted_ = r.downweighted;
      ROS_INFO_THROTTLE(5.0,
                        "pose_graph_backend: %zu nodes, %zu closures (%zu pending, %zu beyond "
                        "%.1f sigma), %d iterations in %.3f s, cost %.4g -> %.4g",
                        r.nodes, r.closure_edges, graph_.pending(), r.downweighted,
                        graph_.options().loss_scale, r.iterations, r.seconds, r.initial_cost,
                        r.final_cost);
      PublishPath();
    }
    return r;
  }

  void OnTimer(const ros::TimerEvent&) {
    Optimize();
    PublishKeyframePoses();
    PublishTf();
  }

  void PublishTf() {
    if (publish_tf_ && graph_.HasOdometry() && !odom_frame_.empty() && graph_.anchored()) {
      const Pose2D m = graph_.MapFromOdom();
      // TF ignores a repeated stamp: once the odometry stops, a changed correction goes out
      // 1 ms after the previous one, an unchanged one not at all.
      const int64_t last = graph_.LastStamp();
      const bool changed =
          !last_tf_ || last_tf_->x != m.x || last_tf_->y != m.y || last_tf_->theta != m.theta;
      if (last <= last_tf_stamp_ && !changed) return;
      last_tf_stamp_ = std::max(last, last_tf_stamp_ + 1000000);
      last_tf_ = m;
      geometry_msgs::TransformStamped t;
      t.header.stamp.fromNSec(static_cast<uint64_t>(last_tf_stamp_));
      t.header.frame_id = map_frame_;
      t.child_frame_id = odom_frame_;
      t.transform.translation.x = m.x;
      t.transform.translation.y = m.y;
      t.transform.rotation = gtbow_ros::QuaternionFromYaw(m.theta);
      tf_broadcaster_.sendTransform(t);
    }
  }

  void PublishPath() {
    if (path_pub_.getNumSubscribers() == 0 || !graph_.HasOdometry()) return;
    nav_msgs::Path path;
    path.header.frame_id = map_frame_;
    path.header.stamp.fromNSec(static_cast<uint64_t>(graph_.LastStamp()));
    for (const auto& p : graph_.Trajectory()) {
      geometry_msgs::PoseStamped ps;
      ps.header.frame_id = map_frame_;
      ps.header.stamp.fromNSec(static_cast<uint64_t>(p.stamp_ns));
      ps.pose.position.x = p.map_from_base.x;
      ps.pose.position.y = p.map_from_base.y;
      ps.pose.orientation = gtbow_ros::QuaternionFromYaw(p.map_from_base.theta);
      path.poses.push_back(ps);
    }
    path_pub_.publish(path);
  }

  bool WriteTrajectory(const std::string& path, std::string* error) {
    if (!graph_.HasOdometry()) {
      *error = "no odometry received: no trajectory to write to " + path;
      return false;
    }
    if (!graph_.anchored()) {
      *error = "not placed in " + map_frame_ + " yet (no two agreeing fixes from the earlier " +
               "map): no trajectory to write to " + path;
      return false;
    }
    if (!camera_offset_ && !camera_frame_.empty()) camera_offset_ = CameraOffset(camera_frame_);
    const std::string tmp = path + ".partial";
    {
      std::ofstream f(tmp);
      if (!f) {
        *error = "cannot write " + tmp;
        return false;
      }
      f << "stamp,x,y,theta,camera_x,camera_y,camera_theta,odom_x,odom_y,odom_theta\n";
      char line[320];
      for (const auto& p : graph_.Trajectory()) {
        Pose2D cam{NAN, NAN, NAN};
        if (camera_offset_) cam = gtbow::Compose(p.map_from_base, *camera_offset_);
        std::snprintf(line, sizeof(line), "%.9f,%.7f,%.7f,%.7f,%.7f,%.7f,%.7f,%.7f,%.7f,%.7f\n",
                      p.stamp_ns * 1e-9, p.map_from_base.x, p.map_from_base.y,
                      p.map_from_base.theta, cam.x, cam.y, gtbow::WrapAngle(cam.theta),
                      p.odom_from_base.x, p.odom_from_base.y, p.odom_from_base.theta);
        f << line;
      }
      if (!f.flush()) {
        *error = "cannot write " + tmp;
        return false;
      }
    }
    std::error_code ec;
    std::filesystem::rename(tmp, path, ec);
    if (ec) {
      *error = "cannot rename " + tmp + " to " + path + ": " + ec.message();
      return false;
    }
    return true;
  }

  bool OnSave(ground_texture_bow::SaveTrajectory::Request& req,
              ground_texture_bow::SaveTrajectory::Response& res) {
    Optimize();
    res.nodes = static_cast<uint32_t>(graph_.nodes());
    res.closures_received = static_cast<uint32_t>(received_);
    res.closures_accepted = static_cast<uint32_t>(graph_.accepted());
    res.closures_pending = static_cast<uint32_t>(graph_.pending());
    res.closures_rejected = static_cast<uint32_t>(rejected_input_);
    res.closures_downweighted = static_cast<uint32_t>(last_downweighted_);
    // The newest keyframe_poses message (this call's, or an earlier one when no pose changed
    // since): once applied, the localizer holds the poses of this optimisation.
    PublishKeyframePoses();
    res.keyframe_poses_stamp = last_poses_stamp_;
    res.fixes_received = static_cast<uint32_t>(fixes_received_);
    res.fixes_accepted = static_cast<uint32_t>(graph_.fixes_accepted());
    res.anchored = graph_.anchored();
    res.anchored_at.fromNSec(static_cast<uint64_t>(graph_.anchored_at_ns()));
    if (req.closure_query_stamps.size() != req.closure_match_stamps.size()) {
      res.status =
          gtbow_ros::MakeStatus(ground_texture_bow::Status::INVALID_ARGUMENT,
                                "closure_query_stamps and closure_match_stamps differ in length (" +
                                    std::to_string(req.closure_query_stamps.size()) + " and " +
                                    std::to_string(req.closure_match_stamps.size()) + ")");
      return true;
    }
    for (size_t i = 0; i < req.closure_query_stamps.size(); ++i) {
      res.closure_states.push_back(
          StateOf(Ns(req.closure_query_stamps[i]), Ns(req.closure_match_stamps[i])));
    }
    if (req.path.empty()) {
      res.status = gtbow_ros::MakeStatus(ground_texture_bow::Status::OK, "optimised");
      return true;
    }
    std::string error;
    if (WriteTrajectory(req.path, &error)) {
      res.status = gtbow_ros::MakeStatus(ground_texture_bow::Status::OK,
                                         "trajectory written to " + req.path);
    } else {
      res.status = gtbow_ros::MakeStatus(ground_texture_bow::Status::FAILED_PRECONDITION, error);
    }
    return true;
  }

  // The state of the closures with these stamps, as ~save_trajectory reports it.
  uint8_t StateOf(int64_t query_ns, int64_t match_ns) const {
    using Srv = ground_texture_bow::SaveTrajectory::Response;
    const auto it = ids_.find({query_ns, match_ns});
    if (it == ids_.end()) return Srv::NOT_IN_GRAPH;
    bool pending = false;
    for (const size_t id : it->second) {
      const ClosureState s = graph_.State(id);
      if (s == ClosureState::kAccepted) return Srv::ACCEPTED;
      pending |= s == ClosureState::kPending;
    }
    return pending ? Srv::PENDING : Srv::REJECTED;
  }

  struct Waiting {
    LoopClosure msg;
    ros::Time received;
  };
  struct WaitingFix {
    gtbow::backend::Fix fix;
    ros::Time received;
  };
  struct KeyframeEntry {
    int64_t stamp_ns = 0;
    std::string frame;           // the camera frame its mounting is looked up for
    std::optional<Pose2D> sent;  // the pose last published for it
  };

  ros::NodeHandle nh_, pnh_;
  PoseGraph graph_;
  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;
  ros::Subscriber odom_sub_, closure_sub_, keyframe_sub_, fix_sub_;
  std::deque<WaitingFix> waiting_fixes_;
  size_t fixes_received_ = 0;
  ros::Publisher path_pub_, keyframe_poses_pub_;
  std::map<uint32_t, KeyframeEntry> keyframes_;  // the localizer's keyframes, by id
  ros::Time last_poses_stamp_;
  ros::ServiceServer save_srv_;
  ros::Timer timer_;
  std::string map_frame_, odom_frame_, base_frame_, camera_frame_, trajectory_csv_;
  bool publish_tf_ = true;
  double optimize_rate_ = 1.0, closure_wait_ = 5.0;
  std::optional<Pose2D> fixed_offset_, camera_offset_, last_tf_;
  int64_t last_tf_stamp_ = 0;
  std::map<std::string, Pose2D> offsets_;
  // The pose graph's ids of the closures added, by (query, match) stamp.
  std::map<std::pair<int64_t, int64_t>, std::vector<size_t>> ids_;
  std::deque<Waiting> waiting_;
  size_t received_ = 0, rejected_input_ = 0, bad_odometry_ = 0, last_downweighted_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "pose_graph_backend");
  ros::NodeHandle nh, pnh("~");
  std::unique_ptr<Backend> backend;
  try {
    backend = std::make_unique<Backend>(nh, pnh);
  } catch (const std::exception& e) {
    ROS_FATAL("pose_graph_backend: %s", e.what());
    return 2;
  }
  ros::spin();
  backend->Finish();
  return 0;
}
