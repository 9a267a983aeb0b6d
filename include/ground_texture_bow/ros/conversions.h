// Conversions between ROS messages and the core's types, as free functions (each unit-tested in
// test/ros/conversions_test.cpp), in the manner of cartographer_ros's msg_conversion.h.
//
// Frames. The camera frame is an optical frame (REP-103: x right = image u, y down = image v,
// z forward = down onto the floor). Such a camera sees the floor mirrored with respect to the
// map (z up), so images are flipped upside down before they reach the core, which then sees the
// floor from above: pixel (u, v') maps to the map plane through a rotation. A camera's planar
// pose ("footprint") is the floor point under the image centre and the yaw of the camera's x
// axis in the map, metres and radians.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <geometry_msgs/Pose2D.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <geometry_msgs/Transform.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2/buffer_core.h>
#include <opencv2/core.hpp>

#include "ground_texture_bow/Candidate.h"
#include "ground_texture_bow/Status.h"
#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/core/localizer.h"

namespace gtbow_ros {

// The core's view of an image message: 8-bit grey, flipped upside down (see above). Accepts
// mono8, mono16, bgr8, rgb8, bgra8 and rgba8, and every other encoding cv_bridge converts to
// mono8 (Bayer, YUV422, 16-bit colour; raw or decoded from compressed transport). Throws
// std::invalid_argument naming the problem: unsupported encoding, empty image, inconsistent
// step or data size.
cv::Mat ToFloorImage(const sensor_msgs::Image& msg);
// The same for a compressed image (sensor_msgs/CompressedImage: JPEG or PNG, any channel count),
// decoded with OpenCV. Throws std::invalid_argument when it is empty or cannot be decoded.
cv::Mat ToFloorImage(const sensor_msgs::CompressedImage& msg);

// The planar footprint of a downward camera from its pose in the map (e.g. a TF lookup of
// map -> camera optical frame). Throws std::invalid_argument for non-finite values or a camera
// whose z axis is more than `max_tilt` radians from straight down.
gtbow::Pose2D FootprintFromTransform(const geometry_msgs::Transform& map_from_camera,
                                     double max_tilt = 0.35);

// The inverse for a camera at `height` metres above the floor: the optical frame's transform.
geometry_msgs::Transform TransformFromFootprint(const gtbow::Pose2D& footprint, double height);

// A relative pose of the core (the query in the match image's above-view frame, x along u and
// y along -v) expressed in the match camera's optical frame: (x, -y, -theta), covariance
// transformed alike.
geometry_msgs::Pose2D ToOpticalPose2D(const gtbow::Pose2D& above);
std::array<double, 9> ToOpticalCovariance(const std::array<double, 9>& above);

geometry_msgs::Pose2D ToPose2DMsg(const gtbow::Pose2D& pose);
gtbow::Pose2D FromPose2DMsg(const geometry_msgs::Pose2D& msg);  // throws for non-finite values

// A planar fix as PoseWithCovarianceStamped (amcl_pose's form): z = 0, roll = pitch = 0, the
// x, y, yaw covariance placed in the 6x6 matrix and `planar_variance` on z, roll and pitch.
geometry_msgs::PoseWithCovarianceStamped ToPoseWithCovariance(
    const gtbow::Pose2D& pose, const std::array<double, 9>& covariance, const ros::Time& stamp,
    const std::string& frame_id, double planar_variance = 1e-9);

// The ground sampling distance (metres per pixel) of a downward camera at `height` metres above
// the floor: height / f, with f the focal length in pixels of K (divided by the binning).
// Throws std::invalid_argument naming the problem: no K (all zero, as an uncalibrated driver
// sends), pixels that are not square (fx and fy more than 1% apart), or a height that is not
// positive.
double MetersPerPixelFromCameraInfo(const sensor_msgs::CameraInfo& info, double height);

// A downward camera's height above the floor from TF: its latest z in the first of `frames`
// that exists and reaches it with a positive height (each frame's z = 0 plane taken as the
// floor, as REP-120's base_footprint). `source` says which ("TF base_link -> camera").
struct CameraHeightFromTf {
  double height = 0;
  std::string source;
};
std::optional<CameraHeightFromTf> LookupCameraHeight(const tf2::BufferCore& tf,
                                                     const std::vector<std::string>& frames,
                                                     const std::string& camera);

// Whether the camera_info's distortion is other than none (all coefficients zero).
bool HasDistortion(const sensor_msgs::CameraInfo& info);

// Undistorts floor images (flipped, as ToFloorImage gives them) of a camera with distortion,
// onto the pinhole image of the same K (so the scale is unchanged). The maps are computed once
// per camera_info (K, D, size, model) and kept. Thread-compatible: one per worker.
class Rectifier {
 public:
  // Throws std::invalid_argument for a distortion model other than plumb_bob or
  // rational_polynomial, or an image whose size is not the camera_info's.
  cv::Mat Rectify(const cv::Mat& floor_image, const sensor_msgs::CameraInfo& info);

 private:
  sensor_msgs::CameraInfo cached_;  // the camera_info the maps are for
  cv::Mat map_x_, map_y_;
};

// A fix's 3x3 (x, y, yaw) covariance with its diagonal raised to at least the floors: RANSAC's
// own value is sub-millimetre, which a filter would trust more than any fix deserves.
std::array<double, 9> FlooredCovariance(const std::array<double, 9>& covariance,
                                        double min_position_variance, double min_yaw_variance);

// A robot base's pose from its camera's: map_from_base = map_from_camera * base_from_camera^-1
// (camera footprints, geometry.h), and the covariance carried through the lever arm, J C J^T.
struct BasePose {
  gtbow::Pose2D pose;
  std::array<double, 9> covariance{};
};
BasePose BaseFromCamera(const gtbow::Pose2D& map_from_camera,
                        const std::array<double, 9>& covariance,
                        const gtbow::Pose2D& base_from_camera);

// Nanoseconds since the epoch and back.
int64_t ToNanoseconds(const ros::Time& t);
ros::Time FromNanoseconds(int64_t ns);

// A core candidate as a message (relative pose in the optical frame).
ground_texture_bow::Candidate ToCandidateMsg(const gtbow::Candidate& candidate);

// A service status.
ground_texture_bow::Status MakeStatus(uint8_t code, const std::string& message);

// Yaw (radians) of a quaternion's x axis projected on the x-y plane.
double YawOf(double qx, double qy, double qz, double qw);
// The rotation by `yaw` radians about z.
geometry_msgs::Quaternion QuaternionFromYaw(double yaw);

}  // namespace gtbow_ros
