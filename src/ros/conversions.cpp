#include "ground_texture_bow/ros/conversions.h"

#include <cmath>
#include <stdexcept>

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/image_encodings.h>
#include <tf2/exceptions.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace gtbow_ros {

namespace enc = sensor_msgs::image_encodings;

cv::Mat ToFloorImage(const sensor_msgs::Image& msg) {
  if (msg.width == 0 || msg.height == 0) {
    throw std::invalid_argument("empty image (" + std::to_string(msg.width) + "x" +
                                std::to_string(msg.height) + ")");
  }
  const std::string& e = msg.encoding;
  const bool known = enc::isMono(e) || enc::isColor(e) || enc::isBayer(e) || e == enc::YUV422 ||
                     e == "yuv422_yuy2";
  int channels = 0, depth_bytes = 0;
  if (known) {
    channels = enc::numChannels(e);
    depth_bytes = enc::bitDepth(e) / 8;
  }
  if (channels <= 0 || depth_bytes <= 0) {
    throw std::invalid_argument("unsupported encoding '" + e +
                                "' (mono8, mono16, bgr8, rgb8, bgra8, rgba8, or another that "
                                "cv_bridge converts to mono8: Bayer, yuv422, 16-bit colour)");
  }
  const size_t row = static_cast<size_t>(msg.width) * channels * depth_bytes;
  if (msg.step < row || msg.data.size() < static_cast<size_t>(msg.step) * (msg.height - 1) + row) {
    throw std::invalid_argument("image data (" + std::to_string(msg.data.size()) + " bytes, step " +
                                std::to_string(msg.step) + ") is too small for " +
                                std::to_string(msg.width) + "x" + std::to_string(msg.height) + " " +
                                e);
  }
  const boost::shared_ptr<const sensor_msgs::Image> view(&msg, [](const sensor_msgs::Image*) {});
  cv::Mat gray;
  if (e == enc::MONO16) {
    // Scaled, not clipped: a 16-bit camera's full range onto 8 bits.
    cv_bridge::toCvShare(view, e)->image.convertTo(gray, CV_8U, 1.0 / 256.0);
  } else {
    try {
      gray = cv_bridge::toCvShare(view, enc::MONO8)->image;
    } catch (const std::exception& ex) {  // cv_bridge::Exception, cv::Exception
      throw std::invalid_argument("cannot convert encoding '" + e + "' to mono8: " + ex.what());
    }
  }
  cv::Mat flipped;
  cv::flip(gray, flipped, 0);  // optical frame -> floor seen from above (always a new buffer)
  return flipped;
}

cv::Mat ToFloorImage(const sensor_msgs::CompressedImage& msg) {
  if (msg.data.empty()) throw std::invalid_argument("empty compressed image");
  const cv::Mat buf(1, static_cast<int>(msg.data.size()), CV_8U,
                    const_cast<uint8_t*>(msg.data.data()));
  cv::Mat gray;
  try {
    gray = cv::imdecode(buf, cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception&) {
    gray.release();
  }
  if (gray.empty()) {
    throw std::invalid_argument("cannot decode the compressed image (format '" + msg.format +
                                "', " + std::to_string(msg.data.size()) + " bytes)");
  }
  cv::Mat flipped;
  cv::flip(gray, flipped, 0);
  return flipped;
}

geometry_msgs::Quaternion QuaternionFromYaw(double yaw) {
  geometry_msgs::Quaternion q;
  q.z = std::sin(0.5 * yaw);
  q.w = std::cos(0.5 * yaw);
  return q;
}

double YawOf(double qx, double qy, double qz, double qw) {
  // The rotated x axis: first column of the rotation matrix.
  const double r00 = 1.0 - 2.0 * (qy * qy + qz * qz);
  const double r10 = 2.0 * (qx * qy + qz * qw);
  return std::atan2(r10, r00);
}

gtbow::Pose2D FootprintFromTransform(const geometry_msgs::Transform& t, double max_tilt) {
  const auto& q = t.rotation;
  const auto& p = t.translation;
  for (double v : {q.x, q.y, q.z, q.w, p.x, p.y, p.z}) {
    if (!std::isfinite(v)) throw std::invalid_argument("camera transform has a non-finite value");
  }
  const double n = std::sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
  if (n < 1e-6) throw std::invalid_argument("camera transform has a zero quaternion");
  const double x = q.x / n, y = q.y / n, z = q.z / n, w = q.w / n;
  // The camera's z axis in the map (third column); a downward camera has it near (0, 0, -1).
  const double zx = 2.0 * (x * z + y * w), zy = 2.0 * (y * z - x * w);
  const double zz = 1.0 - 2.0 * (x * x + y * y);
  const double tilt = std::acos(std::max(-1.0, std::min(1.0, -zz)));
  if (tilt > max_tilt) {
    throw std::invalid_argument("the camera is not looking down: its optical axis is " +
                                std::to_string(tilt * 180.0 / M_PI) + " degrees from vertical");
  }
  // The floor point under the image centre (the floor is the map's z = 0 plane).
  const double s = std::abs(zz) > 1e-9 ? -p.z / zz : 0.0;
  return {p.x + s * zx, p.y + s * zy, YawOf(x, y, z, w)};
}

geometry_msgs::Transform TransformFromFootprint(const gtbow::Pose2D& f, double height) {
  // R = Rz(theta) * Rx(pi): x along the yaw, y and z flipped (z points down).
  const double h = 0.5 * f.theta;
  geometry_msgs::Transform t;
  t.translation.x = f.x;
  t.translation.y = f.y;
  t.translation.z = height;
  // q = (cos h, 0, 0, sin h) * (0, 1, 0, 0) [w, x, y, z]
  t.rotation.w = 0.0;
  t.rotation.x = std::cos(h);
  t.rotation.y = std::sin(h);
  t.rotation.z = 0.0;
  return t;
}

geometry_msgs::Pose2D ToOpticalPose2D(const gtbow::Pose2D& above) {
  geometry_msgs::Pose2D m;
  m.x = above.x;
  m.y = -above.y;
  m.theta = -above.theta;
  return m;
}

std::array<double, 9> ToOpticalCovariance(const std::array<double, 9>& c) {
  // J = diag(1, -1, -1): entries mixing x with y or theta change sign.
  const double s[3] = {1.0, -1.0, -1.0};
  std::array<double, 9> out{};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) out[3 * i + j] = s[i] * s[j] * c[3 * i + j];
  }
  return out;
}

geometry_msgs::Pose2D ToPose2DMsg(const gtbow::Pose2D& p) {
  geometry_msgs::Pose2D m;
  m.x = p.x;
  m.y = p.y;
  m.theta = p.theta;
  return m;
}

gtbow::Pose2D FromPose2DMsg(const geometry_msgs::Pose2D& m) {
  if (!std::isfinite(m.x) || !std::isfinite(m.y) || !std::isfinite(m.theta)) {
    throw std::invalid_argument("pose has a non-finite value");
  }
  return {m.x, m.y, m.theta};
}

geometry_msgs::PoseWithCovarianceStamped ToPoseWithCovariance(const gtbow::Pose2D& p,
                                                              const std::array<double, 9>& c,
                                                              const ros::Time& stamp,
                                                              const std::string& frame_id,
                                                              double planar_variance) {
  geometry_msgs::PoseWithCovarianceStamped m;
  m.header.stamp = stamp;
  m.header.frame_id = frame_id;
  m.pose.pose.position.x = p.x;
  m.pose.pose.position.y = p.y;
  m.pose.pose.position.z = 0.0;
  m.pose.pose.orientation = QuaternionFromYaw(p.theta);
  // 6x6 row-major over (x, y, z, roll, pitch, yaw).
  const int idx[3] = {0, 1, 5};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m.pose.covariance[6 * idx[i] + idx[j]] = c[3 * i + j];
  }
  for (int k : {2, 3, 4}) m.pose.covariance[6 * k + k] = planar_variance;
  return m;
}

int64_t ToNanoseconds(const ros::Time& t) { return static_cast<int64_t>(t.toNSec()); }

ros::Time FromNanoseconds(int64_t ns) {
  ros::Time t;
  t.fromNSec(static_cast<uint64_t>(ns < 0 ? 0 : ns));
  return t;
}

ground_texture_bow::Candidate ToCandidateMsg(const gtbow::Candidate& c) {
  ground_texture_bow::Candidate m;
  m.id = c.id;
  m.stamp = FromNanoseconds(c.stamp_ns);
  m.score = c.score;
  m.has_pose = c.has_pose;
  if (c.has_pose) m.pose = ToPose2DMsg(c.map_from_camera);
  m.verified = c.verified;
  if (c.verified) {
    m.inliers = static_cast<uint32_t>(c.relative.inliers);
    m.match_from_query = ToOpticalPose2D(c.relative.floor_from_query);
    const auto cov = ToOpticalCovariance(c.relative.covariance);
    std::copy(cov.begin(), cov.end(), m.covariance.begin());
  } else {
    m.reason = c.relative.reason;
  }
  return m;
}

double MetersPerPixelFromCameraInfo(const sensor_msgs::CameraInfo& info, double height) {
  if (!(height > 0) || !std::isfinite(height)) {
    throw std::invalid_argument("the camera's height above the floor (" + std::to_string(height) +
                                " m) is not positive");
  }
  const double bx = info.binning_x > 1 ? info.binning_x : 1.0;
  const double by = info.binning_y > 1 ? info.binning_y : 1.0;
  const double fx = info.K[0] / bx, fy = info.K[4] / by;
  if (!(fx > 0) || !(fy > 0) || !std::isfinite(fx) || !std::isfinite(fy)) {
    throw std::invalid_argument(
        "camera_info has no focal length (K[0] = " + std::to_string(info.K[0]) +
        ", K[4] = " + std::to_string(info.K[4]) + "): is the camera calibrated?");
  }
  if (std::abs(fx - fy) > 0.01 * std::max(fx, fy)) {
    throw std::invalid_argument("camera_info's pixels are not square (fx " + std::to_string(fx) +
                                ", fy " + std::to_string(fy) +
                                "): the floor's scale would differ along u and v");
  }
  return height / (0.5 * (fx + fy));
}

std::optional<CameraHeightFromTf> LookupCameraHeight(const tf2::BufferCore& tf,
                                                     const std::vector<std::string>& frames,
                                                     const std::string& camera) {
  for (const std::string& f : frames) {
    if (f.empty() || !tf._frameExists(f)) continue;
    try {
      const double h = tf.lookupTransform(f, camera, ros::Time(0)).transform.translation.z;
      if (h > 0) return CameraHeightFromTf{h, "TF " + f + " -> " + camera};
    } catch (const tf2::TransformException&) {
    }
  }
  return std::nullopt;
}

bool HasDistortion(const sensor_msgs::CameraInfo& info) {
  for (double d : info.D) {
    if (d != 0.0) return true;
  }
  return false;
}

cv::Mat Rectifier::Rectify(const cv::Mat& floor_image, const sensor_msgs::CameraInfo& info) {
  if (info.distortion_model != "plumb_bob" && info.distortion_model != "rational_polynomial") {
    throw std::invalid_argument("camera_info's distortion model '" + info.distortion_model +
                                "' is not supported (plumb_bob or rational_polynomial; or feed "
                                "rectified images and set ~rectify false)");
  }
  if (static_cast<uint32_t>(floor_image.cols) != info.width ||
      static_cast<uint32_t>(floor_image.rows) != info.height) {
    throw std::invalid_argument("the image is " + std::to_string(floor_image.cols) + "x" +
                                std::to_string(floor_image.rows) + ", its camera_info " +
                                std::to_string(info.width) + "x" + std::to_string(info.height));
  }
  if (map_x_.empty() || cached_.K != info.K || cached_.D != info.D || cached_.width != info.width ||
      cached_.height != info.height || cached_.distortion_model != info.distortion_model) {
    const cv::Mat k(3, 3, CV_64F, const_cast<double*>(info.K.data()));
    const cv::Mat d(1, static_cast<int>(info.D.size()), CV_64F, const_cast<double*>(info.D.data()));
    cv::Mat mx, my;
    cv::initUndistortRectifyMap(k, d, cv::Mat(), k, floor_image.size(), CV_32FC1, mx, my);
    // The maps are for the optical image; the floor image is it upside down:
    // rect_floor(u, v) = optical(mx(u, H-1-v), my(u, H-1-v)) = floor(mx(..), H-1 - my(..)).
    cv::flip(mx, map_x_, 0);
    cv::flip(my, map_y_, 0);
    map_y_ = static_cast<float>(floor_image.rows - 1) - map_y_;
    cached_ = info;
  }
  cv::Mat out;
  cv::remap(floor_image, out, map_x_, map_y_, cv::INTER_LINEAR, cv::BORDER_CONSTANT, 0);
  return out;
}

std::array<double, 9> FlooredCovariance(const std::array<double, 9>& c, double min_position,
                                        double min_yaw) {
  std::array<double, 9> out = c;
  out[0] = std::max(out[0], min_position);
  out[4] = std::max(out[4], min_position);
  out[8] = std::max(out[8], min_yaw);
  return out;
}

BasePose BaseFromCamera(const gtbow::Pose2D& map_from_camera, const std::array<double, 9>& c,
                        const gtbow::Pose2D& base_from_camera) {
  const gtbow::Pose2D camera_from_base = gtbow::Inverse(base_from_camera);
  BasePose out;
  out.pose = gtbow::Compose(map_from_camera, camera_from_base);
  // d(base)/d(camera): the base moves with the camera's translation, and swings about it with
  // the camera's yaw by the lever arm R(theta) t.
  const double ct = std::cos(map_from_camera.theta), st = std::sin(map_from_camera.theta);
  const double tx = camera_from_base.x, ty = camera_from_base.y;
  const double j[9] = {1, 0, -st * tx - ct * ty, 0, 1, ct * tx - st * ty, 0, 0, 1};
  double jc[9];
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) {
      jc[3 * r + k] = 0;
      for (int m = 0; m < 3; ++m) jc[3 * r + k] += j[3 * r + m] * c[3 * m + k];
    }
  }
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) {
      double v = 0;
      for (int m = 0; m < 3; ++m) v += jc[3 * r + m] * j[3 * k + m];
      out.covariance[3 * r + k] = v;
    }
  }
  return out;
}

ground_texture_bow::Status MakeStatus(uint8_t code, const std::string& message) {
  ground_texture_bow::Status s;
  s.code = code;
  s.message = message;
  return s;
}

}  // namespace gtbow_ros
