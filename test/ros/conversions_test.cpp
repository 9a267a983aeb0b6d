// Unit tests of the message conversions (no ROS master needed).
#include "ground_texture_bow/ros/conversions.h"

#include <cmath>

#include <gtest/gtest.h>
#include <sensor_msgs/image_encodings.h>
#include <opencv2/imgcodecs.hpp>

namespace gtbow_ros {
namespace {

sensor_msgs::Image MakeImage(const std::string& encoding, int w, int h, int bytes_per_pixel) {
  sensor_msgs::Image m;
  m.width = w;
  m.height = h;
  m.encoding = encoding;
  m.step = w * bytes_per_pixel;
  m.data.resize(m.step * h);
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      for (int c = 0; c < bytes_per_pixel; ++c)
        m.data[v * m.step + u * bytes_per_pixel + c] = static_cast<uint8_t>(v * 10 + c);
    }
  }
  return m;
}

TEST(Conversions, ImagesOfEveryEncodingBecomeFlippedGrey) {
  // Row v of the message has value 10 v; the core sees it upside down.
  const cv::Mat mono = ToFloorImage(MakeImage("mono8", 4, 3, 1));
  ASSERT_EQ(mono.type(), CV_8UC1);
  EXPECT_EQ(mono.at<uint8_t>(0, 0), 20);
  EXPECT_EQ(mono.at<uint8_t>(2, 0), 0);
  // Colour: a grey pixel (equal channels) keeps its value.
  sensor_msgs::Image bgr = MakeImage("bgr8", 4, 3, 3);
  for (size_t i = 0; i < bgr.data.size(); i += 3) bgr.data[i + 1] = bgr.data[i + 2] = bgr.data[i];
  EXPECT_EQ(ToFloorImage(bgr).at<uint8_t>(0, 1), 20);
  sensor_msgs::Image rgb = bgr;
  rgb.encoding = "rgb8";
  EXPECT_EQ(ToFloorImage(rgb).at<uint8_t>(2, 3), 0);
  // mono16: the high byte.
  sensor_msgs::Image m16 = MakeImage("mono16", 4, 3, 2);
  for (size_t i = 0; i < m16.data.size(); i += 2) {
    const uint16_t v = static_cast<uint16_t>(m16.data[i] * 256);  // little endian
    m16.data[i] = v & 0xff;
    m16.data[i + 1] = v >> 8;
  }
  m16.is_bigendian = 0;
  EXPECT_EQ(ToFloorImage(m16).at<uint8_t>(0, 0), 20);
  // Row padding (step > width) is honoured.
  sensor_msgs::Image padded = MakeImage("mono8", 4, 3, 1);
  padded.step = 6;
  padded.data.assign(18, 7);
  EXPECT_EQ(ToFloorImage(padded).cols, 4);
}

TEST(Conversions, BayerAndYuvCamerasAreConvertedByCvBridge) {
  // A uniform grey Bayer mosaic and a grey YUV422 (UYVY: U Y V Y with U = V = 128) image.
  sensor_msgs::Image bayer = MakeImage("bayer_rggb8", 8, 6, 1);
  bayer.data.assign(bayer.data.size(), 90);
  const cv::Mat b = ToFloorImage(bayer);
  ASSERT_EQ(b.type(), CV_8UC1);
  EXPECT_EQ(b.cols, 8);
  EXPECT_NEAR(b.at<uint8_t>(3, 4), 90, 2);
  sensor_msgs::Image yuv = MakeImage("yuv422", 8, 6, 2);
  for (size_t i = 0; i < yuv.data.size(); i += 2) {
    yuv.data[i] = 128;
    yuv.data[i + 1] = 150;
  }
  EXPECT_NEAR(ToFloorImage(yuv).at<uint8_t>(2, 2), 150, 3);
}

TEST(Conversions, TheScaleComesFromKAndTheHeight) {
  sensor_msgs::CameraInfo info;
  info.K = {800, 0, 319.5, 0, 800, 239.5, 0, 0, 1};
  EXPECT_DOUBLE_EQ(MetersPerPixelFromCameraInfo(info, 0.2), 0.00025);
  info.binning_x = info.binning_y = 2;  // binned pixels are twice as large
  EXPECT_DOUBLE_EQ(MetersPerPixelFromCameraInfo(info, 0.2), 0.0005);
  info.binning_x = info.binning_y = 0;
  auto expect_reason = [](const sensor_msgs::CameraInfo& i, double h, const std::string& what) {
    try {
      MetersPerPixelFromCameraInfo(i, h);
      ADD_FAILURE() << "accepted: " << what;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  expect_reason(info, 0.0, "height");
  sensor_msgs::CameraInfo uncalibrated;
  expect_reason(uncalibrated, 0.2, "calibrated");
  sensor_msgs::CameraInfo stretched = info;
  stretched.K[4] = 830;
  expect_reason(stretched, 0.2, "not square");
  EXPECT_FALSE(HasDistortion(info));
  info.D = {-0.2, 0.05, 0, 0, 0};
  EXPECT_TRUE(HasDistortion(info));
}

TEST(Conversions, BasePosesCarryTheCovarianceThroughTheLeverArm) {
  // The camera 15 cm ahead of the base and turned 90 degrees; the camera at (1, 2), yaw 0.3.
  const gtbow::Pose2D base_from_camera{0.15, 0.0, M_PI / 2};
  const gtbow::Pose2D camera{1.0, 2.0, 0.3};
  const std::array<double, 9> c = {1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-4};
  const BasePose b = BaseFromCamera(camera, c, base_from_camera);
  // The base is 15 cm behind the camera along the base's x axis, which is the camera's yaw
  // minus 90 degrees.
  const double yaw = 0.3 - M_PI / 2;
  EXPECT_NEAR(b.pose.x, 1.0 - 0.15 * std::cos(yaw), 1e-12);
  EXPECT_NEAR(b.pose.y, 2.0 - 0.15 * std::sin(yaw), 1e-12);
  EXPECT_NEAR(b.pose.theta, yaw, 1e-12);
  // Composing back gives the camera.
  const gtbow::Pose2D back = gtbow::Compose(b.pose, base_from_camera);
  EXPECT_NEAR(back.x, 1.0, 1e-12);
  EXPECT_NEAR(back.y, 2.0, 1e-12);
  // The yaw's variance swings the base by the 15 cm lever: 1e-6 + 0.15^2 * 1e-4 in total.
  EXPECT_NEAR(b.covariance[0] + b.covariance[4], 2e-6 + 0.0225 * 1e-4, 1e-12);
  EXPECT_DOUBLE_EQ(b.covariance[8], 1e-4);
  // Against a numerical Jacobian.
  const double h = 1e-6;
  double j[3][3];
  for (int k = 0; k < 3; ++k) {
    gtbow::Pose2D p = camera;
    (k == 0 ? p.x : k == 1 ? p.y : p.theta) += h;
    const gtbow::Pose2D q = BaseFromCamera(p, c, base_from_camera).pose;
    j[0][k] = (q.x - b.pose.x) / h;
    j[1][k] = (q.y - b.pose.y) / h;
    j[2][k] = (q.theta - b.pose.theta) / h;
  }
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) {
      double v = 0;
      for (int m = 0; m < 3; ++m) v += j[r][m] * c[3 * m + m] * j[k][m];
      EXPECT_NEAR(b.covariance[3 * r + k], v, 1e-9) << r << "," << k;
    }
  }
  // Floors raise the diagonal only.
  const auto f = FlooredCovariance({1e-9, 5e-10, 0, 5e-10, 1e-9, 0, 0, 0, 1e-9}, 1e-6, 3e-6);
  EXPECT_EQ(f[0], 1e-6);
  EXPECT_EQ(f[4], 1e-6);
  EXPECT_EQ(f[8], 3e-6);
  EXPECT_EQ(f[1], 5e-10);
}

TEST(Conversions, BadImagesAreRejectedWithTheReason) {
  auto expect_reason = [](const sensor_msgs::Image& m, const std::string& what) {
    try {
      ToFloorImage(m);
      ADD_FAILURE() << "accepted: " << what;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  expect_reason(MakeImage("32FC1", 4, 3, 4), "unsupported encoding '32FC1'");
  expect_reason(MakeImage("mono8", 0, 0, 1), "empty image");
  sensor_msgs::Image short_data = MakeImage("mono8", 4, 3, 1);
  short_data.data.resize(5);
  expect_reason(short_data, "too small");
}

TEST(Conversions, CompressedImagesAreDecodedAndFlipped) {
  cv::Mat img(3, 4, CV_8UC1);
  for (int v = 0; v < 3; ++v) img.row(v).setTo(v * 10);
  sensor_msgs::CompressedImage m;
  m.format = "png";
  std::vector<uint8_t> buf;
  cv::imencode(".png", img, buf);
  m.data = buf;
  const cv::Mat out = ToFloorImage(m);
  EXPECT_EQ(out.at<uint8_t>(0, 0), 20);
  EXPECT_EQ(out.at<uint8_t>(2, 3), 0);
  sensor_msgs::CompressedImage bad;
  bad.format = "jpeg";
  EXPECT_THROW(ToFloorImage(bad), std::invalid_argument);  // empty
  bad.data = {1, 2, 3, 4, 5};
  try {
    ToFloorImage(bad);
    ADD_FAILURE() << "decoded garbage";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("cannot decode"), std::string::npos) << e.what();
  }
}

TEST(Conversions, FootprintsRoundTripThroughTransforms) {
  for (double theta : {0.0, 0.7, -2.5, 3.1}) {
    const gtbow::Pose2D f{1.5, -0.25, theta};
    const geometry_msgs::Transform t = TransformFromFootprint(f, 0.3);
    EXPECT_NEAR(t.translation.z, 0.3, 1e-12);
    const gtbow::Pose2D back = FootprintFromTransform(t);
    EXPECT_NEAR(back.x, f.x, 1e-9);
    EXPECT_NEAR(back.y, f.y, 1e-9);
    EXPECT_NEAR(std::remainder(back.theta - theta, 2 * M_PI), 0.0, 1e-9);
  }
  // A tilted camera: the footprint is where the optical axis meets the floor.
  geometry_msgs::Transform tilted = TransformFromFootprint({0, 0, 0}, 1.0);
  // Rotate by 0.1 rad about the camera's x axis: q * (cos .05, sin .05, 0, 0).
  const double c = std::cos(0.05), s = std::sin(0.05);
  const auto q = tilted.rotation;  // (w=0, x=1, y=0, z=0)
  tilted.rotation.w = q.w * c - q.x * s;
  tilted.rotation.x = q.w * s + q.x * c;
  tilted.rotation.y = q.y * c + q.z * s;
  tilted.rotation.z = q.z * c - q.y * s;
  const gtbow::Pose2D f = FootprintFromTransform(tilted);
  EXPECT_NEAR(std::abs(f.y), std::tan(0.1), 1e-6);
  // A camera looking sideways or a NaN are refused.
  geometry_msgs::Transform side;
  side.rotation.w = 1.0;  // identity: optical axis along map +z (up)
  EXPECT_THROW(FootprintFromTransform(side), std::invalid_argument);
  geometry_msgs::Transform nan = TransformFromFootprint({0, 0, 0}, 1.0);
  nan.translation.x = NAN;
  EXPECT_THROW(FootprintFromTransform(nan), std::invalid_argument);
}

TEST(Conversions, RelativePosesAndCovariancesInTheOpticalFrame) {
  const geometry_msgs::Pose2D p = ToOpticalPose2D({0.01, 0.02, 0.3});
  EXPECT_DOUBLE_EQ(p.x, 0.01);
  EXPECT_DOUBLE_EQ(p.y, -0.02);
  EXPECT_DOUBLE_EQ(p.theta, -0.3);
  const std::array<double, 9> c = {1, 2, 3, 2, 4, 5, 3, 5, 6};
  const auto o = ToOpticalCovariance(c);
  const std::array<double, 9> expect = {1, -2, -3, -2, 4, 5, -3, 5, 6};
  EXPECT_EQ(o, expect);
}

TEST(Conversions, PoseWithCovarianceHasThePlanarCovarianceInPlace) {
  const std::array<double, 9> c = {1e-6, 2e-7, 3e-8, 2e-7, 4e-6, 5e-8, 3e-8, 5e-8, 6e-5};
  const auto m = ToPoseWithCovariance({1, 2, M_PI / 2}, c, ros::Time(5, 0), "map", 1e-9);
  EXPECT_EQ(m.header.frame_id, "map");
  EXPECT_EQ(m.header.stamp, ros::Time(5, 0));
  EXPECT_NEAR(YawOf(m.pose.pose.orientation.x, m.pose.pose.orientation.y, m.pose.pose.orientation.z,
                    m.pose.pose.orientation.w),
              M_PI / 2, 1e-12);
  EXPECT_EQ(m.pose.covariance[0], 1e-6);          // x x
  EXPECT_EQ(m.pose.covariance[1], 2e-7);          // x y
  EXPECT_EQ(m.pose.covariance[5], 3e-8);          // x yaw
  EXPECT_EQ(m.pose.covariance[35], 6e-5);         // yaw yaw
  EXPECT_EQ(m.pose.covariance[6 * 5 + 1], 5e-8);  // yaw y
  EXPECT_EQ(m.pose.covariance[14], 1e-9);         // z z
  EXPECT_EQ(m.pose.covariance[21], 1e-9);         // roll roll
  EXPECT_EQ(m.pose.covariance[28], 1e-9);         // pitch pitch
}

TEST(Conversions, StampsCandidatesAndPoses) {
  const ros::Time t(1234, 567890123);
  EXPECT_EQ(FromNanoseconds(ToNanoseconds(t)), t);
  gtbow::Candidate c;
  c.id = 7;
  c.score = 0.5f;
  c.stamp_ns = ToNanoseconds(t);
  c.has_pose = true;
  c.map_from_camera = {1, 2, 3};
  c.verified = true;
  c.relative.success = true;
  c.relative.inliers = 42;
  c.relative.floor_from_query = {0.1, 0.2, 0.3};
  const auto m = ToCandidateMsg(c);
  EXPECT_EQ(m.id, 7u);
  EXPECT_EQ(m.stamp, t);
  EXPECT_EQ(m.inliers, 42u);
  EXPECT_DOUBLE_EQ(m.match_from_query.y, -0.2);
  EXPECT_DOUBLE_EQ(m.pose.theta, 3.0);
  geometry_msgs::Pose2D bad;
  bad.x = NAN;
  EXPECT_THROW(FromPose2DMsg(bad), std::invalid_argument);
}

}  // namespace
}  // namespace gtbow_ros
