// gtbow_images_to_bag: any dataset (docs/DATASET_FORMAT.md) as a rosbag a robot would have
// recorded: the images of one split on a camera topic, in sequence order, and the camera's
// ground-truth pose as TF (map -> camera optical frame) and as a PoseStamped topic, and the
// camera's sensor_msgs/CameraInfo (a pinhole looking down from --height, whose focal length
// gives the dataset's meters_per_pixel).
//
// With --odometry (a drive from `gtbow synth --drive`), the robot's wheel odometry replaces the
// ground-truth TF: nav_msgs/Odometry on --odom-topic and TF odom -> base_link at each image
// stamp, plus a static (latched /tf_static) base_link -> camera optical frame from
// --camera-offset; the ground truth stays on the PoseStamped topic only (TF allows one parent
// per frame). base_link lies on the floor (z = 0) and the odometry CSV holds the camera's
// footprint, so the base's odometry pose is odom_from_camera * camera_offset^-1.
// With --camera-offset alone, the same static mount, and the ground-truth TF is map -> base_link
// (none with --no-tf): a robot whose ~pose is its base's.
//
// The camera is a downward optical frame (x = image right, y = image down, z down onto the
// floor), so it sees the floor mirrored with respect to the dataset's floor frame (which, like
// the map, has z up): images are stored flipped upside down. The localizer flips them back
// (ros/conversions.h), and its fixes are then in the dataset's floor frame.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <image_transport/camera_common.h>
#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>
#include <tf2_msgs/TFMessage.h>
#include <opencv2/imgproc.hpp>

#include <CLI/CLI.hpp>

#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/progress.h"
#include "ground_texture_bow/eval/dataset.h"
#include "ground_texture_bow/ros/conversions.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace {

struct BagArgs {
  std::string dataset;
  std::string out;
  std::string split = "database";
  std::string topic = "/camera/image_raw";
  std::string frame = "camera_optical";
  std::string map_frame = "map";
  std::string truth_topic = "/ground_truth/pose";
  std::string encoding = "mono8";
  double rate = 10.0;
  double start = 1000.0;
  double height = 0.2;
  size_t max_images = 0;
  bool no_tf = false;
  bool quiet = false;
  bool no_camera_info = false;
  std::string odometry;  // drive_odometry.csv (poses.csv columns): odometry instead of truth TF
  std::string odom_frame = "odom";
  std::string base_frame = "base_link";
  std::string odom_topic = "/odom";
  std::vector<double> camera_offset = {0.0, 0.0, 0.0};  // camera footprint in base_link
  bool mount = false;  // --camera-offset given (or --odometry): a base_link -> camera mount
};

sensor_msgs::Image ToMessage(const cv::Mat& gray_floor_view, const std::string& encoding) {
  cv::Mat img;
  cv::flip(gray_floor_view, img, 0);  // the optical frame sees the floor mirrored
  namespace enc = sensor_msgs::image_encodings;
  if (encoding == enc::BGR8 || encoding == enc::RGB8) {
    cv::cvtColor(img, img, cv::COLOR_GRAY2BGR);  // grey: BGR and RGB are the same bytes
  } else if (encoding == enc::MONO16) {
    img.convertTo(img, CV_16U, 257.0);
  } else if (encoding != enc::MONO8) {
    throw std::invalid_argument("--encoding must be mono8, mono16, bgr8 or rgb8, not '" + encoding +
                                "'");
  }
  sensor_msgs::Image m;
  m.height = static_cast<uint32_t>(img.rows);
  m.width = static_cast<uint32_t>(img.cols);
  m.encoding = encoding;
  m.step = static_cast<uint32_t>(img.cols * img.elemSize());
  m.data.resize(m.step * m.height);
  for (int r = 0; r < img.rows; ++r) {
    std::memcpy(&m.data[r * m.step], img.ptr(r), m.step);
  }
  return m;
}

// The camera_info of a pinhole camera without distortion looking straight down from `height`:
// focal length height / meters_per_pixel, principal point at the image centre (the core's).
sensor_msgs::CameraInfo CameraInfoOf(const ImageGeometry& g, double height) {
  sensor_msgs::CameraInfo c;
  c.width = static_cast<uint32_t>(g.width);
  c.height = static_cast<uint32_t>(g.height);
  const double f = height / g.meters_per_pixel;
  const double cx = 0.5 * (g.width - 1), cy = 0.5 * (g.height - 1);
  c.distortion_model = "plumb_bob";
  c.D = {0, 0, 0, 0, 0};
  c.K = {f, 0, cx, 0, f, cy, 0, 0, 1};
  c.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  c.P = {f, 0, cx, 0, 0, f, cy, 0, 0, 0, 1, 0};
  return c;
}

void RunImagesToBag(const BagArgs& a) {
  const Dataset ds = Dataset::Load(a.dataset);
  const auto names = ds.Split(a.split);  // throws naming the split when it is missing
  if (names.empty()) throw std::invalid_argument("split '" + a.split + "' is empty");
  if (!(a.rate > 0)) throw std::invalid_argument("--rate must be > 0");
  if (!(a.start > 0)) throw std::invalid_argument("--start must be > 0 (ROS time 0 means unset)");
  const size_t n = a.max_images > 0 ? std::min(a.max_images, names.size()) : names.size();
  if (a.camera_offset.size() != 3) {
    throw std::invalid_argument("--camera-offset takes X Y YAW (metres, radians)");
  }
  const Pose2D base_from_camera{a.camera_offset[0], a.camera_offset[1], a.camera_offset[2]};
  std::unordered_map<std::string, Pose2D> odometry;
  if (!a.odometry.empty()) {
    if (a.no_tf) throw std::invalid_argument("--odometry publishes TF: it excludes --no-tf");
    for (const auto& r : ParsePosesCsv(ReadFile(a.odometry), a.odometry)) {
      odometry[r.image] = r.pose;
    }
    for (size_t i = 0; i < n; ++i) {
      if (odometry.count(names[i]) == 0) {
        throw std::invalid_argument(a.odometry + " has no odometry pose for image " + names[i] +
                                    " of split '" + a.split + "'");
      }
    }
  }
  const fs::path out = a.out;
  const fs::path tmp = out.string() + ".partial";
  {
    rosbag::Bag bag;
    try {
      bag.open(tmp.string(), rosbag::bagmode::Write);
    } catch (const std::exception& e) {
      throw std::runtime_error("cannot write " + out.string() + ": " + e.what());
    }
    ProgressBar bar("images-to-bag", n, !a.quiet);
    const std::string info_topic = image_transport::getCameraInfoTopic(a.topic);
    const sensor_msgs::CameraInfo info = CameraInfoOf(ds.info().geometry, a.height);
    try {
      if (a.mount || !odometry.empty()) {
        // Latched, like a robot_state_publisher's: rosbag play republishes it latched.
        geometry_msgs::TransformStamped mount;
        mount.header.stamp = ros::Time(a.start);
        mount.header.frame_id = a.base_frame;
        mount.child_frame_id = a.frame;
        mount.transform = gtbow_ros::TransformFromFootprint(base_from_camera, a.height);
        tf2_msgs::TFMessage tf;
        tf.transforms.push_back(mount);
        auto header = boost::make_shared<ros::M_string>();
        // A custom connection header replaces rosbag's own: it needs the type fields too.
        (*header)["type"] = ros::message_traits::datatype<tf2_msgs::TFMessage>();
        (*header)["md5sum"] = ros::message_traits::md5sum<tf2_msgs::TFMessage>();
        (*header)["message_definition"] = ros::message_traits::definition<tf2_msgs::TFMessage>();
        (*header)["latching"] = "1";
        (*header)["callerid"] = "/gtbow_images_to_bag";
        bag.write("/tf_static", ros::Time(a.start), tf, header);
      }
      for (size_t i = 0; i < n; ++i) {
        const ros::Time stamp(a.start + static_cast<double>(i) / a.rate);
        sensor_msgs::Image img = ToMessage(ds.LoadGray(names[i]), a.encoding);
        img.header.stamp = stamp;
        img.header.frame_id = a.frame;
        img.header.seq = static_cast<uint32_t>(i);
        const Pose2D& pose = ds.PoseOf(names[i]);
        geometry_msgs::TransformStamped t;
        t.header.stamp = stamp;
        t.header.frame_id = a.map_frame;
        t.child_frame_id = a.frame;
        t.transform = gtbow_ros::TransformFromFootprint(pose, a.height);
        if (!odometry.empty()) {
          const Pose2D base = Compose(odometry.at(names[i]), Inverse(base_from_camera));
          nav_msgs::Odometry odom;
          odom.header.stamp = stamp;
          odom.header.frame_id = a.odom_frame;
          odom.child_frame_id = a.base_frame;
          odom.pose.pose.position.x = base.x;
          odom.pose.pose.position.y = base.y;
          odom.pose.pose.orientation = gtbow_ros::QuaternionFromYaw(base.theta);
          bag.write(a.odom_topic, stamp, odom);
          geometry_msgs::TransformStamped ob;
          ob.header = odom.header;
          ob.child_frame_id = a.base_frame;
          ob.transform.translation.x = base.x;
          ob.transform.translation.y = base.y;
          ob.transform.rotation = odom.pose.pose.orientation;
          tf2_msgs::TFMessage tf;
          tf.transforms.push_back(ob);
          bag.write("/tf", stamp, tf);
        } else if (!a.no_tf) {
          tf2_msgs::TFMessage tf;
          if (a.mount) {  // the truth of the base; the camera hangs from it
            const Pose2D base = Compose(pose, Inverse(base_from_camera));
            t.child_frame_id = a.base_frame;
            t.transform = geometry_msgs::Transform();
            t.transform.translation.x = base.x;
            t.transform.translation.y = base.y;
            t.transform.rotation = gtbow_ros::QuaternionFromYaw(base.theta);
          }
          tf.transforms.push_back(t);
          bag.write("/tf", stamp, tf);
        }
        geometry_msgs::PoseStamped truth;
        truth.header = t.header;
        truth.header.frame_id = a.map_frame;
        truth.pose.position.x = pose.x;
        truth.pose.position.y = pose.y;
        truth.pose.orientation = gtbow_ros::QuaternionFromYaw(pose.theta);
        bag.write(a.truth_topic, stamp, truth);
        if (!a.no_camera_info) {
          sensor_msgs::CameraInfo ci = info;
          ci.header = img.header;
          bag.write(info_topic, stamp, ci);
        }
        bag.write(a.topic, stamp, img);
        bar.Add();
      }
      bar.Finish();
      bag.close();
    } catch (...) {
      bag.close();
      std::error_code ec;
      fs::remove(tmp, ec);
      throw;
    }
  }
  fs::rename(tmp, out);
  const ImageGeometry& g = ds.info().geometry;
  std::string tf_desc;
  if (!odometry.empty()) {
    tf_desc = a.odom_frame + " -> " + a.base_frame + " (odometry, also on " + a.odom_topic +
              ") -> " + a.frame + " (static)";
  } else if (a.mount) {
    tf_desc = (a.no_tf ? std::string("(map omitted: --no-tf) ") : a.map_frame + " -> ") +
              a.base_frame + " -> " + a.frame + " (static)";
  } else {
    tf_desc = a.map_frame + " -> " + a.frame + (a.no_tf ? " (omitted: --no-tf)" : "");
  }
  std::printf(
      "%zu images of split '%s' written to %s\n  %s (%s), TF %s, ground truth %s\n"
      "  %.1f Hz from t = %.1f s; %dx%d pixels, meters_per_pixel %.6g; %s\n",
      n, a.split.c_str(), out.c_str(), a.topic.c_str(), a.encoding.c_str(), tf_desc.c_str(),
      a.truth_topic.c_str(), a.rate, a.start, g.width, g.height, g.meters_per_pixel,
      a.no_camera_info ? "no camera_info"
                       : ("camera_info on " + image_transport::getCameraInfoTopic(a.topic) +
                          " (f = height / meters_per_pixel)")
                             .c_str());
}

}  // namespace
}  // namespace gtbow

int main(int argc, char** argv) {
  using gtbow::BagArgs;
  auto a = std::make_shared<BagArgs>();
  CLI::App app{
      "gtbow_images_to_bag: write a dataset split as a rosbag of camera images plus "
      "ground-truth TF (the ROS part of the gtbow tools)"};
  CLI::App* cmd = &app;
  cmd->add_option("--dataset", a->dataset, "Dataset (docs/DATASET_FORMAT.md)")->required();
  cmd->add_option("-o,--out", a->out, "Output bag file")->required();
  cmd->add_option("--split", a->split, "Split to write, in sequence order")->capture_default_str();
  cmd->add_option("--topic", a->topic, "Image topic")->capture_default_str();
  cmd->add_option("--frame", a->frame, "Camera optical frame id")->capture_default_str();
  cmd->add_option("--map-frame", a->map_frame, "Parent frame of the ground truth")
      ->capture_default_str();
  cmd->add_option("--truth-topic", a->truth_topic,
                  "Ground-truth PoseStamped topic (camera footprint)")
      ->capture_default_str();
  cmd->add_option("--encoding", a->encoding, "mono8, mono16, bgr8 or rgb8")->capture_default_str();
  cmd->add_option("--rate", a->rate, "Images per second")->capture_default_str();
  cmd->add_option("--start", a->start, "Stamp of the first image, seconds")->capture_default_str();
  cmd->add_option("--height", a->height, "Camera height above the floor, metres (TF z)")
      ->capture_default_str();
  cmd->add_option("--max-images", a->max_images, "Write at most this many images (0 = all)");
  cmd->add_flag("--no-tf", a->no_tf, "Omit /tf (a robot that must localize globally)");
  cmd->add_option("--odometry", a->odometry,
                  "Odometry CSV (poses.csv columns, e.g. drive_odometry.csv from gtbow synth "
                  "--drive): publish it as nav_msgs/Odometry and TF odom -> base_link, with a "
                  "static base_link -> camera transform, instead of the ground-truth TF")
      ->check(CLI::ExistingFile);
  cmd->add_option("--odom-frame", a->odom_frame, "Odometry frame (--odometry)")
      ->capture_default_str();
  cmd->add_option("--base-frame", a->base_frame, "Robot base frame (--odometry, --camera-offset)")
      ->capture_default_str();
  cmd->add_option("--odom-topic", a->odom_topic, "nav_msgs/Odometry topic (--odometry)")
      ->capture_default_str();
  cmd->add_option("--camera-offset", a->camera_offset,
                  "The camera's footprint in the base frame: X Y YAW (metres, radians). Writes "
                  "a static base frame -> camera mount; the ground-truth TF (without --odometry) "
                  "is then map -> base frame")
      ->expected(3);
  cmd->add_flag("--no-camera-info", a->no_camera_info,
                "Omit sensor_msgs/CameraInfo (written by default on the image topic's "
                "camera_info, with the focal length that --height and the dataset's "
                "meters_per_pixel give)");
  cmd->add_flag("-q,--quiet", a->quiet, "No progress bar");
  try {
    app.parse(argc, argv);
    a->mount = cmd->count("--camera-offset") > 0;
    gtbow::RunImagesToBag(*a);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "gtbow_images_to_bag: error: %s\n", e.what());
    return 2;
  }
  return 0;
}
