#include "ground_texture_bow/core/config.h"

#include <yaml-cpp/yaml.h>

#include <functional>
#include <map>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "ground_texture_bow/core/file_util.h"

namespace gtbow {

void RetrievalConfig::Check() const {
  features.Check();
  vocabulary.Check();
  bow.Check();
  verification.Check();
  if (bow.compact_postings && features.num_features > 256) {
    throw std::invalid_argument(
        "bow: compact_postings holds at most 256 keypoints per image; set "
        "compact_postings: false for features.num_features " +
        std::to_string(features.num_features));
  }
  if (vocabulary.kind == VocabularyKind::kHkm && bow.soft_assignment != 1) {
    throw std::invalid_argument("bow: soft_assignment must be 1 with an hkm vocabulary");
  }
  const bool binary = features.type == FeatureType::kOrb;
  if (binary && vocabulary.metric == Metric::kL2) {
    throw std::invalid_argument(
        "vocabulary: metric l2 is for SIFT; use l2_bytes or hamming with ORB");
  }
  if (!binary && vocabulary.metric != Metric::kL2) {
    throw std::invalid_argument("vocabulary: SIFT descriptors need metric l2");
  }
  if (bow.size_binning == SizeBinning::kOctave && !binary) {
    throw std::invalid_argument("bow: size_binning octave needs ORB; use percentile with SIFT");
  }
}

namespace {

// One table for every option: its section and key, how its YAML value is read, and how it is
// written. Parsing (the schema), FormatRetrievalConfig (the presets' documented form and what a
// map file records to refuse other options) and RetrievalConfigDifference all come from it.
struct Field {
  const char* section;
  const char* key;
  std::function<void(RetrievalConfig*, const YAML::Node&)> read;
  std::function<std::string(const RetrievalConfig&)> write;
  bool recorded;  // written by FormatRetrievalConfig (threads are not: answers do not depend on
                  // them)
};

template <typename T>
std::string Text(const T& v) {
  std::ostringstream o;
  o << std::boolalpha << v;
  return o.str();
}

template <typename S, typename T>
Field Value(const char* section, const char* key, S RetrievalConfig::*part, T S::*field,
            bool recorded = true) {
  return {section, key,
          [part, field](RetrievalConfig* c, const YAML::Node& n) { (c->*part).*field = n.as<T>(); },
          [part, field](const RetrievalConfig& c) { return Text((c.*part).*field); }, recorded};
}

template <typename S, typename E>
Field Enum(const char* section, const char* key, S RetrievalConfig::*part, E S::*field,
           E (*parse)(const std::string&), std::string (*name)(E)) {
  return {section, key,
          [part, field, parse](RetrievalConfig* c, const YAML::Node& n) {
            (c->*part).*field = parse(n.as<std::string>());
          },
          [part, field, name](const RetrievalConfig& c) { return name((c.*part).*field); }, true};
}

// A verification option (unrecorded: they do not shape the map).
template <typename T>
Field Verify(const char* key, T LocalizationOptions::*field) {
  return {"verification", key,
          [field](RetrievalConfig* c, const YAML::Node& n) { c->verification.*field = n.as<T>(); },
          [field](const RetrievalConfig& c) { return Text(c.verification.*field); }, false};
}
template <typename T>
Field VerifyPose(const char* key, T PoseOptions::*field) {
  return {
      "verification", key,
      [field](RetrievalConfig* c, const YAML::Node& n) { c->verification.pose.*field = n.as<T>(); },
      [field](const RetrievalConfig& c) { return Text(c.verification.pose.*field); }, false};
}

const std::vector<Field>& Fields() {
  using R = RetrievalConfig;
  using F = FeatureOptions;
  using V = VocabularyOptions;
  using B = BowOptions;
  static const std::vector<Field> fields = {
      Enum("features", "type", &R::features, &F::type, &ParseFeatureType, &FeatureTypeName),
      Value("features", "num_features", &R::features, &F::num_features),
      // Shapes no map: a map made without it loads with it.
      Value("features", "query_num_features", &R::features, &F::query_num_features, false),
      Value("features", "query_escalate", &R::features, &F::query_escalate, false),
      Value("features", "query_escalate_backoff", &R::features, &F::query_escalate_backoff, false),
      Value("features", "orb_scale_factor", &R::features, &F::orb_scale_factor),
      Value("features", "orb_num_levels", &R::features, &F::orb_num_levels),
      Value("features", "orb_edge_threshold", &R::features, &F::orb_edge_threshold),
      Value("features", "orb_first_level", &R::features, &F::orb_first_level),
      Value("features", "orb_wta_k", &R::features, &F::orb_wta_k),
      Value("features", "orb_fast_score", &R::features, &F::orb_fast_score),
      Value("features", "orb_patch_size", &R::features, &F::orb_patch_size),
      Value("features", "orb_fast_threshold", &R::features, &F::orb_fast_threshold),
      // Shapes no map: the same keypoints either way.
      Value("features", "orb_threshold_ladder", &R::features, &F::orb_threshold_ladder, false),
      Enum("features", "contrast", &R::features, &F::contrast, &ParseContrast, &ContrastName),
      Value("features", "contrast_target", &R::features, &F::contrast_target),
      Value("features", "contrast_max_gain", &R::features, &F::contrast_max_gain),
      Value("features", "clahe_clip", &R::features, &F::clahe_clip),
      Value("features", "clahe_tiles", &R::features, &F::clahe_tiles),
      Value("features", "orb_min_fast_threshold", &R::features, &F::orb_min_fast_threshold),
      Value("features", "grid_cols", &R::features, &F::grid_cols),
      Value("features", "grid_rows", &R::features, &F::grid_rows),
      Value("features", "grid_oversample", &R::features, &F::grid_oversample),
      Value("features", "grid_refill", &R::features, &F::grid_refill),
      Value("features", "transient_median", &R::features, &F::transient_median),
      Value("features", "transient_k", &R::features, &F::transient_k),
      Value("features", "transient_grow", &R::features, &F::transient_grow),
      Value("features", "transient_fill", &R::features, &F::transient_fill),
      Enum("features", "transient_polarity", &R::features, &F::transient_polarity,
           &ParseMarkPolarity, &MarkPolarityName),
      Value("features", "sift_octave_layers", &R::features, &F::sift_octave_layers),
      Value("features", "sift_contrast_threshold", &R::features, &F::sift_contrast_threshold),
      Value("features", "sift_edge_threshold", &R::features, &F::sift_edge_threshold),
      Value("features", "sift_sigma", &R::features, &F::sift_sigma),
      Enum("vocabulary", "kind", &R::vocabulary, &V::kind, &ParseVocabularyKind,
           &VocabularyKindName),
      Enum("vocabulary", "metric", &R::vocabulary, &V::metric, &ParseMetric, &MetricName),
      Value("vocabulary", "num_words", &R::vocabulary, &V::num_words),
      Value("vocabulary", "kmeans_iterations", &R::vocabulary, &V::kmeans_iterations),
      Value("vocabulary", "kmeans_stop_fraction", &R::vocabulary, &V::kmeans_stop_fraction),
      Value("vocabulary", "kmeans_min_iterations", &R::vocabulary, &V::kmeans_min_iterations),
      Value("vocabulary", "num_trees", &R::vocabulary, &V::num_trees),
      Value("vocabulary", "checks", &R::vocabulary, &V::checks),
      Value("vocabulary", "train_checks", &R::vocabulary, &V::train_checks),
      Enum("vocabulary", "ann", &R::vocabulary, &V::ann, &ParseAnnIndex, &AnnIndexName),
      Value("vocabulary", "nprobe", &R::vocabulary, &V::nprobe),
      Value("vocabulary", "train_nprobe", &R::vocabulary, &V::train_nprobe),
      // The triangle bounds change no answer: like threads, not recorded in maps and caches.
      Value("vocabulary", "ivf_bound", &R::vocabulary, &V::ivf_bound, false),
      Value("vocabulary", "train_bound", &R::vocabulary, &V::train_bound, false),
      Value("vocabulary", "hkm_branching", &R::vocabulary, &V::hkm_branching),
      Value("vocabulary", "hkm_depth", &R::vocabulary, &V::hkm_depth),
      Value("vocabulary", "seed", &R::vocabulary, &V::seed),
      Value("vocabulary", "threads", &R::vocabulary, &V::threads, false),
      Enum("bow", "size_binning", &R::bow, &B::size_binning, &ParseSizeBinning, &SizeBinningName),
      Value("bow", "num_size_bins", &R::bow, &B::num_size_bins),
      Value("bow", "soft_assignment", &R::bow, &B::soft_assignment),
      Value("bow", "sigma", &R::bow, &B::sigma),
      Enum("bow", "normalization", &R::bow, &B::normalization, &ParseNormalization,
           &NormalizationName),
      Value("bow", "orientation_verification", &R::bow, &B::orientation_verification),
      Value("bow", "orientation_bins", &R::bow, &B::orientation_bins),
      Enum("bow", "scoring", &R::bow, &B::scoring, &ParseScoring, &ScoringName),
      Value("bow", "compact_postings", &R::bow, &B::compact_postings),
      Verify("candidates", &LocalizationOptions::candidates),
      Field{"verification", "matches",
            [](RetrievalConfig* c, const YAML::Node& n) {
              c->verification.matches = ParseMatchSource(n.as<std::string>());
            },
            [](const RetrievalConfig& c) { return MatchSourceName(c.verification.matches); },
            false},
      Verify("descriptor_ratio", &LocalizationOptions::descriptor_ratio),
      Verify("max_conflict_ratio", &LocalizationOptions::max_conflict_ratio),
      Verify("consensus_distance", &LocalizationOptions::consensus_distance),
      Verify("consensus_angle", &LocalizationOptions::consensus_angle),
      Verify("guided_radius", &LocalizationOptions::guided_radius),
      Verify("guided_max_distance", &LocalizationOptions::guided_max_distance),
      Verify("guided_seed_inliers", &LocalizationOptions::guided_seed_inliers),
      Verify("guided_repeat_check", &LocalizationOptions::guided_repeat_check),
      Verify("guided_repeat_candidates", &LocalizationOptions::guided_repeat_candidates),
      Verify("guided_repeat_ratio", &LocalizationOptions::guided_repeat_ratio),
      Verify("plain_repeat_below", &LocalizationOptions::plain_repeat_below),
      Verify("plain_repeat_ratio", &LocalizationOptions::plain_repeat_ratio),
      Verify("guided_combined", &LocalizationOptions::guided_combined),
      Verify("escalate_min_inliers", &LocalizationOptions::escalate_min_inliers),
      VerifyPose("min_inliers", &PoseOptions::min_inliers),
      VerifyPose("inlier_threshold", &PoseOptions::inlier_threshold),
      VerifyPose("max_iterations", &PoseOptions::max_iterations),
      VerifyPose("confidence", &PoseOptions::confidence),
      VerifyPose("weighted", &PoseOptions::weighted),
      VerifyPose("angle_tolerance", &PoseOptions::angle_tolerance),
      VerifyPose("min_inlier_fraction", &PoseOptions::min_inlier_fraction),
      VerifyPose("min_spread", &PoseOptions::min_spread),
      VerifyPose("max_theta_sigma", &PoseOptions::max_theta_sigma),
      VerifyPose("max_second_ratio", &PoseOptions::max_second_ratio),

  };
  return fields;
}

const Field* FindField(const std::string& section, const std::string& key) {
  for (const Field& f : Fields()) {
    if (section == f.section && key == f.key) return &f;
  }
  return nullptr;
}

}  // namespace

std::vector<std::string> RetrievalConfigKeys() {
  std::vector<std::string> keys;
  for (const Field& f : Fields()) {
    if (f.recorded) keys.push_back(std::string(f.section) + "." + f.key);
  }
  return keys;
}

RetrievalConfig ParseRetrievalConfig(const std::string& text, const std::string& source) {
  auto fail = [&](const YAML::Node* n, const std::string& what) {
    std::ostringstream s;
    s << source;
    if (n != nullptr && n->Mark().line >= 0) s << ":" << n->Mark().line + 1;
    s << ": " << what;
    throw std::runtime_error(s.str());
  };
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::ParserException& e) {
    throw std::runtime_error(source + ":" + std::to_string(e.mark.line + 1) +
                             ": invalid YAML: " + e.msg);
  }
  RetrievalConfig c;
  if (root.IsNull()) return c;
  if (!root.IsMap()) fail(&root, "expected sections features, vocabulary, bow and verification");
  for (const auto& section : root) {
    const std::string name = section.first.as<std::string>();
    if (name != "features" && name != "vocabulary" && name != "bow" && name != "verification") {
      fail(&section.first,
           "unknown section '" + name + "' (valid: features, vocabulary, bow, verification)");
    }
    if (!section.second.IsMap()) fail(&section.second, "section '" + name + "' must be a mapping");
    for (const auto& kv : section.second) {
      const std::string key = kv.first.as<std::string>();
      const Field* field = FindField(name, key);
      if (field == nullptr) fail(&kv.first, "unknown key '" + name + "." + key + "'");
      try {
        field->read(&c, kv.second);
      } catch (const YAML::Exception&) {
        fail(&kv.second, "bad value for '" + name + "." + key + "': '" +
                             (kv.second.IsScalar() ? kv.second.Scalar() : std::string("?")) + "'");
      } catch (const std::invalid_argument& e) {
        fail(&kv.second, name + "." + key + ": " + e.what());
      }
    }
  }
  try {
    c.Check();
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(source + ": " + e.what());
  }
  return c;
}

RetrievalConfig LoadRetrievalConfig(const std::filesystem::path& path) {
  return ParseRetrievalConfig(ReadFile(path), path.string());
}

std::string FormatRetrievalConfig(const RetrievalConfig& c) {
  std::ostringstream s;
  std::string section;
  for (const Field& f : Fields()) {
    if (!f.recorded) continue;
    if (section != f.section) {
      section = f.section;
      s << section << ":\n";
    }
    s << "  " << f.key << ": " << f.write(c) << "\n";
  }
  return s.str();
}

std::string RetrievalConfigDifference(const RetrievalConfig& a, const std::string& a_name,
                                      const RetrievalConfig& b, const std::string& b_name) {
  std::string diff;
  for (const Field& f : Fields()) {
    if (!f.recorded) continue;
    const std::string va = f.write(a), vb = f.write(b);
    if (va == vb) continue;
    diff += (diff.empty() ? "" : "; ") + std::string(f.section) + "." + f.key + ": " + va + " (" +
            a_name + "), " + vb + " (" + b_name + ")";
  }
  return diff;
}

std::string FormatVerificationOptions(const LocalizationOptions& verification) {
  RetrievalConfig c;
  c.verification = verification;
  std::ostringstream s;
  s << "verification:\n";
  for (const Field& f : Fields()) {
    if (std::string(f.section) == "verification") s << "  " << f.key << ": " << f.write(c) << "\n";
  }
  return s.str();
}

std::string FormatFeatureOptions(const FeatureOptions& features) {
  RetrievalConfig c;
  c.features = features;
  const std::string all = FormatRetrievalConfig(c);
  return all.substr(0, all.find("vocabulary:\n"));
}

void CheckVocabularyExtractor(const Vocabulary& vocabulary, const std::string& vocabulary_name,
                              const FeatureOptions& features) {
  if (vocabulary.extractor().empty()) {
    if (IsPlainExtractor(features)) return;
    throw std::invalid_argument(vocabulary_name +
                                ": the vocabulary does not record its feature extractor (written "
                                "before format 3) and the preset adapts features to the floor; "
                                "train it again with gtbow train-vocab");
  }
  if (vocabulary.extractor() == FormatFeatureOptions(features)) return;
  RetrievalConfig trained;
  try {
    trained = ParseRetrievalConfig(vocabulary.extractor(), vocabulary_name + " (its extractor)");
  } catch (const std::exception& e) {
    throw std::invalid_argument(std::string(e.what()));
  }
  RetrievalConfig wanted;
  wanted.features = features;
  const std::string diff =
      RetrievalConfigDifference(trained, "the vocabulary", wanted, "the preset");
  if (!diff.empty()) {
    throw std::invalid_argument(vocabulary_name +
                                ": the vocabulary was trained with another feature extractor than "
                                "the preset's (" +
                                diff + "); train it with the preset");
  }
}

}  // namespace gtbow
