// gtbow_bag_to_dataset: a robot's recording as a dataset (docs/DATASET_FORMAT.md), so that
// `gtbow train-vocab`, `gtbow eval` and `gtbow slam` run on a user's own floor. The inverse of
// gtbow_images_to_bag.
//
// From the bag: the images of one topic (any encoding ToFloorImage takes; flipped into the view
// from above, as the node sees them), the camera's sensor_msgs/CameraInfo (the scale: height / f,
// the height from TF), and TF (/tf and /tf_static): each image's camera footprint in the map
// frame when the bag has map -> camera, else in the odometry frame. With the odometry frame in
// TF, drive_odometry.csv holds the camera's odometry and the `drive` split the images in order
// (what gtbow slam reads). Every split (train, database, drive) holds every image kept: the
// vocabulary is then trained on the floor it will map.
//
// The dataset is written to OUT.partial and renamed to OUT when complete: an interrupted run
// leaves no half dataset under OUT.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <image_transport/camera_common.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2/buffer_core.h>
#include <tf2/exceptions.h>
#include <tf2_msgs/TFMessage.h>
#include <opencv2/imgcodecs.hpp>

#include <CLI/CLI.hpp>

#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/progress.h"
#include "ground_texture_bow/eval/dataset.h"
#include "ground_texture_bow/ros/conversions.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace {

struct Args {
  std::string bag;
  std::string out;
  std::string image_topic = "/camera/image_raw";
  std::string info_topic;  // default: the image topic's camera_info
  std::string map_frame = "map";
  std::string odom_frame = "odom";
  std::string base_frame = "base_link";
  std::string camera_frame;  // default: the images' frame_id
  double meters_per_pixel = 0;
  double camera_height = 0;
  size_t every = 1;
  std::string name;
  std::string surface = "unknown";
  bool allow_no_poses = false;
  bool force = false;
  bool quiet = false;
};

std::string Strip(std::string frame) {
  if (!frame.empty() && frame[0] == '/') frame.erase(0, 1);
  return frame;
}

// The camera's footprint in `target` at `stamp`, if TF has it.
std::optional<Pose2D> Footprint(const tf2::BufferCore& tf, const std::string& target,
                                const std::string& camera, const ros::Time& stamp) {
  try {
    return gtbow_ros::FootprintFromTransform(tf.lookupTransform(target, camera, stamp).transform);
  } catch (const tf2::TransformException&) {
    return std::nullopt;
  }
}

void Run(const Args& a) {
  if (a.every == 0) throw std::invalid_argument("--every must be >= 1");
  if (a.meters_per_pixel < 0 || a.camera_height < 0) {
    throw std::invalid_argument("--meters-per-pixel and --camera-height must be >= 0");
  }
  const fs::path out = a.out;
  if (fs::exists(out) && !a.force) {
    throw std::invalid_argument(out.string() + " exists (--force replaces it)");
  }
  rosbag::Bag bag;
  try {
    bag.open(a.bag, rosbag::bagmode::Read);
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot read the bag " + a.bag + ": " + e.what());
  }
  const std::string info_topic =
      a.info_topic.empty() ? image_transport::getCameraInfoTopic(a.image_topic) : a.info_topic;
  const std::string compressed_topic = a.image_topic + "/compressed";

  // Pass 1: TF over the whole recording, the camera_info, and what the images are.
  rosbag::View all(bag);
  const double duration = (all.getEndTime() - all.getBeginTime()).toSec();
  tf2::BufferCore tf(ros::Duration(std::max(10.0, duration + 10.0)));
  sensor_msgs::CameraInfoConstPtr info;
  size_t images = 0;
  std::string camera = a.camera_frame;
  std::map<std::string, size_t> topics;
  for (const rosbag::MessageInstance& m : all) {
    topics[m.getTopic()]++;
    if (m.getTopic() == "/tf" || m.getTopic() == "/tf_static") {
      if (auto msg = m.instantiate<tf2_msgs::TFMessage>()) {
        const bool is_static = m.getTopic() == "/tf_static";
        for (const auto& t : msg->transforms) tf.setTransform(t, "bag", is_static);
      }
    } else if (m.getTopic() == info_topic) {
      if (!info) info = m.instantiate<sensor_msgs::CameraInfo>();
    } else if (m.getTopic() == a.image_topic || m.getTopic() == compressed_topic) {
      images++;
      if (camera.empty()) {
        if (auto img = m.instantiate<sensor_msgs::Image>()) camera = Strip(img->header.frame_id);
        if (auto c = m.instantiate<sensor_msgs::CompressedImage>())
          camera = Strip(c->header.frame_id);
      }
    }
  }
  if (images == 0) {
    std::string listed;
    for (const auto& [t, n] : topics) listed += "\n  " + t + " (" + std::to_string(n) + ")";
    throw std::invalid_argument("the bag " + a.bag + " has no image on " + a.image_topic + " or " +
                                compressed_topic + "; its topics:" + listed);
  }
  if (camera.empty()) {
    throw std::invalid_argument("the images have no frame_id; pass --camera-frame");
  }

  // The pose frame: the map when TF reaches the camera from it, else the odometry.
  const bool has_map = tf._frameExists(a.map_frame);
  const bool has_odom = tf._frameExists(a.odom_frame);
  std::string pose_frame;
  if (has_map && tf.canTransform(a.map_frame, camera, ros::Time(0))) {
    pose_frame = a.map_frame;
  } else if (has_odom && tf.canTransform(a.odom_frame, camera, ros::Time(0))) {
    pose_frame = a.odom_frame;
  } else if (!a.allow_no_poses) {
    throw std::invalid_argument("no poses: TF in the bag reaches " + camera + " from neither " +
                                a.map_frame + " nor " + a.odom_frame +
                                " (record /tf and /tf_static); --allow-no-poses writes zero poses, "
                                "which only gtbow train-vocab can use");
  }

  // The scale.
  double scale = a.meters_per_pixel;
  std::string scale_source = "--meters-per-pixel";
  if (!(scale > 0)) {
    if (!info) {
      throw std::invalid_argument("no scale: no sensor_msgs/CameraInfo on " + info_topic +
                                  " (record it, or pass --meters-per-pixel)");
    }
    double height = a.camera_height;
    std::string height_source = "--camera-height";
    if (!(height > 0)) {
      if (const auto h = gtbow_ros::LookupCameraHeight(
              tf, {a.base_frame, a.odom_frame, a.map_frame}, camera)) {
        height = h->height;
        height_source = h->source;
      }
    }
    if (!(height > 0)) {
      throw std::invalid_argument("no camera height: TF has no " + a.base_frame + " -> " + camera +
                                  " (record /tf_static, or pass --camera-height)");
    }
    scale = gtbow_ros::MetersPerPixelFromCameraInfo(*info, height);
    char buf[160];
    std::snprintf(buf, sizeof(buf), "camera_info fx %.2f px, height %.4f m (%s)", info->K[0],
                  height, height_source.c_str());
    scale_source = buf;
  }

  // Pass 2: the images.
  const fs::path tmp = out.string() + ".partial";
  std::error_code ec;
  fs::remove_all(tmp, ec);
  fs::create_directories(tmp / "images");
  std::vector<PoseRecord> poses, odometry;
  std::vector<std::string> names;
  size_t seen = 0, skipped = 0;
  int width = 0, height = 0;
  ProgressBar bar("bag-to-dataset", images, !a.quiet);
  try {
    for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
      if (m.getTopic() != a.image_topic && m.getTopic() != compressed_topic) continue;
      bar.Add();
      if (seen++ % a.every != 0) continue;
      cv::Mat gray;
      ros::Time stamp;
      if (auto img = m.instantiate<sensor_msgs::Image>()) {
        gray = gtbow_ros::ToFloorImage(*img);
        stamp = img->header.stamp;
      } else if (auto c = m.instantiate<sensor_msgs::CompressedImage>()) {
        gray = gtbow_ros::ToFloorImage(*c);
        stamp = c->header.stamp;
      } else {
        continue;
      }
      if (width == 0) {
        width = gray.cols;
        height = gray.rows;
      } else if (gray.cols != width || gray.rows != height) {
        throw std::invalid_argument("image " + std::to_string(seen - 1) + " is " +
                                    std::to_string(gray.cols) + "x" + std::to_string(gray.rows) +
                                    ", the first was " + std::to_string(width) + "x" +
                                    std::to_string(height));
      }
      std::optional<Pose2D> pose = Pose2D{0, 0, 0};
      if (!pose_frame.empty()) pose = Footprint(tf, pose_frame, camera, stamp);
      if (!pose) {  // TF does not cover this image's stamp
        skipped++;
        continue;
      }
      std::optional<Pose2D> odom;
      if (has_odom) odom = Footprint(tf, a.odom_frame, camera, stamp);
      char name[32];
      std::snprintf(name, sizeof(name), "%06zu.png", names.size());
      if (!cv::imwrite((tmp / "images" / name).string(), gray)) {
        throw std::runtime_error("cannot write " + (tmp / "images" / name).string());
      }
      names.push_back(name);
      poses.push_back({name, *pose});
      if (odom) odometry.push_back({name, *odom});
    }
    bar.Finish();
    if (names.empty()) {
      throw std::invalid_argument("no image has a pose: TF " + pose_frame + " -> " + camera +
                                  " covers none of the images' stamps");
    }
    DatasetInfo di;
    di.name = a.name.empty() ? fs::path(a.bag).stem().string() : a.name;
    di.surface = a.surface;
    di.geometry = {width, height, scale};
    std::map<std::string, std::vector<std::string>> splits = {{"train", names},
                                                              {"database", names}};
    const bool drive = odometry.size() == names.size();
    if (drive) {
      splits["drive"] = names;
      WriteFileAtomic(tmp / "drive_odometry.csv", FormatPosesCsv(odometry));
    }
    WriteDatasetFiles(tmp, di, poses, splits);
    fs::remove_all(out, ec);
    fs::rename(tmp, out);
    std::printf(
        "%zu images of %s (%zu on the topic, every %zu%s) written to %s\n"
        "  %dx%d pixels, %.6g m/px from %s\n  poses: %s\n  splits: train, database%s\n",
        names.size(), a.image_topic.c_str(), images, a.every,
        skipped ? (", " + std::to_string(skipped) + " without TF skipped").c_str() : "",
        out.c_str(), width, height, scale, scale_source.c_str(),
        pose_frame.empty() ? "none (zeros: --allow-no-poses)"
                           : ("the camera footprint in " + pose_frame + " (TF)").c_str(),
        drive ? (", drive (with drive_odometry.csv from " + a.odom_frame + ")").c_str() : "");
  } catch (...) {
    fs::remove_all(tmp, ec);
    throw;
  }
}

}  // namespace
}  // namespace gtbow

int main(int argc, char** argv) {
  gtbow::Args a;
  CLI::App app{
      "gtbow_bag_to_dataset: a recording (rosbag) of a downward camera as a dataset "
      "(docs/DATASET_FORMAT.md) for gtbow train-vocab, eval and slam"};
  app.add_option("--bag", a.bag, "The recording")->required()->check(CLI::ExistingFile);
  app.add_option("-o,--out", a.out, "Dataset directory to write")->required();
  app.add_option("--image-topic", a.image_topic, "Image topic (raw, or its /compressed)")
      ->capture_default_str();
  app.add_option("--info-topic", a.info_topic,
                 "sensor_msgs/CameraInfo topic (default: the image topic's camera_info)");
  app.add_option("--map-frame", a.map_frame, "Poses from here when TF has it")
      ->capture_default_str();
  app.add_option("--odom-frame", a.odom_frame, "Else from here; also drive_odometry.csv")
      ->capture_default_str();
  app.add_option("--base-frame", a.base_frame, "The camera's height is read in this frame")
      ->capture_default_str();
  app.add_option("--camera-frame", a.camera_frame, "Override the images' frame_id");
  app.add_option("--meters-per-pixel", a.meters_per_pixel,
                 "The scale (default: camera_info's focal length and the camera's TF height)");
  app.add_option("--camera-height", a.camera_height, "Metres above the floor (default: from TF)");
  app.add_option("--every", a.every, "Keep every Nth image")->capture_default_str();
  app.add_option("--name", a.name, "dataset.yaml name (default: the bag's)");
  app.add_option("--surface", a.surface, "dataset.yaml surface")->capture_default_str();
  app.add_flag("--allow-no-poses", a.allow_no_poses,
               "Without TF to the camera, write zero poses (for train-vocab only)");
  app.add_flag("--force", a.force, "Replace an existing OUT");
  app.add_flag("-q,--quiet", a.quiet, "No progress bar");
  try {
    app.parse(argc, argv);
    gtbow::Run(a);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "gtbow_bag_to_dataset: error: %s\n", e.what());
    return 2;
  }
  return 0;
}
