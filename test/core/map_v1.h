// A map file of format version 1 (before memory-mapped maps: one framed, checksummed blob),
// written the way that version's Localizer::Save wrote it, for the tests of what happens to
// such maps now (refused by Load with a conversion hint, ImportVersion1, gtbow convert-map).
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/bow.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/localizer.h"

namespace gtbow {
namespace testing_util {

struct Version1Keyframe {
  gtbow::ImageFeatures features;
  int width = 0, height = 0;
  int64_t stamp_ns = 0;
  std::optional<gtbow::Pose2D> pose;
};

inline void WriteVersion1Map(const std::filesystem::path& path, const gtbow::Vocabulary& vocabulary,
                             const std::string& vocabulary_path,
                             const gtbow::LocalizerOptions& options,
                             const std::vector<Version1Keyframe>& keyframes) {
  using namespace gtbow;
  const BowEncoder encoder(vocabulary, options.retrieval.bow);
  BowDatabase db(encoder.num_rows(), options.retrieval.bow, vocabulary.fingerprint());
  for (const auto& k : keyframes) db.Add(encoder.Encode(k.features));
  BinaryWriter w;
  w.PutString(vocabulary_path);
  w.Put<uint64_t>(vocabulary.fingerprint());
  w.PutString(FormatRetrievalConfig(options.retrieval));
  w.Put<double>(options.meters_per_pixel);
  w.PutString(db.Serialize());
  w.Put<uint64_t>(keyframes.size());
  for (const auto& k : keyframes) {
    w.Put<int64_t>(k.stamp_ns);
    w.Put<uint8_t>(k.pose ? 1 : 0);
    const Pose2D p = k.pose.value_or(Pose2D{});
    w.Put<double>(p.x);
    w.Put<double>(p.y);
    w.Put<double>(p.theta);
    w.Put<int32_t>(k.width);
    w.Put<int32_t>(k.height);
    w.PutVector(k.features.keypoints);
    const cv::Mat d = k.features.descriptors.clone();
    w.Put<int32_t>(d.rows);
    w.Put<int32_t>(d.cols);
    w.Put<int32_t>(d.type());
    w.PutArray(d.data, d.empty() ? 0 : d.total() * d.elemSize());
  }
  const char magic[8] = {'G', 'T', 'B', 'W', 'M', 'A', 'P', '\0'};
  WriteFramedFile(path, magic, 1, w.buffer());
}

}  // namespace testing_util
}  // namespace gtbow
