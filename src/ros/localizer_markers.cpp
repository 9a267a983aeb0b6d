// What the localizer node draws: the debug image (keypoints, verified matches, caption) and the
// RViz markers of the map (keyframe footprints, loop-closure edges).
#include <cmath>

#include <cv_bridge/cv_bridge.h>
#include <visualization_msgs/MarkerArray.h>
#include <opencv2/imgproc.hpp>

#include "ground_texture_bow/ros/conversions.h"
#include "ground_texture_bow/ros/localizer_server.h"

namespace gtbow_ros {

void LocalizerServer::PublishDebugImage(const cv::Mat& floor_image,
                                        const gtbow::ProcessedImage& img,
                                        const std::vector<gtbow::Vec2>& inliers,
                                        const std::string& caption,
                                        const std_msgs::Header& header) {
  cv::Mat color;
  cv::Mat camera_view;
  cv::flip(floor_image, camera_view, 0);  // back to the camera's view
  cv::cvtColor(camera_view, color, cv::COLOR_GRAY2BGR);
  const float last_row = static_cast<float>(floor_image.rows - 1);
  for (const auto& k : img.features.keypoints) {
    cv::circle(color, cv::Point2f(k.x, last_row - k.y), std::max(2.0f, 0.5f * k.size),
               cv::Scalar(0, 200, 0), 1, cv::LINE_AA);
  }
  for (const auto& p : inliers) {
    cv::circle(color, cv::Point2f(static_cast<float>(p.x), last_row - static_cast<float>(p.y)), 4,
               cv::Scalar(0, 0, 255), 2, cv::LINE_AA);
  }
  cv::putText(color, caption, cv::Point(8, 24), cv::FONT_HERSHEY_SIMPLEX, 0.7,
              cv::Scalar(0, 255, 255), 2, cv::LINE_AA);
  debug_pub_.publish(cv_bridge::CvImage(header, "bgr8", color).toImageMsg());
  debug_images_++;
}

void LocalizerServer::PublishMarkers(const ros::TimerEvent&) {
  if (markers_pub_.getNumSubscribers() == 0) return;
  visualization_msgs::MarkerArray arr;
  visualization_msgs::Marker fp, edges;
  fp.header.frame_id = edges.header.frame_id = options_.map_frame;
  // Stamp 0: the map does not move with time; RViz then uses the latest transform (a bag
  // replayed on wall time, a map frame that a backend corrects).
  fp.header.stamp = edges.header.stamp = ros::Time(0);
  fp.ns = "keyframes";
  edges.ns = "loop_closures";
  fp.type = edges.type = visualization_msgs::Marker::LINE_LIST;
  fp.action = edges.action = visualization_msgs::Marker::ADD;
  fp.pose.orientation.w = edges.pose.orientation.w = 1.0;
  fp.scale.x = 0.002;
  edges.scale.x = 0.004;
  fp.color.g = 0.8f;
  fp.color.a = 0.6f;
  edges.color.r = 1.0f;
  edges.color.a = 0.9f;
  const auto kfs = localizer_->Keyframes();
  for (const auto& k : kfs) {
    if (!k.has_pose) continue;
    const auto corners =
        gtbow::Footprint(k.map_from_camera, {k.width, k.height, localizer_->meters_per_pixel()});
    for (int i = 0; i < 4; ++i) {
      geometry_msgs::Point a, b;
      a.x = corners[i].x;
      a.y = corners[i].y;
      b.x = corners[(i + 1) % 4].x;
      b.y = corners[(i + 1) % 4].y;
      fp.points.push_back(a);
      fp.points.push_back(b);
    }
  }
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    for (const Edge& e : edges_) {
      if (e.from >= kfs.size() || e.to >= kfs.size()) continue;
      if (!kfs[e.from].has_pose || !kfs[e.to].has_pose) continue;
      geometry_msgs::Point a, b;
      a.x = kfs[e.from].map_from_camera.x;
      a.y = kfs[e.from].map_from_camera.y;
      b.x = kfs[e.to].map_from_camera.x;
      b.y = kfs[e.to].map_from_camera.y;
      edges.points.push_back(a);
      edges.points.push_back(b);
    }
  }
  if (fp.points.empty()) fp.action = visualization_msgs::Marker::DELETE;
  if (edges.points.empty()) edges.action = visualization_msgs::Marker::DELETE;
  arr.markers.push_back(fp);
  arr.markers.push_back(edges);
  markers_pub_.publish(arr);
}

}  // namespace gtbow_ros
