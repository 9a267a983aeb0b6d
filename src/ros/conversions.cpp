#include "ground_texture_bow/ros/conversions.h"

#include <cmath>
#include <stdexcept>

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/image_encodings.h>
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
  int channels = 0, depth_bytes = 1;
  if (e == enc::MONO8) {
    channels = 1;
  } else if (e == enc::MONO16) {
    channels = 1;
    depth_bytes = 2;
  } else if (e == enc::BGR8 || e == enc::RGB8) {
    channels = 3;
  } else if (e == enc::BGRA8 || e == enc::RGBA8) {
    channels = 4;
  } else {
    throw std::invalid_argument("unsupported encoding '" + e +
                                "' (mono8, mono16, bgr8, rgb8, bgra8 or rgba8 expected)");
  }
  const size_t row = static_cast<size_t>(msg.width) * channels * depth_bytes;
  if (msg.step < row || msg.data.size() < static_cast<size_t>(msg.step) * (msg.height - 1) + row) {
    throw std::invalid_argument("image data (" + std::to_string(msg.data.size()) + " bytes, step " +
                                std::to_string(msg.step) + ") is too small for " +
                                std::to_string(msg.width) + "x" + std::to_string(msg.height) + " " +
                                e);
  }
  cv_bridge::CvImageConstPtr cv = cv_bridge::toCvShare(
      boost::shared_ptr<const sensor_msgs::Image>(&msg, [](const sensor_msgs::Image*) {}), e);
  cv::Mat gray;
  const cv::Mat& in = cv->image;
  if (e == enc::MONO8) {
    gray = in;
  } else if (e == enc::MONO16) {
    in.convertTo(gray, CV_8U, 1.0 / 256.0);
  } else if (e == enc::BGR8) {
    cv::cvtColor(in, gray, cv::COLOR_BGR2GRAY);
  } else if (e == enc::RGB8) {
    cv::cvtColor(in, gray, cv::COLOR_RGB2GRAY);
  } else if (e == enc::BGRA8) {
    cv::cvtColor(in, gray, cv::COLOR_BGRA2GRAY);
  } else {
    cv::cvtColor(in, gray, cv::COLOR_RGBA2GRAY);
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

ground_texture_bow::Status MakeStatus(uint8_t code, const std::string& message) {
  ground_texture_bow::Status s;
  s.code = code;
  s.message = message;
  return s;
}

}  // namespace gtbow_ros
