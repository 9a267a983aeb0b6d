// Vocabularies: the options, training (the kinds in vocabulary_akm.cpp and vocabulary_hkm.cpp,
// then the idf weights here), and the file format's common part.
#include "ground_texture_bow/core/vocabulary.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/enum_names.h"
#include "vocabulary_internal.h"

namespace gtbow {

using namespace vocabulary_internal;

namespace {

constexpr char kVocabularyMagic[8] = {'G', 'T', 'B', 'W', 'V', 'O', 'C', '\0'};
// 2: IVF lists stored with AKM words; 3: the extractor the vocabulary was trained with (and
// binary IVF lists for Hamming words). Version 2 files are read.
constexpr uint32_t kVocabularyVersion = 3;
constexpr uint32_t kOldestVocabularyVersion = 2;

}  // namespace

namespace {
constexpr EnumName<AnnIndex> kAnnIndexes[] = {{"flann", AnnIndex::kFlann}, {"ivf", AnnIndex::kIvf}};
constexpr EnumName<VocabularyKind> kKinds[] = {{"akm", VocabularyKind::kAkm},
                                               {"hkm", VocabularyKind::kHkm}};
constexpr EnumName<Metric> kMetrics[] = {
    {"l2_bytes", Metric::kL2Bytes}, {"hamming", Metric::kHamming}, {"l2", Metric::kL2}};
}  // namespace

AnnIndex ParseAnnIndex(const std::string& name) {
  return ParseEnumName(name, "ann index", kAnnIndexes);
}
std::string AnnIndexName(AnnIndex index) { return EnumValueName(index, kAnnIndexes); }
VocabularyKind ParseVocabularyKind(const std::string& name) {
  return ParseEnumName(name, "vocabulary kind", kKinds);
}
std::string VocabularyKindName(VocabularyKind kind) { return EnumValueName(kind, kKinds); }
Metric ParseMetric(const std::string& name) { return ParseEnumName(name, "metric", kMetrics); }
std::string MetricName(Metric metric) { return EnumValueName(metric, kMetrics); }

void VocabularyOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("vocabulary: ") + what);
  };
  need(num_words >= 2, "num_words must be >= 2");
  need(kmeans_iterations >= 1, "kmeans_iterations must be >= 1");
  need(kmeans_stop_fraction >= 0.0 && kmeans_stop_fraction < 1.0,
       "kmeans_stop_fraction must be in [0, 1)");
  need(kmeans_min_iterations >= 1, "kmeans_min_iterations must be >= 1");
  need(train_checks >= 0, "train_checks must be >= 0 (0: max(2000, V / 5))");
  need(train_nprobe >= 0, "train_nprobe must be >= 0 (0: all lists)");
  need(num_trees >= 1 && num_trees <= 64, "num_trees must be in 1..64");
  need(checks >= 1, "checks must be >= 1");
  need(nprobe >= 1, "nprobe must be >= 1");
  need(hkm_branching >= 2, "hkm_branching must be >= 2");
  need(hkm_depth >= 1 && hkm_depth <= 12, "hkm_depth must be in 1..12");
  need(threads >= 0, "threads must be >= 0");
}

std::unique_ptr<Vocabulary> TrainVocabulary(const VocabularyOptions& o, const cv::Mat& descriptors,
                                            const std::vector<uint32_t>& image_of, bool progress) {
  o.Check();
  if (descriptors.empty()) throw std::invalid_argument("TrainVocabulary: no descriptors");
  if (image_of.size() != static_cast<size_t>(descriptors.rows)) {
    throw std::invalid_argument("TrainVocabulary: image_of must have one entry per descriptor");
  }
  const cv::Mat data = ToSpace(descriptors, o.metric);
  std::unique_ptr<Vocabulary> vocab;
  vocab =
      o.kind == VocabularyKind::kAkm ? TrainAkm(o, data, progress) : TrainHkm(o, data, progress);
  // idf = log(N / n_w) over the training images (paper §III: standard tf-idf).
  std::vector<WordHit> hits;
  vocab->Assign(descriptors, 1, &hits);
  // Document frequency: distinct training images per word.
  std::vector<std::pair<uint32_t, uint32_t>> word_image(hits.size());
  for (size_t i = 0; i < hits.size(); ++i) word_image[i] = {hits[i].word, image_of[i]};
  std::sort(word_image.begin(), word_image.end());
  word_image.erase(std::unique(word_image.begin(), word_image.end()), word_image.end());
  std::vector<uint32_t> df(vocab->size(), 0);
  for (const auto& wi : word_image) ++df[wi.first];
  std::vector<uint32_t> images(image_of);
  std::sort(images.begin(), images.end());
  const auto num_images =
      static_cast<uint32_t>(std::unique(images.begin(), images.end()) - images.begin());
  std::vector<float> idf(vocab->size(), 0.0f);
  for (uint32_t w = 0; w < vocab->size(); ++w) {
    if (df[w] > 0) idf[w] = static_cast<float>(std::log(static_cast<double>(num_images) / df[w]));
  }
  vocab->set_idf(std::move(idf));
  vocab->set_search(o.ann, o.nprobe);
  vocab->set_search_bound(o.ivf_bound);
  return vocab;
}

void Vocabulary::Save(const std::filesystem::path& path) const {
  BinaryWriter w;
  w.Put<uint8_t>(static_cast<uint8_t>(kind()));
  w.Put<uint8_t>(static_cast<uint8_t>(metric()));
  w.Put<uint32_t>(size());
  w.PutVector(idf_);
  w.PutVector(size_thresholds_);
  w.PutString(extractor_);
  SaveWords(&w);
  WriteFramedFile(path, kVocabularyMagic, kVocabularyVersion, w.buffer());
}

std::unique_ptr<Vocabulary> Vocabulary::Load(const std::filesystem::path& path) {
  const FramedPayload payload = ReadFramedFile(path, kVocabularyMagic, kOldestVocabularyVersion,
                                               kVocabularyVersion, "vocabulary");
  BinaryReader r(payload.data(), payload.size(), path.string());
  const uint8_t kind = r.Get<uint8_t>(), metric = r.Get<uint8_t>();
  if (kind > 1 || metric > 2) r.Fail("unknown vocabulary kind or metric");
  const uint32_t words = r.Get<uint32_t>();
  auto idf = r.GetVector<float>(100000000);
  auto thresholds = r.GetVector<float>(256);
  std::string extractor;
  if (payload.version() >= 3) extractor = r.GetString(1u << 16);
  auto vocab = static_cast<VocabularyKind>(kind) == VocabularyKind::kAkm
                   ? ReadAkm(&r, static_cast<Metric>(metric))
                   : ReadHkm(&r, static_cast<Metric>(metric));
  if (vocab->size() != words || idf.size() != words) r.Fail("word count mismatch");
  if (r.remaining() != 0) r.Fail("unexpected trailing data");
  vocab->set_idf(std::move(idf));
  vocab->set_size_thresholds(std::move(thresholds));
  vocab->set_extractor(std::move(extractor));
  return vocab;
}

}  // namespace gtbow
