#include "image_source.h"

#include <algorithm>
#include <atomic>
#include <mutex>
#include <stdexcept>
#include <thread>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

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
    if (e.is_regular_file() && (ext == ".png" || ext == ".jpg" || ext == ".jpeg" ||
                                ext == ".bmp" || ext == ".tif" || ext == ".tiff")) {
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

std::vector<ImageFeatures> ExtractAll(const ImageSource& source, const FeatureOptions& options,
                                      int threads, bool progress) {
  const int n_threads = threads > 0 ? threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  std::vector<ImageFeatures> out(source.size());
  std::atomic<size_t> next{0};
  std::atomic<bool> failed{false};
  std::string error;
  std::mutex m;
  ProgressBar bar("features", source.size(), progress);
  auto worker = [&]() {
    const FeatureExtractor fx(options);
    while (!failed) {
      const size_t i = next.fetch_add(1);
      if (i >= source.size()) return;
      try {
        out[i] = fx.Extract(source.LoadGray(i));
      } catch (const std::exception& e) {
        std::lock_guard<std::mutex> lock(m);
        error = e.what();
        failed = true;
        return;
      }
      bar.Add();
    }
  };
  std::vector<std::thread> pool;
  for (int t = 0; t < n_threads; ++t) pool.emplace_back(worker);
  for (auto& t : pool) t.join();
  bar.Finish();
  if (failed) throw std::runtime_error(error);
  return out;
}

std::vector<BowVector> EncodeAll(const BowEncoder& encoder, const std::vector<ImageFeatures>& f,
                                 int threads, bool progress) {
  std::vector<BowVector> out(f.size());
  ProgressBar bar("transform", f.size(), progress);
  const int nt = threads > 0 ? threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  std::atomic<size_t> next{0};
  std::vector<std::thread> pool;
  for (int t = 0; t < nt; ++t) {
    pool.emplace_back([&]() {
      for (size_t i; (i = next.fetch_add(1)) < f.size();) {
        out[i] = encoder.Encode(f[i]);
        bar.Add();
      }
    });
  }
  for (auto& t : pool) t.join();
  return out;
}

}  // namespace tools
}  // namespace gtbow
