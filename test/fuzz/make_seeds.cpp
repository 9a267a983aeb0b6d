// Writes the fuzzers' fixture vocabulary (test/fuzz/data/tiny.gtvoc, only when it is missing:
// its fingerprint is in every map seed) and the seed inputs of every corpus under
// test/fuzz/seeds/<target>/seed_*. Usage: make_seeds TEST_FUZZ_DIR CONFIG_DIR
// Run by scripts/fuzz.sh before fuzzing; the fuzzers then add what they find.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "../core/test_scene.h"
#include "fuzz_fixture.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/features.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/eval/dataset.h"
#include "ground_texture_bow/eval/synth/generator.h"

namespace fs = std::filesystem;
using namespace gtbow;

namespace {

fs::path g_corpus;

void Seed(const std::string& target, const std::string& name, const std::string& bytes,
          int mode = -1) {
  fs::create_directories(g_corpus / target);
  std::string out = mode >= 0 ? std::string(1, static_cast<char>(mode)) + bytes : bytes;
  std::ofstream(g_corpus / target / ("seed_" + name), std::ios::binary) << out;
}

struct Images {
  std::vector<cv::Mat> train, map;
  std::vector<Pose2D> map_poses;
};

Images Render() {
  const synth::Scene scene = testing_util::SmallScene(0.15, 0.12, 12);
  Images out;
  for (const auto& im : scene.plan().images) {
    cv::Mat img = scene.Render(im);
    if (im.split == "train") {
      out.train.push_back(img);
    } else if (out.map.size() < 4) {
      out.map.push_back(img);
      out.map_poses.push_back(im.pose);
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: make_seeds TEST_FUZZ_DIR CONFIG_DIR\n");
    return 2;
  }
  const fs::path dir = argv[1], config = argv[2];
  g_corpus = dir / "seeds";
  const Images images = Render();
  const LocalizerOptions lo = fuzz::FixtureOptions();
  const FeatureExtractor fx(lo.retrieval.features);
  cv::Mat train;
  std::vector<uint32_t> image_of;
  for (uint32_t i = 0; i < images.train.size(); ++i) {
    const ImageFeatures f = fx.Extract(images.train[i]);
    image_of.insert(image_of.end(), f.size(), i);
    train.push_back(f.descriptors);
  }
  const fs::path vocab_path = fuzz::FixtureVocabularyPath();
  if (!fs::exists(vocab_path)) {
    auto v = TrainVocabulary(lo.retrieval.vocabulary, train, image_of, false);
    v->set_search(AnnIndex::kIvf, lo.retrieval.vocabulary.nprobe);
    v->Save(vocab_path);
    std::printf("wrote %s\n", vocab_path.c_str());
  }
  // Vocabularies: the fixture (with its IVF index), and small others of each kind and metric.
  Seed("vocabulary", "akm_l2_bytes_ivf", ReadFile(vocab_path), 1);
  Seed("vocabulary", "akm_l2_bytes_ivf_raw", ReadFile(vocab_path), 0);
  const fs::path scratch = fs::temp_directory_path() / "gtbow_make_seeds.tmp";
  auto save_vocab = [&](const std::string& name, VocabularyOptions vo, bool ivf) {
    auto v = TrainVocabulary(vo, train, image_of, false);
    if (ivf) v->set_search(AnnIndex::kIvf, 2);
    v->Save(scratch);
    Seed("vocabulary", name, ReadFile(scratch), 1);
  };
  VocabularyOptions vo = lo.retrieval.vocabulary;
  vo.num_words = 16;
  save_vocab("akm_l2_bytes_flann", vo, false);
  vo.metric = Metric::kHamming;
  save_vocab("akm_hamming", vo, false);
  vo.kind = VocabularyKind::kHkm;
  vo.hkm_branching = 3;
  vo.hkm_depth = 2;
  save_vocab("hkm_hamming", vo, false);
  vo.metric = Metric::kL2Bytes;
  save_vocab("hkm_l2_bytes", vo, false);

  // Maps: empty, four keyframes with poses, the same without poses.
  const auto vocab = fuzz::FixtureVocabulary();
  for (int posed = 0; posed < 3; ++posed) {
    Localizer loc(vocab, vocab_path.string(), lo);
    for (size_t i = 0; posed > 0 && i < images.map.size(); ++i) {
      std::optional<Pose2D> pose;
      if (posed == 2) pose = images.map_poses[i];
      loc.Add(loc.Process(images.map[i]), static_cast<int64_t>(i) * 1000000, pose);
    }
    loc.Save(scratch);
    const char* names[] = {"empty", "unposed", "posed"};
    Seed("map", names[posed], ReadFile(scratch), 1);
    if (posed == 2) Seed("map", "posed_raw", ReadFile(scratch), 0);
  }
  // Databases of both layouts, as files (modes 1, 3) and in memory (modes 5, 7).
  for (const bool compact : {true, false}) {
    const LocalizerOptions o = fuzz::FixtureOptions(compact);
    const BowEncoder encoder(*vocab, o.retrieval.bow);
    BowDatabase db(encoder.num_rows(), o.retrieval.bow, vocab->fingerprint());
    for (const cv::Mat& img : images.map) db.Add(encoder.Encode(fx.Extract(img)));
    db.Remove(1);
    db.Save(scratch);
    const std::string layout = compact ? "compact" : "precise";
    Seed("database", layout + "_file", ReadFile(scratch), compact ? 1 : 3);
    Seed("database", layout + "_file_raw", ReadFile(scratch), compact ? 0 : 2);
    Seed("database", layout + "_memory", db.Serialize(), compact ? 5 : 7);
  }
  fs::remove(scratch);

  // dataset.yaml: the format's example, our writer's output, and one with extra keys.
  Seed("dataset_yaml", "example",
       "format_version: 1\nname: asphalt_synth_seed1      # free text\nsurface: asphalt\n"
       "image_width: 640\nimage_height: 480\nmeters_per_pixel: 0.00025\n"
       "query_days: {query_day000: 0, query_day030: 30}\n");
  DatasetInfo info;
  info.name = "seed";
  info.surface = "concrete";
  info.query_days = {{"query_day000", 0}, {"query_day180", 180}};
  Seed("dataset_yaml", "written", FormatDatasetYaml(info));
  Seed("dataset_yaml", "extra_keys",
       "format_version: 1\nimage_width: 320\nimage_height: 240\nmeters_per_pixel: 1.0e-4\n"
       "camera: {model: pinhole, fx: 500}\nnotes: [a, b]\n");
  // poses.csv and sequence files.
  std::vector<PoseRecord> poses;
  for (size_t i = 0; i < images.map_poses.size(); ++i) {
    poses.push_back({"img" + std::to_string(i) + ".png", images.map_poses[i]});
  }
  Seed("poses_csv", "written", FormatPosesCsv(poses));
  Seed("poses_csv", "extra_columns",
       "stamp,theta,image,y,x,quality\n1,0.5,a.png,1.0,2.0,good\n2,-3.1,b.png,-1e-3,4,ok\n");
  Seed("poses_csv", "sequence", "# query split\n000001.png\n\n000002.png  \n");
  // Presets: every file in config/ and config/ablation/.
  for (const fs::path d : {config, config / "ablation"}) {
    for (const auto& e : fs::directory_iterator(d)) {
      if (e.path().extension() == ".yaml" && e.path().filename() != "localizer.yaml") {
        Seed("config", e.path().stem().string(), ReadFile(e.path()));
      }
    }
  }
  std::printf("seeds written under %s\n", g_corpus.c_str());
  return 0;
}
