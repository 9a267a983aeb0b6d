// Reading and writing ground-texture datasets (docs/DATASET_FORMAT.md, version 1).
// Readers tolerate what the format allows (extra columns and keys, comment and blank lines,
// colour images) and reject what it forbids with std::runtime_error naming file and line.
#pragma once

#include <filesystem>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

#include <opencv2/core.hpp>

#include "ground_texture_bow/core/geometry.h"

namespace gtbow {

// Contents of dataset.yaml.
struct DatasetInfo {
  int format_version = 1;                    // only version 1 exists
  std::string name;                          // free text
  std::string surface;                       // free text, e.g. "asphalt"
  ImageGeometry geometry;                    // image size (pixels) and metres per pixel
  std::map<std::string, double> query_days;  // optional: age of each query split, days
};

// One row of poses.csv.
struct PoseRecord {
  std::string image;  // file name under images/
  Pose2D pose;        // metres, radians
};

// Parsers of the individual files. `source` names the file in error messages.
DatasetInfo ParseDatasetYaml(const std::string& text, const std::string& source);
std::vector<PoseRecord> ParsePosesCsv(const std::string& text, const std::string& source);
std::vector<std::string> ParseSequence(const std::string& text, const std::string& source);

// Serialisers producing exactly the format the parsers read.
std::string FormatDatasetYaml(const DatasetInfo& info);
std::string FormatPosesCsv(const std::vector<PoseRecord>& poses);
std::string FormatSequence(const std::vector<std::string>& names);

// Writes dataset.yaml, poses.csv and sequences/<split>.txt under `root` (atomically, file by
// file). Images are written by the caller under root/images.
void WriteDatasetFiles(const std::filesystem::path& root, const DatasetInfo& info,
                       const std::vector<PoseRecord>& poses,
                       const std::map<std::string, std::vector<std::string>>& splits);

// A dataset on disk. Load() validates dataset.yaml and poses.csv; splits are read on demand.
class Dataset {
 public:
  // Throws std::runtime_error naming the file (and line) on missing or malformed input.
  static Dataset Load(const std::filesystem::path& root);

  const std::filesystem::path& root() const { return root_; }
  const DatasetInfo& info() const { return info_; }
  const std::vector<PoseRecord>& poses() const { return poses_; }

  bool HasImage(const std::string& image) const { return index_.count(image) > 0; }
  // Ground-truth pose of an image; throws std::out_of_range naming it when unknown.
  const Pose2D& PoseOf(const std::string& image) const;

  // Names of the splits under sequences/, sorted.
  std::vector<std::string> SplitNames() const;
  // Image names of a split. Throws when the file is missing, empty, or names an image that has
  // no pose (error names file and line).
  std::vector<std::string> Split(const std::string& split) const;

  std::filesystem::path ImagePath(const std::string& image) const;
  // Loads an image as 8-bit grayscale (colour is converted). Throws naming the file when it is
  // missing, unreadable, or not image_width x image_height.
  cv::Mat LoadGray(const std::string& image) const;

 private:
  std::filesystem::path root_;
  DatasetInfo info_;
  std::vector<PoseRecord> poses_;
  std::unordered_map<std::string, size_t> index_;  // image name -> row in poses_
};

}  // namespace gtbow
