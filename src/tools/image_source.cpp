#include "image_source.h"

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/parallel.h"
#include "ground_texture_bow/core/progress.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace tools {

ImageSource ImageSource::FromDataset(const fs::path& root, const std::string& split) {
  ImageSource s;
  s.dataset_ = std::make_shared<Dataset>(Dataset::Load(root));
  s.names_ = s.dataset_->Split(split);
  return s;
}

ImageSource ImageSource::FromFolder(const fs::path& folder) {
  if (!fs::is_directory(folder)) {
    throw std::runtime_error("image folder '" + folder.string() + "' is not a directory");
  }
  ImageSource s;
  s.folder_ = folder;
  for (const auto& e : fs::directory_iterator(folder)) {
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
    if (e.is_regular_file() && (ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".bmp" ||
                                ext == ".tif" || ext == ".tiff")) {
      s.names_.push_back(e.path().filename().string());
    }
  }
  std::sort(s.names_.begin(), s.names_.end());
  if (s.names_.empty()) throw std::runtime_error("no images found in '" + folder.string() + "'");
  return s;
}

cv::Mat ImageSource::LoadGray(size_t i) const {
  if (dataset_) return dataset_->LoadGray(names_.at(i));
  const fs::path p = folder_ / names_.at(i);
  cv::Mat img = cv::imread(p.string(), cv::IMREAD_GRAYSCALE);
  if (img.empty()) throw std::runtime_error("cannot read image " + p.string());
  return img;
}

void ImageSource::Subsample(size_t max_images) {
  if (max_images == 0 || names_.size() <= max_images) return;
  std::vector<std::string> kept;
  for (size_t i = 0; i < max_images; ++i) kept.push_back(names_[i * names_.size() / max_images]);
  names_.swap(kept);
}

void ImageSource::Keep(const std::vector<std::string>& names) {
  const std::set<std::string> held(names_.begin(), names_.end());
  for (const auto& n : names) {
    if (held.count(n) == 0) throw std::runtime_error("image " + n + " is not in this source");
  }
  names_ = names;
}

std::vector<ImageFeatures> ExtractAll(const ImageSource& source, const FeatureOptions& options,
                                      int threads, bool progress) {
  std::vector<ImageFeatures> out(source.size());
  ProgressBar bar("features", source.size(), progress);
  ParallelForEach(
      source.size(), threads, [&] { return FeatureExtractor(options); },
      [&](const FeatureExtractor& fx, size_t i) {
        out[i] = fx.Extract(source.LoadGray(i));
        bar.Add();
      });
  bar.Finish();
  return out;
}

fs::path ImageSource::Path(size_t i) const {
  return dataset_ ? dataset_->ImagePath(names_.at(i)) : folder_ / names_.at(i);
}

uint64_t ImageSource::ContentKey() const {
  BinaryWriter w;
  w.PutString(fs::absolute(dataset_ ? dataset_->root() : folder_).lexically_normal().string());
  for (size_t i = 0; i < names_.size(); ++i) {
    std::error_code ec;
    const fs::path p = Path(i);
    w.PutString(names_[i]);
    w.Put<uint64_t>(fs::file_size(p, ec));
    w.Put<int64_t>(fs::last_write_time(p, ec).time_since_epoch().count());
  }
  return Checksum64(w.buffer().data(), w.buffer().size());
}

namespace {

constexpr char kFeatureCacheMagic[8] = {'G', 'T', 'B', 'W', 'F', 'E', 'A', 'T'};
constexpr uint32_t kFeatureCacheVersion = 1;

void SaveFeatures(const fs::path& path, const std::vector<ImageFeatures>& feats) {
  BinaryWriter w;
  w.Put<uint64_t>(feats.size());
  for (const auto& f : feats) {
    w.PutVector(f.keypoints);
    w.Put<int32_t>(f.descriptors.rows);
    w.Put<int32_t>(f.descriptors.cols);
    w.Put<int32_t>(f.descriptors.type());
    const cv::Mat d = f.descriptors.isContinuous() ? f.descriptors : f.descriptors.clone();
    w.PutArray(d.data, d.total() * d.elemSize());
  }
  WriteFramedFile(path, kFeatureCacheMagic, kFeatureCacheVersion, w.buffer());
}

std::vector<ImageFeatures> LoadFeatures(const fs::path& path, size_t expected) {
  const FramedPayload p =
      ReadFramedFile(path, kFeatureCacheMagic, kFeatureCacheVersion, "feature cache");
  BinaryReader r(p.data(), p.size(), path.string());
  if (r.Get<uint64_t>() != expected) r.Fail("image count does not match");
  std::vector<ImageFeatures> feats(expected);
  for (auto& f : feats) {
    f.keypoints = r.GetVector<Keypoint>(1u << 20);
    const int32_t rows = r.Get<int32_t>(), cols = r.Get<int32_t>(), type = r.Get<int32_t>();
    if (rows != static_cast<int32_t>(f.keypoints.size()) || cols < 0 || cols > 4096 ||
        (type != CV_8U && type != CV_32F)) {
      r.Fail("invalid descriptor block");
    }
    f.descriptors.create(rows, cols, type);
    auto bytes = r.GetVector<uint8_t>(static_cast<uint64_t>(rows) * cols * 4);
    if (bytes.size() != f.descriptors.total() * f.descriptors.elemSize())
      r.Fail("descriptor size mismatch");
    if (!bytes.empty()) std::memcpy(f.descriptors.data, bytes.data(), bytes.size());
  }
  if (r.remaining() != 0) r.Fail("unexpected trailing data");
  return feats;
}

}  // namespace

std::string ConfigFile(const std::string& name) {
  static const fs::path dir = [] {
    std::error_code ec;
    const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
    if (!ec) {
      const fs::path installed =
          exe.parent_path().parent_path() / "share" / "ground_texture_bow" / "config";
      if (fs::is_regular_file(installed / "high_accuracy.yaml", ec)) return installed;
    }
    return fs::path(GTBOW_CONFIG_DIR);
  }();
  return (dir / name).string();
}

fs::path DefaultCacheDir() {
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x != nullptr && *x != '\0') {
    return fs::path(x) / "ground_texture_bow";
  }
  const char* home = std::getenv("HOME");
  return fs::path(home != nullptr && *home != '\0' ? home : "/tmp") / ".cache" /
         "ground_texture_bow";
}

std::vector<ImageFeatures> ExtractAllCached(const ImageSource& source,
                                            const FeatureOptions& options,
                                            const fs::path& cache_dir, int threads, bool progress) {
  if (cache_dir.empty()) return ExtractAll(source, options, threads, progress);
  RetrievalConfig key_config;
  key_config.features = options;
  const std::string opt = FormatRetrievalConfig(key_config);
  char name[64];
  std::snprintf(name, sizeof(name), "features-%016llx-%016llx.bin",
                static_cast<unsigned long long>(source.ContentKey()),
                static_cast<unsigned long long>(Checksum64(opt.data(), opt.size())));
  const fs::path file = cache_dir / name;
  std::error_code ec;
  if (fs::exists(file, ec)) {
    try {
      return LoadFeatures(file, source.size());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "feature cache: %s; extracting again\n", e.what());
    }
  }
  auto feats = ExtractAll(source, options, threads, progress);
  try {
    fs::create_directories(cache_dir);
    SaveFeatures(file, feats);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "feature cache: not saved (%s)\n", e.what());
  }
  return feats;
}

std::unique_ptr<Vocabulary> TrainOnFeatures(const RetrievalConfig& c,
                                            const std::vector<ImageFeatures>& feats,
                                            bool progress) {
  size_t total = 0;
  for (const auto& f : feats) total += f.size();
  if (total == 0) throw std::runtime_error("no features found in the training images");
  cv::Mat desc;
  std::vector<cv::Mat> blocks;
  std::vector<uint32_t> image_of;
  std::vector<float> sizes;
  image_of.reserve(total);
  for (size_t i = 0; i < feats.size(); ++i) {
    if (feats[i].size() == 0) continue;
    blocks.push_back(feats[i].descriptors);
    for (const auto& k : feats[i].keypoints) {
      image_of.push_back(static_cast<uint32_t>(i));
      sizes.push_back(k.size);
    }
  }
  cv::vconcat(blocks, desc);
  if (c.vocabulary.kind == VocabularyKind::kAkm && desc.rows < c.vocabulary.num_words) {
    throw std::runtime_error("only " + std::to_string(desc.rows) + " descriptors from " +
                             std::to_string(feats.size()) + " training images for " +
                             std::to_string(c.vocabulary.num_words) +
                             " words; use more training images or fewer words");
  }
  auto vocab = TrainVocabulary(c.vocabulary, desc, image_of, progress);
  vocab->set_size_thresholds(SizePercentileThresholds(sizes, c.bow.num_size_bins));
  vocab->set_extractor(FormatFeatureOptions(c.features));
  return vocab;
}

std::vector<BowVector> EncodeAll(const BowEncoder& encoder, const std::vector<ImageFeatures>& f,
                                 int threads, bool progress) {
  std::vector<BowVector> out(f.size());
  ProgressBar bar("transform", f.size(), progress);
  ParallelForEach(f.size(), threads, [&](size_t i) {
    out[i] = encoder.Encode(f[i]);
    bar.Add();
  });
  return out;
}

// The vocabulary for a configuration: the given file, or one trained on the dataset's train
// split (cached under the cache directory, keyed by the training images and options).
std::unique_ptr<Vocabulary> DatasetVocabulary(const VocabularyRequest& a, const RetrievalConfig& c,
                                              std::string* desc) {
  if (!a.file.empty()) {
    // A given vocabulary serves every preset of its kind and metric; others are trained.
    auto v = Vocabulary::Load(a.file);
    if (v->kind() == c.vocabulary.kind && v->metric() == c.vocabulary.metric) {
      CheckVocabularyExtractor(*v, a.file, c.features);
      *desc = a.file;
      return v;
    }
    if (!a.train_other_kinds) {
      throw std::runtime_error(a.file + " is a " + VocabularyKindName(v->kind()) + "/" +
                               MetricName(v->metric()) + " vocabulary; the preset needs " +
                               VocabularyKindName(c.vocabulary.kind) + "/" +
                               MetricName(c.vocabulary.metric));
    }
  }
  const auto splits = Dataset::Load(a.dataset).SplitNames();
  if (std::find(splits.begin(), splits.end(), "train") == splits.end()) {
    throw std::runtime_error(a.dataset +
                             ": no train split to train a vocabulary on; give --vocab FILE");
  }
  ImageSource src = ImageSource::FromDataset(a.dataset, "train");
  RetrievalConfig key;
  key.vocabulary = c.vocabulary;
  key.vocabulary.threads = 0;
  // Size thresholds are learned for percentile bins only; other bins share one vocabulary.
  if (c.bow.size_binning == SizeBinning::kPercentile) key.bow.num_size_bins = c.bow.num_size_bins;
  std::string opt =
      FormatRetrievalConfig(key) + FormatRetrievalConfig(RetrievalConfig{c.features, {}, {}, {}});
  // The key predates bow.compact_postings, which does not touch the vocabulary: leave the line
  // out so that vocabularies cached before it stay valid (AKM training is not bit-reproducible).
  for (size_t at; (at = opt.find("  compact_postings: true\n")) != std::string::npos;) {
    opt.erase(at, std::strlen("  compact_postings: true\n"));
  }
  char name[80];
  std::snprintf(name, sizeof(name), "vocabulary-%016llx-%016llx.gtvoc",
                static_cast<unsigned long long>(src.ContentKey()),
                static_cast<unsigned long long>(Checksum64(opt.data(), opt.size())));
  const fs::path cached = a.cache.empty() ? fs::path() : a.cache / name;
  if (!cached.empty() && fs::exists(cached)) {
    try {
      *desc = "trained on the train split (cached as " + cached.filename().string() + ")";
      return Vocabulary::Load(cached);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "vocabulary cache: %s; training again\n", e.what());
    }
  }
  const auto feats = ExtractAllCached(src, c.features, a.cache, a.threads, a.progress);
  RetrievalConfig tc = c;
  tc.vocabulary.threads = a.threads;
  auto vocab = TrainOnFeatures(tc, feats, a.progress);
  *desc = "trained on the train split (" + std::to_string(src.size()) + " images)";
  if (!cached.empty()) {
    try {
      fs::create_directories(cached.parent_path());
      vocab->Save(cached);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "vocabulary cache: not saved (%s)\n", e.what());
    }
  }
  return vocab;
}

}  // namespace tools
}  // namespace gtbow
