// Where the command-line tools get their images: a split of a dataset in the package's format,
// or every image in a folder. Loading and feature extraction run on all cores.
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "ground_texture_bow/core/bow.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/features.h"
#include "ground_texture_bow/eval/dataset.h"

namespace gtbow {
namespace tools {

class ImageSource {
 public:
  // A dataset split (throws naming the file on a malformed dataset or missing split).
  static ImageSource FromDataset(const std::filesystem::path& root, const std::string& split);
  // Every .png/.jpg/.jpeg/.bmp/.tif file in a folder, sorted by name.
  static ImageSource FromFolder(const std::filesystem::path& folder);

  size_t size() const { return names_.size(); }
  const std::string& name(size_t i) const { return names_[i]; }
  // Loads image i as 8-bit gray; throws naming the file when it cannot.
  cv::Mat LoadGray(size_t i) const;
  // Keeps every k-th image so that at most `max_images` remain (0 = all).
  void Subsample(size_t max_images);
  // Keeps exactly these images, in this order; throws naming one the source does not hold.
  void Keep(const std::vector<std::string>& names);
  // The file of image i.
  std::filesystem::path Path(size_t i) const;
  // Identifies the images: names, sizes and modification times (for caches).
  uint64_t ContentKey() const;

 private:
  std::shared_ptr<Dataset> dataset_;  // null for a folder
  std::filesystem::path folder_;
  std::vector<std::string> names_;
};

// Extracts features of every image on `threads` threads (0 = all cores) with a progress bar.
std::vector<ImageFeatures> ExtractAll(const ImageSource& source, const FeatureOptions& options,
                                      int threads, bool progress);

// ExtractAll through a cache: the features of `source` with `options` are stored under
// `cache_dir` (created when missing) in a file named by the images' ContentKey and the options,
// and read back on the next call. An empty `cache_dir` disables the cache; a damaged or
// unwritable cache is reported on stderr and bypassed, never fatal.
std::vector<ImageFeatures> ExtractAllCached(const ImageSource& source,
                                            const FeatureOptions& options,
                                            const std::filesystem::path& cache_dir, int threads,
                                            bool progress);

// The default cache directory: $XDG_CACHE_HOME/ground_texture_bow or ~/.cache/ground_texture_bow.
std::filesystem::path DefaultCacheDir();

// A file of the package's config directory (presets, the node's and the backend's parameter
// files): beside an installed gtbow (<prefix>/bin/gtbow: <prefix>/share/ground_texture_bow/config,
// as catkin_make install lays it out), else the source tree's this binary was built from.
std::string ConfigFile(const std::string& name);

// Trains a vocabulary of configuration `config` on the features of training images (idf over
// these images; percentile size thresholds for config.bow.num_size_bins). Throws when there are
// too few descriptors.
std::unique_ptr<Vocabulary> TrainOnFeatures(const RetrievalConfig& config,
                                            const std::vector<ImageFeatures>& features,
                                            bool progress);

// BoW vectors of every image's features on `threads` threads (0 = all cores).
std::vector<BowVector> EncodeAll(const BowEncoder& encoder,
                                 const std::vector<ImageFeatures>& features, int threads,
                                 bool progress);

// Where a command gets the vocabulary for a configuration on a dataset.
struct VocabularyRequest {
  std::string file;                // a vocabulary file; empty: train on the dataset's train split
  bool train_other_kinds = false;  // a file of another kind or metric: train instead of failing
  std::string dataset;
  std::filesystem::path
      cache;  // trained vocabularies and features are cached here; empty: no cache
  int threads = 0;
  bool progress = true;
};

// The given file, or one trained on the dataset's train split (cached under the cache
// directory, keyed by the training images and options). `desc` says which.
std::unique_ptr<Vocabulary> DatasetVocabulary(const VocabularyRequest& request,
                                              const RetrievalConfig& config, std::string* desc);

}  // namespace tools
}  // namespace gtbow
