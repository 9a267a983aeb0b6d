// gtbow eval: every metric of docs/DATASET_FORMAT.md on a dataset, for one or more retrieval
// presets: retrieval (mAP@1000, Recall@N, score separation), global localization (success at
// 4.8 mm and 1.5 degrees, error distribution) and timing laid out like the paper's Table II.
// Writes results.json (every number), summary.md (ours next to the paper's) and, through
// scripts/plot_eval.py, PNG plots.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <exception>
#include <fstream>
#include <functional>
#include <iomanip>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>
#include <string>
#include <thread>

#include "commands.h"
#include "eval_results.h"
#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/maintenance.h"
#include "ground_texture_bow/core/parallel.h"
#include "ground_texture_bow/core/pose.h"
#include "ground_texture_bow/core/progress.h"
#include "ground_texture_bow/core/sequence.h"
#include "ground_texture_bow/core/simd.h"
#include "ground_texture_bow/eval/metrics.h"
#include "image_source.h"
#include "json_writer.h"
#include "paper_reference.h"
#include "timing.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace tools {

namespace {

// Age of a query split in days: dataset.yaml's query_days, else the digits of query_dayNNN.
double SplitDay(const DatasetInfo& info, const std::string& split) {
  const auto it = info.query_days.find(split);
  if (it != info.query_days.end()) return it->second;
  const auto p = split.find("day");
  if (p != std::string::npos && p + 3 < split.size()) {
    try {
      return std::stod(split.substr(p + 3));
    } catch (const std::exception&) {
    }
  }
  return NAN;
}

std::string PresetName(const std::string& file) {
  return file.empty() ? "high_accuracy (built-in defaults)" : fs::path(file).stem().string();
}

std::unique_ptr<Vocabulary> GetVocabulary(const EvalArgs& a, const RetrievalConfig& c,
                                          const Dataset& ds, std::string* desc) {
  VocabularyRequest r;
  r.file = a.vocab;
  r.train_other_kinds = a.ablation;
  r.dataset = a.dataset;
  r.cache = a.no_cache ? fs::path() : fs::path(a.cache);
  r.threads = a.threads;
  r.progress = !a.quiet;
  (void)ds;
  return DatasetVocabulary(r, c, desc);
}

// --sequence: the trail of each query (split trail_X of query split query_X, the nearest
// sequence - 1 images, with trail_X_odometry.csv), to combine with the query's own features as
// the node's Localizer::Combine does (CombineViews). A query keeps its trail images up to the
// first beyond --sequence-max-span (ImagesInSpan, the rule the node's QuerySequence applies at
// each image; applied once here, against the query, it keeps the same images for a trail that
// leads away from the query, as gtbow synth's do); a query left with none is localized alone,
// as the node localizes an image whose sequence holds only it.
struct QueryTrails {
  std::vector<std::vector<ImageFeatures>> views;  // per query, nearest first
  std::vector<std::vector<Pose2D>> poses;         // per query: the query's (origin), then theirs
  bool Alone(size_t qi) const { return views[qi].empty(); }
  ImageFeatures Combine(const ImageFeatures& query, size_t qi, const ImageGeometry& g) const {
    std::vector<const ImageFeatures*> all{&query};
    for (const ImageFeatures& v : views[qi]) all.push_back(&v);
    return CombineViews(all, poses[qi], g);
  }
};

QueryTrails ReadTrails(const EvalArgs& a, const Dataset& ds, const std::string& split,
                       const ImageSource& q_src, const FeatureOptions& options,
                       const SequenceOptions& sequence, const fs::path& cache) {
  if (split.rfind("query_", 0) != 0) {
    throw std::invalid_argument("--sequence: split " + split + " is not a query_X split");
  }
  const std::string trail = "trail_" + split.substr(6);
  const std::vector<std::string> queries = ds.Split(split);
  const std::vector<std::string> trail_names = ds.Split(trail);
  if (trail_names.size() % queries.size() != 0) {
    throw std::runtime_error(a.dataset + ": split " + trail + " has " +
                             std::to_string(trail_names.size()) + " images, not a multiple of " +
                             split + "'s " + std::to_string(queries.size()));
  }
  const size_t per = trail_names.size() / queries.size();
  if (static_cast<size_t>(a.sequence - 1) > per) {
    throw std::invalid_argument("--sequence " + std::to_string(a.sequence) + ": the dataset's " +
                                "trails have " + std::to_string(per) + " images per query");
  }
  const fs::path odom_file = fs::path(a.dataset) / (trail + "_odometry.csv");
  std::map<std::string, Pose2D> odom;
  for (const PoseRecord& r : ParsePosesCsv(ReadFile(odom_file), odom_file.string())) {
    odom[r.image] = r.pose;
  }
  std::map<std::string, size_t> ordinal;
  for (size_t i = 0; i < queries.size(); ++i) ordinal[queries[i]] = i;
  const size_t n = static_cast<size_t>(a.sequence - 1);
  std::vector<std::string> wanted;  // the trails of the queries kept (after --max-queries)
  for (size_t qi = 0; qi < q_src.size(); ++qi) {
    const size_t i = ordinal.at(q_src.name(qi));
    for (size_t j = 1; j <= n; ++j) wanted.push_back(trail_names[i * per + j - 1]);
  }
  ImageSource t_src = ImageSource::FromDataset(a.dataset, trail);
  t_src.Keep(wanted);
  std::vector<ImageFeatures> feats = ExtractAllCached(t_src, options, cache, a.threads, !a.quiet);
  QueryTrails t;
  t.views.resize(q_src.size());
  t.poses.assign(q_src.size(), {Pose2D{}});
  for (size_t qi = 0; qi < q_src.size(); ++qi) {
    for (size_t j = 0; j < n; ++j) {
      const size_t k = qi * n + j;
      const auto it = odom.find(t_src.name(k));
      if (it == odom.end()) {
        throw std::runtime_error(odom_file.string() + ": no odometry for " + t_src.name(k));
      }
      t.views[qi].push_back(std::move(feats[k]));
      t.poses[qi].push_back(it->second);
    }
    const std::vector<std::optional<Pose2D>> odometry(t.poses[qi].begin(), t.poses[qi].end());
    const size_t kept = ImagesInSpan(odometry, sequence);
    t.poses[qi].resize(kept);
    t.views[qi].resize(kept - 1);
  }
  return t;
}

// --maintain: the map kept up by the robot's sessions (maintenance.h), as the node's
// maintenance mode does it: each session image, in order, localized as a query against the map
// as it is then; the maintainer's step applied (keyframes retired, the view added as a keyframe,
// extracted as one, at its fix). The splits are then evaluated against the maintained map.
MaintenanceResult Maintain(const EvalArgs& a, const RetrievalConfig& c, const BowEncoder& enc,
                           const Dataset& ds, const ImageGeometry& geo, const MapAccess& map,
                           BowDatabase* db, std::vector<ImageFeatures>* db_feats,
                           std::vector<std::vector<Keypoint>>* stored, std::vector<Pose2D>* db_pose,
                           std::vector<Pose2D>* map_pose, std::vector<std::string>* db_names,
                           std::vector<char>* db_live) {
  const fs::path cache = a.no_cache ? fs::path() : fs::path(a.cache);
  MaintenanceResult mr;
  mr.options = a.maintenance;
  MapMaintainer maintainer(a.maintenance, geo);
  for (uint32_t id = 0; id < map_pose->size(); ++id)
    maintainer.Track(id, (*map_pose)[id], 0, false);
  constexpr double kNsPerDay = 86400e9;
  for (const std::string& split : a.maintain) {
    MaintenanceSession ms;
    ms.split = split;
    ms.day = SplitDay(ds.info(), split);
    if (!(ms.day >= 0)) {
      throw std::invalid_argument(
          "--maintain: split " + split +
          " has no day (query_days in dataset.yaml, or dayNNN in its name)");
    }
    const ImageSource src = ImageSource::FromDataset(a.dataset, split);
    const auto q_feats =
        ExtractAllCached(src, QueryFeatureOptions(c.features), cache, a.threads, !a.quiet);
    const auto k_feats = ExtractAllCached(src, c.features, cache, a.threads, !a.quiet);
    const auto q_vecs = EncodeAll(enc, q_feats, a.threads, !a.quiet);
    const auto k_vecs = EncodeAll(enc, k_feats, a.threads, !a.quiet);
    ProgressBar bar("maintain " + split, src.size(), !a.quiet);
    for (size_t i = 0; i < src.size(); ++i) {
      const auto stamp = static_cast<int64_t>(ms.day * kNsPerDay) + static_cast<int64_t>(i);
      const Pose2D truth = ds.PoseOf(src.name(i));
      const auto candidates =
          db->Query(q_vecs[i], static_cast<size_t>(c.verification.candidates), true);
      const Localization fix = VerifyCandidates(candidates, q_vecs[i], map, geo, c.verification);
      ++ms.images;
      if (fix.success) {
        ++ms.fixes;
        ms.correct += IsCorrectPose(fix.estimate.floor_from_query, truth) ? 1 : 0;
      }
      const MaintenanceStep step = maintainer.Observe(fix, stamp);
      if ((!step.retire.empty() || step.add) && map.repeats != nullptr) map.repeats->Clear();
      for (uint32_t id : step.retire) {
        db->Remove(id);
        (*db_live)[id] = 0;
        ++ms.retired;
      }
      if (!step.add) {
        bar.Add();
        continue;
      }
      const Pose2D& p = fix.estimate.floor_from_query;
      const uint32_t id = db->Add(k_vecs[i]);
      db_feats->push_back(k_feats[i]);
      if (!a.exact_keypoints) {
        stored->push_back(StoredKeypoints(k_feats[i].keypoints, geo.width, geo.height));
      }
      db_pose->push_back(truth);
      map_pose->push_back(p);
      db_names->push_back(src.name(i));
      db_live->push_back(1);
      if (id + 1 != db_pose->size())
        throw std::logic_error("eval --maintain: keyframe ids out of step");
      maintainer.Track(id, p, stamp, true);
      ++ms.added;
      const double err = 1000.0 * std::hypot(p.x - truth.x, p.y - truth.y);
      ms.added_error_mm.push_back(err);
      ms.added_error_deg.push_back(std::abs(WrapAngle(p.theta - truth.theta)) * 180.0 / M_PI);
      ms.added_wrong += IsCorrectPose(p, truth) ? 0 : 1;
      bar.Add();
    }
    bar.Finish();
    ms.keyframes_after = db->size();
    mr.sessions.push_back(ms);
  }
  return mr;
}

// --timing-alternate: the presets' timed queries side by side, as --timing-kernels times the
// kernels. Each preset runs on a thread of its own, and only one thread works at a time: the
// presets, in the order given, up to their timing; there each hands over its one-query timing
// and waits. The calling thread (Run) then times every query through every preset, the order
// rotating from query to query, so that a change in the machine's speed falls on every preset
// alike; then the presets finish, again in order. A preset's locals stay alive on its waiting
// thread while the calling thread times through them.
class TimingRotation {
 public:
  struct Abandoned {};  // another preset failed: this one stops too
  explicit TimingRotation(size_t presets) : time_(presets), sizes_(presets) {}

  // Preset k waits for its turn; false when the rotation was abandoned.
  bool Begin(size_t k) {
    std::unique_lock<std::mutex> lock(m_);
    cv_.wait(lock, [&] { return failed_ || turn_ == k; });
    return !failed_;
  }
  // Preset k hands over `time_one` (times query i of its `queries` timed queries) and waits
  // until every query is timed and its turn has come again; throws Abandoned when it was.
  void Arrive(size_t k, std::function<void(size_t)> time_one, size_t queries) {
    std::unique_lock<std::mutex> lock(m_);
    time_[k] = std::move(time_one);
    sizes_[k] = queries;
    ++turn_;
    cv_.notify_all();
    cv_.wait(lock, [&] { return failed_ || (timed_ && after_ == k); });
    if (failed_) throw Abandoned{};
  }
  // Preset k is done: the next one's turn.
  void Finish(size_t k) {
    std::lock_guard<std::mutex> lock(m_);
    if (timed_) after_ = k + 1;
    cv_.notify_all();
  }
  // A preset (or the timing) failed: every waiting thread stops.
  void Fail() {
    std::lock_guard<std::mutex> lock(m_);
    failed_ = true;
    cv_.notify_all();
  }
  // The calling thread: waits for every preset, times, and lets them finish. Throws what a
  // timing threw (after Fail).
  void Run(bool quiet) {
    {
      std::unique_lock<std::mutex> lock(m_);
      cv_.wait(lock, [&] { return failed_ || turn_ == time_.size(); });
      if (failed_) return;
    }
    try {
      const size_t n = time_.size(), queries = sizes_[0];
      for (size_t s : sizes_) {
        if (s != queries)
          throw std::logic_error("--timing-alternate: the presets timed different queries");
      }
      ProgressBar bar("timing, presets side by side", queries, !quiet);
      for (size_t qi = 0; qi < queries; ++qi) {
        for (size_t j = 0; j < n; ++j) time_[(qi + j) % n](qi);
        bar.Add();
      }
      bar.Finish();
    } catch (...) {
      Fail();
      throw;
    }
    std::lock_guard<std::mutex> lock(m_);
    timed_ = true;
    after_ = 0;
    cv_.notify_all();
  }

 private:
  std::mutex m_;
  std::condition_variable cv_;
  std::vector<std::function<void(size_t)>> time_;
  std::vector<size_t> sizes_;
  size_t turn_ = 0, after_ = 0;
  bool timed_ = false, failed_ = false;
};

PresetResult EvalPreset(const EvalArgs& a, const std::string& preset_file, const Dataset& ds,
                        const std::vector<std::string>& splits, std::string* rankings,
                        std::string* poses, std::string* verifications,
                        TimingRotation* rotation = nullptr, size_t rotation_index = 0) {
  PresetResult pr;
  pr.file = preset_file;
  pr.name = PresetName(preset_file);
  RetrievalConfig c = preset_file.empty() ? RetrievalConfig{} : LoadRetrievalConfig(preset_file);
  if (a.words > 0 && c.vocabulary.kind == VocabularyKind::kAkm) c.vocabulary.num_words = a.words;
  if (a.candidates > 0) c.verification.candidates = a.candidates;
  if (a.min_inliers > 0) c.verification.pose.min_inliers = a.min_inliers;
  c.Check();
  pr.config = c;
  const ImageGeometry geo = ds.info().geometry;
  const fs::path cache = a.no_cache ? fs::path() : fs::path(a.cache);
  if (!a.quiet) std::fprintf(stderr, "== preset %s\n", pr.name.c_str());

  auto vocab = GetVocabulary(a, c, ds, &pr.vocab_desc);
  vocab->set_search(c.vocabulary.ann, c.vocabulary.nprobe);
  vocab->set_search_bound(c.vocabulary.ivf_bound);
  const BowEncoder enc(*vocab, c.bow);
  ImageSource db_src = ImageSource::FromDataset(a.dataset, "database");
  auto db_feats = ExtractAllCached(db_src, c.features, cache, a.threads, !a.quiet);
  const auto db_vecs = EncodeAll(enc, db_feats, a.threads, !a.quiet);
  // Query images of every split, extracted (or read from the cache) before the database grows.
  std::vector<ImageSource> q_sources;
  std::vector<std::vector<BowVector>> q_vecs_all;
  std::vector<QueryTrails> q_trails;                 // --sequence
  std::vector<std::vector<BowVector>> q_single_all;  // --sequence: each query alone
  SequenceOptions sequence;
  sequence.length = a.sequence;
  sequence.single_first = !a.sequence_always;
  sequence.max_span = a.sequence_max_span;
  sequence.Check();
  // An escalating preset (features.query_escalate) localizes a single image as the node's
  // localization mode does (Localizer::LocalizeImage): extracted as a keyframe first, with
  // query_num_features only when that gives no fix with escalate_min_inliers inliers. Not with
  // --sequence or --maintain, where the node takes query_num_features keypoints at once (sequences,
  // the maintenance mode).
  const bool escalate = c.features.query_escalate && a.sequence <= 1 && a.maintain.empty();
  std::vector<std::vector<BowVector>> q_first_all;  // escalate: each query as a keyframe
  for (const auto& split : splits) {
    ImageSource q_src = ImageSource::FromDataset(a.dataset, split);
    q_src.Subsample(a.max_queries);
    std::vector<ImageFeatures> q_feats =
        ExtractAllCached(q_src, QueryFeatureOptions(c.features), cache, a.threads, !a.quiet);
    if (escalate) {
      q_first_all.push_back(
          EncodeAll(enc, ExtractAllCached(q_src, c.features, cache, a.threads, !a.quiet), a.threads,
                    !a.quiet));
    }
    if (a.sequence > 1) {
      q_single_all.push_back(EncodeAll(enc, q_feats, a.threads, !a.quiet));
      q_trails.push_back(
          ReadTrails(a, ds, split, q_src, QueryFeatureOptions(c.features), sequence, cache));
      for (size_t qi = 0; qi < q_feats.size(); ++qi) {
        q_feats[qi] = q_trails.back().Combine(q_feats[qi], qi, geo);
      }
    }
    q_vecs_all.push_back(EncodeAll(enc, q_feats, a.threads, !a.quiet));
    q_sources.push_back(std::move(q_src));
  }

  // The database, grown image by image: every insertion is timed, and at sizes 1,000, 2,000,
  // 4,000, ... (from 250) a sample of queries is timed too (the paper's Fig. 3).
  BowDatabase db(enc.num_rows(), c.bow, vocab->fingerprint());
  std::vector<Pose2D> db_pose;
  std::vector<BowVector> scaling_queries;
  for (size_t s = 0; s < q_vecs_all.size() && scaling_queries.size() < kScalingQueries; ++s) {
    for (size_t i = 0; i < q_vecs_all[s].size() && scaling_queries.size() < kScalingQueries; ++i) {
      scaling_queries.push_back(q_vecs_all[s][i]);
    }
  }
  size_t next_checkpoint = 250;
  std::vector<double> insert_ms;
  auto checkpoint = [&]() {
    ScalingPoint sp;
    sp.images = db.size();
    const size_t n = std::min(insert_ms.size(), static_cast<size_t>(1000));
    sp.insert = Summarise(std::vector<double>(insert_ms.end() - n, insert_ms.end()));
    std::vector<double> q;
    for (const auto& v : scaling_queries) {
      const auto t0 = std::chrono::steady_clock::now();
      (void)db.Query(v, static_cast<size_t>(c.verification.candidates), true);
      q.push_back(Ms(std::chrono::steady_clock::now() - t0));
    }
    sp.query = Summarise(q);
    pr.scaling.push_back(sp);
  };
  {
    ProgressBar bar("database", db_vecs.size(), !a.quiet);
    for (size_t i = 0; i < db_vecs.size(); ++i) {
      const auto t0 = std::chrono::steady_clock::now();
      db.Add(db_vecs[i]);
      insert_ms.push_back(Ms(std::chrono::steady_clock::now() - t0));
      db_pose.push_back(ds.PoseOf(db_src.name(i)));
      if (db.size() == next_checkpoint) {
        checkpoint();
        next_checkpoint *= 2;
      }
      bar.Add();
    }
    bar.Finish();
    if (pr.scaling.empty() || pr.scaling.back().images != db.size()) checkpoint();
  }
  pr.db_images = db.size();
  // The map's keypoints as the node's map keeps them (quantised, StoredKeypoints), unless
  // --exact-keypoints: the node verifies against those.
  std::vector<std::vector<Keypoint>> stored;
  if (!a.exact_keypoints) {
    stored.resize(db_feats.size());
    for (size_t i = 0; i < db_feats.size(); ++i) {
      stored[i] = StoredKeypoints(db_feats[i].keypoints, geo.width, geo.height);
    }
  }
  MapAccess map;
  map.keypoints = [&](uint32_t i) -> const std::vector<Keypoint>& {
    return a.exact_keypoints ? db_feats.at(i).keypoints : stored.at(i);
  };
  map.descriptors = [&](uint32_t i) { return db_feats.at(i).descriptors; };
  // The poses localization reads: the truth for the database, the fix for a view a maintained
  // map added (db_pose keeps every keyframe's truth, for relevance).
  std::vector<Pose2D> map_pose = db_pose;
  map.pose = [&](uint32_t i) { return map_pose.at(i); };
  // A map image as a query and the map's retrieval for it, for the repeat check of guided
  // matching (verification.guided_repeat_check), as the node's Localizer::Localize gives them.
  map.query_of = [&](uint32_t i) {
    ImageFeatures f;
    f.keypoints = map.keypoints(i);
    f.descriptors = db_feats.at(i).descriptors;
    return enc.Encode(f);
  };
  map.retrieve = [&](const BowVector& q, uint32_t self, size_t k) {
    auto r = db.Query(q, k + 1, true);
    r.erase(std::remove_if(r.begin(), r.end(),
                           [self](const QueryResult& x) { return x.image == self; }),
            r.end());
    return r;
  };
  // Each keyframe's copies, found by the repeat checks, kept until the map changes (as the
  // node's Localizer keeps them): a maintained map clears them at every change.
  RepeatCache repeat_cache;
  map.repeats = &repeat_cache;
  std::vector<std::string> db_names;
  for (size_t i = 0; i < db_src.size(); ++i) db_names.push_back(db_src.name(i));
  std::vector<char> db_live(db_pose.size(), 1);  // 0: retired by maintenance
  const LocalizationOptions& lo = c.verification;
  // A sequence query's combined view is verified as the node's Localizer verifies one.
  const LocalizationOptions lo_view = a.sequence > 1 ? CombinedViewOptions(lo) : lo;
  const LocalizationOptions lo_first = FirstPassOptions(lo);  // escalate: the first pass
  if (!a.maintain.empty()) {
    pr.maintenance = Maintain(a, c, enc, ds, geo, map, &db, &db_feats, &stored, &db_pose, &map_pose,
                              &db_names, &db_live);
  }

  // Retrieval and localization, split by split.
  for (size_t si = 0; si < splits.size(); ++si) {
    const std::string& split = splits[si];
    const ImageSource& q_src = q_sources[si];
    const std::vector<BowVector>& q_vecs = q_vecs_all[si];
    SplitResult sr;
    sr.name = split;
    sr.day = SplitDay(ds.info(), split);
    sr.queries = q_src.size();
    struct PerQuery {
      bool counted = false;
      double ap = 0;
      std::vector<double> hits;
      std::vector<std::pair<double, bool>> top10;
      std::vector<double> disjoint;  // top-10 scores of false results not overlapping at all
      std::vector<QueryResult> ranking;
      Localization loc;
      bool escalated = false;    // escalate: the full pass gave loc
      bool skipped = false;      // escalate: the backoff sent it straight to the full pass
      Localization first, full;  // escalate: each pass's own fix (the backoff chooses, below)
      // Verified candidates of one pass: counted, and written to verifications.csv.
      struct Verified {
        size_t verified = 0, wrong = 0;
        std::string rows;
        void Add(const Verified& o) {
          verified += o.verified;
          wrong += o.wrong;
          rows += o.rows;
        }
      };
      // escalate: each pass's verified candidates, counted where the node would have run it
      // (the first pass unless the backoff skipped it, the full pass when the first gave no fix
      // that stands).
      Verified first_pass, full_pass;
      Pose2D truth;
      Verified poses;  // over all top-K candidates of the passes that ran
    };
    std::vector<PerQuery> per(q_src.size());
    ProgressBar bar("queries " + split, q_src.size(), !a.quiet);
    ParallelForEach(q_src.size(), a.threads, [&](size_t qi) {
      PerQuery& p = per[qi];
      p.truth = ds.PoseOf(q_src.name(qi));
      size_t num_rel = 0;
      for (size_t d = 0; d < db_pose.size(); ++d) {
        num_rel += db_live[d] && IsRelevant(p.truth, db_pose[d], geo) ? 1 : 0;
      }
      p.ranking = db.Query(q_vecs[qi], 1000, false);
      // Localization as the node does it, then every candidate of the top K verified on its
      // own (with the consensus, when on), to count wrong poses among all of them.
      const auto candidates = db.Query(q_vecs[qi], static_cast<size_t>(lo.candidates), true);
      // A sequence query: the query alone first (--sequence-always: the combined view only),
      // as the node does (SequenceFix). An escalating query: the image as a keyframe first
      // (EscalatedFix). Their candidates are the first pass's.
      std::vector<QueryResult> single_candidates;
      const BowVector* first_vec = nullptr;
      const LocalizationOptions* first_lo = &lo;
      // A sequence query's combined view is verified only where the node verifies it: when the
      // query alone gave no fix (or with --sequence-always). Its candidates count only then.
      bool used_combined = true;
      if (a.sequence > 1) {
        const BowVector& own = q_single_all[si][qi];
        first_vec = &own;
        // No trail image within the span: the node localizes the image alone (its sequence
        // holds only it), as a single image.
        const bool alone = q_trails[si].Alone(qi);
        if (sequence.single_first || alone) {
          single_candidates = db.Query(own, static_cast<size_t>(lo.candidates), true);
        }
        if (alone) {
          p.loc = VerifyCandidates(single_candidates, own, map, geo, lo);
          used_combined = false;
        } else {
          p.loc = SequenceFix(
              sequence, [&] { return VerifyCandidates(single_candidates, own, map, geo, lo); },
              [&] { return VerifyCandidates(candidates, q_vecs[qi], map, geo, lo_view); },
              &used_combined);
        }
      } else if (escalate) {
        const BowVector& own = q_first_all[si][qi];
        first_vec = &own;
        first_lo = &lo_first;
        single_candidates = db.Query(own, static_cast<size_t>(lo.candidates), true);
        // Both passes here; which of them the node would have run is decided in the split's
        // order below, as its backoff decides in the order of its images.
        p.first = VerifyCandidates(single_candidates, own, map, geo, lo_first);
        p.full = VerifyCandidates(candidates, q_vecs[qi], map, geo, lo);
      } else {
        p.loc = VerifyCandidates(candidates, q_vecs[qi], map, geo, lo);
      }
      // One row per verified candidate: its evidence and its error against the truth, and which
      // view of the query verified it (`view`: image, first_pass, full_pass, alone, combined).
      auto record = [&](size_t rank, const PoseEstimate& e,
                        const std::vector<QueryResult>& candidates, const char* view,
                        PerQuery::Verified* into) {
        ++into->verified;
        const bool wrong = !IsCorrectPose(e.floor_from_query, p.truth);
        into->wrong += wrong ? 1 : 0;
        const Pose2D& f = e.floor_from_query;
        char b[560];
        const int len = std::snprintf(
            b, sizeof(b),
            "%s,%s,%s,%zu,%s,%.6g,%d,%d,%.4g,%.4g,%.4g,%d,%.4g,%.4g,%.4g,%d,%.6f,%.6f,"
            "%.6f,%.6f,%.6f,%.6f,%s\n",
            pr.name.c_str(), split.c_str(), q_src.name(qi).c_str(), rank + 1,
            db_names[candidates[rank].image].c_str(), candidates[rank].score, e.matches, e.inliers,
            e.residual_rms, e.spread, e.theta_sigma * 180.0 / M_PI, e.second_inliers,
            e.angle_agreement, 1000.0 * std::hypot(f.x - p.truth.x, f.y - p.truth.y),
            std::abs(WrapAngle(f.theta - p.truth.theta)) * 180.0 / M_PI, wrong ? 1 : 0, f.x, f.y,
            f.theta, p.truth.x, p.truth.y, p.truth.theta, view);
        if (len < 0 || static_cast<size_t>(len) >= sizeof(b)) {
          throw std::runtime_error("verifications.csv: the row of query " + q_src.name(qi) +
                                   " does not fit in " + std::to_string(sizeof(b)) + " bytes");
        }
        into->rows += b;
      };
      if (used_combined) {
        const std::vector<PoseEstimate> each =
            VerifyEach(candidates, q_vecs[qi], map, geo, lo_view);
        const char* view = a.sequence > 1 ? "combined" : escalate ? "full_pass" : "image";
        for (size_t k = 0; k < each.size(); ++k) {
          if (each[k].success) {
            record(k, each[k], candidates, view, escalate ? &p.full_pass : &p.poses);
          }
        }
      }
      if (!single_candidates.empty()) {  // the first pass's candidates count too
        const std::vector<PoseEstimate> own =
            VerifyEach(single_candidates, *first_vec, map, geo, *first_lo);
        // An escalating query's first pass stands only with escalate_min_inliers: a weaker pose
        // is never published (EscalatedFix), so it is not counted as verified.
        const int stands = escalate ? lo.escalate_min_inliers : 0;
        for (size_t k = 0; k < own.size(); ++k) {
          if (own[k].success && own[k].inliers >= stands) {
            record(k, own[k], single_candidates, escalate ? "first_pass" : "alone",
                   escalate ? &p.first_pass : &p.poses);
          }
        }
      }
      if (num_rel > 0) {
        p.counted = true;
        std::vector<bool> rel;
        for (size_t k = 0; k < p.ranking.size(); ++k) {
          rel.push_back(IsRelevant(p.truth, db_pose[p.ranking[k].image], geo));
          if (k < 10) {
            p.top10.emplace_back(p.ranking[k].score, rel.back());
            if (!rel.back() && Overlap(p.truth, db_pose[p.ranking[k].image], geo) <= 0.0) {
              p.disjoint.push_back(p.ranking[k].score);
            }
          }
        }
        p.ap = AveragePrecision(rel, num_rel);
        for (size_t n : kRecallN) p.hits.push_back(HitAtN(rel, n));
      }
      bar.Add();
    });
    bar.Finish();
    if (escalate) {
      // The node's stream: the split's images in order through one backoff
      // (features.query_escalate_backoff), each fix chosen by EscalatedFix as the node's.
      EscalationBackoff backoff(c.features.query_escalate_backoff);
      for (PerQuery& p : per) {
        const size_t skipped = backoff.skipped();
        p.loc = EscalatedFix(
            true, lo, [&] { return p.first; }, [&] { return p.full; }, &p.escalated, &backoff);
        p.skipped = backoff.skipped() != skipped;
        if (!p.skipped) p.poses.Add(p.first_pass);  // the first pass ran
        if (p.escalated) p.poses.Add(p.full_pass);  // and the full pass, where it ran
      }
    }
    sr.recall.assign(std::size(kRecallN), 0.0);
    std::vector<RankedAnswer> top1, closures;
    for (size_t qi = 0; qi < per.size(); ++qi) {
      const PerQuery& p = per[qi];
      sr.verified_poses += p.poses.verified;
      sr.wrong_verified_poses += p.poses.wrong;
      sr.escalated += p.escalated && !p.skipped ? 1 : 0;
      sr.first_passes_skipped += p.skipped ? 1 : 0;
      *verifications += p.poses.rows;
      if (p.counted && !p.ranking.empty()) {
        top1.push_back({p.ranking[0].score, IsRelevant(p.truth, db_pose[p.ranking[0].image], geo)});
      }
      if (p.loc.success) {
        closures.push_back({static_cast<double>(p.loc.estimate.inliers),
                            IsCorrectPose(p.loc.estimate.floor_from_query, p.truth)});
      }
      if (p.counted) {
        ++sr.counted;
        sr.map += p.ap;
        for (size_t k = 0; k < p.hits.size(); ++k) sr.recall[k] += p.hits[k];
        for (const auto& [score, rel] : p.top10)
          (rel ? sr.rel_scores : sr.irr_scores).push_back(score);
        sr.disjoint_scores.insert(sr.disjoint_scores.end(), p.disjoint.begin(), p.disjoint.end());
      } else {
        ++sr.no_relevant;
      }
      if (p.loc.success) {
        ++sr.estimated;
        const Pose2D& e = p.loc.estimate.floor_from_query;
        const double em = std::hypot(e.x - p.truth.x, e.y - p.truth.y);
        const double er = std::abs(WrapAngle(e.theta - p.truth.theta));
        sr.err_mm.push_back(1000.0 * em);
        sr.err_deg.push_back(er * 180.0 / M_PI);
        sr.localized += IsCorrectPose(e, p.truth) ? 1 : 0;
      }
      const std::string& qn = q_src.name(qi);
      char b[256];
      for (size_t k = 0; k < p.ranking.size(); ++k) {
        std::snprintf(b, sizeof(b), ",%zu,%s,%.9g\n", k + 1, db_names[p.ranking[k].image].c_str(),
                      p.ranking[k].score);
        *rankings += qn + b;
      }
      if (p.loc.success) {
        const Pose2D& e = p.loc.estimate.floor_from_query;
        std::snprintf(b, sizeof(b), ",%.6f,%.6f,%.6f,%d\n", e.x, e.y, e.theta,
                      p.loc.estimate.inliers);
        *poses += qn + b;
      } else {
        *poses += qn + ",,,,0\n";
      }
    }
    const double n = static_cast<double>(std::max<size_t>(1, sr.counted));
    sr.map /= n;
    for (double& r : sr.recall) r /= n;
    sr.separation = ScoreSeparation(sr.rel_scores, sr.irr_scores);
    sr.pr_bow = PrecisionRecallCurve(top1, sr.counted);
    sr.pr_verified = PrecisionRecallCurve(closures, sr.counted);
    sr.separation_disjoint = ScoreSeparation(sr.rel_scores, sr.disjoint_scores);
    pr.splits.push_back(std::move(sr));
  }

  // Timing: random queries (--timing-in-order: the first ones in order) against the full
  // database, one thread, stage by stage.
  std::vector<std::pair<size_t, size_t>> pool;  // (split, query)
  for (size_t s = 0; s < q_sources.size(); ++s)
    for (size_t i = 0; i < q_sources[s].size(); ++i) pool.emplace_back(s, i);
  std::mt19937_64 rng(7);
  if (!a.timing_in_order) std::shuffle(pool.begin(), pool.end(), rng);
  pool.resize(std::min(pool.size(), a.timing_queries));
  // A localization query is extracted with the query options (query_num_features; an
  // escalating preset's first pass as a keyframe); the insertion is timed with the image
  // extracted as a keyframe.
  const FeatureExtractor fx(c.features), fxq(QueryFeatureOptions(c.features));
  // A keyframe is one image extracted as a keyframe: with --sequence a query is not one.
  const bool query_differs =
      fxq.options().num_features != c.features.num_features || a.sequence > 1;
  struct Samples {
    std::vector<double> ex, tr, in, qu, po, to;
  };
  // One query through every stage, as the node runs them, timed stage by stage.
  // With --sequence the trail's features are at hand (extracted as their images came) and the
  // transform stage combines them with the query's before encoding.
  // With --sequence the stages add up as SequenceFix runs them: the query alone first (unless
  // --sequence-always), then, when it gives no fix, the combined view.
  // An escalating query (escalate) adds up both passes when the first gives no fix.
  auto time_query = [&](const cv::Mat& img, size_t split, size_t qi, Samples* out,
                        EscalationBackoff* backoff) {
    using Clock = std::chrono::steady_clock;
    const auto t0 = Clock::now();
    Clock::duration extraction{}, transform{}, query{};
    auto extract = [&](const FeatureExtractor& x) {
      const auto e0 = Clock::now();
      ImageFeatures r = x.Extract(img);
      extraction += Clock::now() - e0;
      return r;
    };
    ImageFeatures f;
    BowVector v;
    auto localize = [&](auto&& encode, const LocalizationOptions& with) {
      const auto a0 = Clock::now();
      v = encode();
      const auto a1 = Clock::now();
      const auto results = db.Query(v, static_cast<size_t>(with.candidates), true);
      const auto a2 = Clock::now();
      transform += a1 - a0;
      query += a2 - a1;  // the pose is what remains of the end to end
      return VerifyCandidates(results, v, map, geo, with);
    };
    auto alone = [&] { return localize([&] { return enc.Encode(f); }, lo); };
    if (escalate) {
      (void)EscalatedFix(
          true, lo,
          [&] {
            const ImageFeatures first = extract(fx);
            return localize([&] { return enc.Encode(first); }, lo_first);
          },
          [&] {
            f = extract(fxq);
            return alone();
          },
          nullptr, backoff);
    } else {
      f = extract(fxq);
      if (a.sequence > 1 && !q_trails[split].Alone(qi)) {
        (void)SequenceFix(
            sequence, alone,
            [&] {
              return localize([&] { return enc.Encode(q_trails[split].Combine(f, qi, geo)); },
                              lo_view);
            },
            nullptr);
      } else {
        (void)alone();
      }
    }
    const auto t4_query = Clock::now();
    const BowVector keyframe = query_differs ? enc.Encode(fx.Extract(img)) : BowVector();
    const auto t4 = std::chrono::steady_clock::now();
    const uint32_t id = db.Add(query_differs ? keyframe : v);
    const auto t5 = std::chrono::steady_clock::now();
    db.Remove(id);
    out->ex.push_back(Ms(extraction));
    out->tr.push_back(Ms(transform));
    out->qu.push_back(Ms(query));
    out->po.push_back(Ms(t4_query - t0 - extraction - transform - query));
    out->in.push_back(Ms(t5 - t4));
    out->to.push_back(Ms(t4_query - t0));
  };
  auto summarise = [](const Samples& s, auto* dst) {
    dst->extract = Summarise(s.ex);
    dst->transform = Summarise(s.tr);
    dst->insert = Summarise(s.in);
    dst->query = Summarise(s.qu);
    dst->pose = Summarise(s.po);
    dst->total = Summarise(s.to);
  };
  Samples main_samples;
  // An escalating preset's timed queries go through one backoff in the pool's order: random, so
  // unkind to it where the splits differ, unless --timing-in-order (a drive's images; each split
  // a stream of its own, as in the accuracy loop).
  const EscalationBackoff fresh_backoff(c.features.query_escalate_backoff);
  // Where the in-order pool moves on to the next split (time_one is called with qi in order).
  auto new_stream = [&](size_t qi) {
    return a.timing_in_order && qi > 0 && pool[qi].first != pool[qi - 1].first;
  };
  EscalationBackoff main_backoff = fresh_backoff;
  size_t timed_skipped = 0;
  // The repeat checks' copies of keyframes (RepeatCache): a random timed query starts without
  // them, as a robot's first image of a place does; in order (a drive's images) each split's
  // stream starts without them and keeps what it found, as the node does.
  auto time_one = [&](size_t qi) {
    const auto& [s, i] = pool[qi];
    if (new_stream(qi)) {
      timed_skipped += main_backoff.skipped();
      main_backoff = fresh_backoff;
    }
    if (!a.timing_in_order || qi == 0 || new_stream(qi)) repeat_cache.Clear();
    time_query(q_sources[s].LoadGray(i), s, i, &main_samples, &main_backoff);
  };
  if (rotation != nullptr) {
    rotation->Arrive(rotation_index, time_one, pool.size());
  } else {
    ProgressBar bar("timing", pool.size(), !a.quiet);
    for (size_t qi = 0; qi < pool.size(); ++qi) {
      time_one(qi);
      bar.Add();
    }
    bar.Finish();
  }
  pr.timed = pool.size();
  pr.timed_in_order = a.timing_in_order;
  pr.timed_first_passes_skipped = timed_skipped + main_backoff.skipped();
  pr.timed_side_by_side = rotation != nullptr;
  summarise(main_samples, &pr);
  if (!a.timing_kernels.empty()) {
    // Side by side: a change in the machine's speed falls on every kernel alike.
    const std::string limit = SimdLimit();
    const size_t nk = a.timing_kernels.size();
    std::vector<Samples> samples(nk);
    std::vector<EscalationBackoff> backoffs(nk, fresh_backoff);
    pr.by_kernel.resize(nk);
    ProgressBar kbar("timing kernels", pool.size(), !a.quiet);
    for (size_t qi = 0; qi < pool.size(); ++qi) {
      const cv::Mat img = q_sources[pool[qi].first].LoadGray(pool[qi].second);
      if (new_stream(qi)) backoffs.assign(nk, fresh_backoff);  // each split a stream of its own
      for (size_t j = 0; j < nk; ++j) {
        const size_t k = (qi + j) % nk;
        SetSimdLimit(a.timing_kernels[k]);
        if (qi == 0) {
          pr.by_kernel[k].requested = a.timing_kernels[k];
          pr.by_kernel[k].hamming = ActiveHammingKernelName();
          pr.by_kernel[k].l2_bytes = ActiveByteDistanceKernelName();
        }
        repeat_cache.Clear();  // every kernel alike, without the copies of keyframes
        time_query(img, pool[qi].first, pool[qi].second, &samples[k], &backoffs[k]);
      }
      kbar.Add();
    }
    kbar.Finish();
    SetSimdLimit(limit);
    for (size_t k = 0; k < nk; ++k) summarise(samples[k], &pr.by_kernel[k]);
  }
  return pr;
}

void RunEval(const EvalArgs& a) {
  const Dataset ds = Dataset::Load(a.dataset);
  std::vector<std::string> splits = a.query_splits;
  if (splits.empty()) {
    for (const auto& s : ds.SplitNames()) {
      if (s.rfind("query", 0) == 0) splits.push_back(s);
    }
  }
  if (splits.empty())
    throw std::runtime_error(a.dataset + ": no query splits (sequences/query*.txt)");
  (void)ds.Split("database");  // a clear error now rather than after training
  for (const auto& s : splits) (void)ds.Split(s);
  for (const auto& s : a.maintain) (void)ds.Split(s);
  if (!a.maintain.empty()) a.maintenance.Check();
  std::vector<std::string> presets = a.presets;
  std::vector<std::string> rows(presets.size());
  if (a.ablation) {
    if (!presets.empty())
      throw std::invalid_argument("--ablation runs its own presets; drop --preset");
    for (const auto& [row, file] : kAblation) {
      rows.push_back(row);
      presets.push_back(ConfigFile(file));
    }
  }
  if (presets.empty()) {
    presets.emplace_back(ConfigFile("high_accuracy.yaml"));
    rows.emplace_back();
  }
  // Every preset is read now: a typo in the last of several presets fails before hours of work.
  for (const auto& p : presets) (void)LoadRetrievalConfig(p);
  // Outputs are staged, so that a failed run leaves no half-written results. An earlier run's
  // results (results.json) are replaced; any other non-empty directory (a dataset, a home
  // directory given by mistake) is refused, never deleted.
  {
    std::error_code ec;
    const fs::path out = fs::weakly_canonical(fs::absolute(a.out), ec);
    const fs::path data = fs::weakly_canonical(fs::absolute(a.dataset), ec);
    const auto rel = data.lexically_relative(out);
    if (!rel.empty() && *rel.begin() != "..") {  // the dataset is --out or inside it
      throw std::runtime_error("--out '" + a.out + "' holds the dataset '" + a.dataset +
                               "'; choose another directory");
    }
    if (fs::is_directory(out, ec) && !fs::is_empty(out, ec) &&
        !fs::exists(out / "results.json", ec)) {
      throw std::runtime_error("output directory '" + out.string() +
                               "' exists and holds no earlier gtbow eval results (results.json); "
                               "choose another --out or empty it");
    }
  }
  const fs::path staging = StageDirectory(a.out, true);
  std::vector<std::pair<std::string, std::string>> dumps;  // (path, contents)
  try {
    std::vector<PresetResult> results;
    std::string verifications =
        "preset,split,query,rank,image,score,matches,inliers,residual_px,spread_px,"
        "theta_sigma_deg,second_inliers,angle_agreement,error_mm,error_deg,wrong,x,y,theta,true_x,"
        "true_y,true_theta,view\n";
    const size_t np = presets.size();
    std::vector<std::string> rankings_of(np, "query,rank,image,score\n"),
        poses_of(np, "query,x,y,theta,inliers\n"), verifications_of(np);
    if (a.timing_alternate && np > 1) {
      TimingRotation rotation(np);
      std::vector<PresetResult> out(np);
      std::vector<std::exception_ptr> errors(np);
      std::vector<std::thread> threads;
      auto join_all = [&] {
        for (auto& t : threads) t.join();
      };
      for (size_t k = 0; k < np; ++k) {
        try {
          threads.emplace_back([&, k] {
            try {
              if (!rotation.Begin(k)) return;
              out[k] = EvalPreset(a, presets[k], ds, splits, &rankings_of[k], &poses_of[k],
                                  &verifications_of[k], &rotation, k);
              rotation.Finish(k);
            } catch (const TimingRotation::Abandoned&) {
            } catch (...) {
              errors[k] = std::current_exception();
              rotation.Fail();
            }
          });
        } catch (...) {  // the system refused a thread: stop the ones started
          rotation.Fail();
          join_all();
          throw;
        }
      }
      std::exception_ptr timing_error;
      try {
        rotation.Run(a.quiet);
      } catch (...) {
        timing_error = std::current_exception();
      }
      join_all();
      for (const auto& e : errors) {
        if (e) std::rethrow_exception(e);
      }
      if (timing_error) std::rethrow_exception(timing_error);
      results = std::move(out);
    } else {
      for (size_t k = 0; k < np; ++k) {
        results.push_back(EvalPreset(a, presets[k], ds, splits, &rankings_of[k], &poses_of[k],
                                     &verifications_of[k]));
      }
    }
    for (size_t k = 0; k < np; ++k) {
      const std::string& p = presets[k];
      std::string& rankings = rankings_of[k];
      std::string& poses = poses_of[k];
      verifications += verifications_of[k];
      results[k].table_row = rows[k];
      // One file per preset: FILE itself for a single preset, FILE.<preset>.csv otherwise.
      auto target = [&](const std::string& file) {
        if (presets.size() == 1) return file;
        fs::path f(file);
        return (f.parent_path() /
                (f.stem().string() + "." + fs::path(p).stem().string() + f.extension().string()))
            .string();
      };
      if (!a.dump_rankings.empty())
        dumps.emplace_back(target(a.dump_rankings), std::move(rankings));
      if (!a.dump_poses.empty()) dumps.emplace_back(target(a.dump_poses), std::move(poses));
    }
    WriteFileAtomic(staging / "results.json", ToJson(a, ds, results));
    const std::string md = ToMarkdown(a, results);
    WriteFileAtomic(staging / "summary.md", md);
    WriteFileAtomic(staging / "verifications.csv", verifications);
    for (const auto& [path, text] : dumps) WriteFileAtomic(path, text);
    CommitStagedDirectory(staging, a.out);
    std::printf("%s", md.c_str());
  } catch (...) {
    DiscardStagedDirectory(staging);
    throw;
  }
  if (!a.no_plots) {
    const std::string cmd = "/usr/bin/python3 " GTBOW_SCRIPTS_DIR "/plot_eval.py '" +
                            (fs::path(a.out) / "results.json").string() + "' '" + a.out + "'";
    if (std::system(cmd.c_str()) != 0) {
      std::fprintf(stderr, "plots: %s failed (results.json and summary.md are written)\n",
                   cmd.c_str());
    }
  }
  std::printf("Results in %s: results.json, summary.md%s\n", a.out.c_str(),
              a.no_plots ? "" : ", *.png");
}

}  // namespace

void RegisterEval(CLI::App& app) {
  auto a = std::make_shared<EvalArgs>();
  CLI::App* cmd = app.add_subcommand(
      "eval", "Every metric of the evaluation protocol: retrieval, localization and timing");
  cmd->add_option("--dataset", a->dataset,
                  "Dataset (docs/DATASET_FORMAT.md) with database and query splits")
      ->required();
  cmd->add_option("--vocab", a->vocab,
                  "Vocabulary file (default: train on the dataset's train split)");
  cmd->add_option("--preset", a->presets,
                  "Retrieval configuration YAML (repeatable); default: high accuracy");
  cmd->add_option("-o,--out", a->out,
                  "Output directory (results.json, summary.md, plots); an earlier run's results "
                  "are replaced, any other non-empty directory is refused")
      ->capture_default_str();
  cmd->add_option("--query-splits", a->query_splits, "Query splits (default: every query* split)")
      ->delimiter(',');
  cmd->add_option("--max-queries", a->max_queries,
                  "At most this many queries per split (evenly spread)");
  cmd->add_option("--timing-queries", a->timing_queries,
                  "Random queries timed against the full database")
      ->capture_default_str();
  cmd->add_flag("--timing-alternate", a->timing_alternate,
                "With several presets, time them side by side: each timed query runs through "
                "every preset in turn, the order rotating, so that a change in the machine's "
                "speed falls on every preset alike (every preset's map is kept in memory)");
  cmd->add_flag("--timing-in-order", a->timing_in_order,
                "Time the first --timing-queries queries in the splits' order (a drive's images "
                "as a stream: an escalating preset's backoff) instead of a random sample");
  cmd->add_option("--timing-kernels", a->timing_kernels,
                  "Also time each of these SIMD kernels (portable, popcnt, avx2, avx512, neon) "
                  "on every timed query, side by side (a kernel the CPU lacks runs the next one "
                  "down)")
      ->check([](const std::string& name) {
        const std::string before = SimdLimit();
        if (!SetSimdLimit(name)) return std::string("not a SIMD kernel of this build: ") + name;
        SetSimdLimit(before);
        return std::string();
      });
  cmd->add_option("--candidates", a->candidates,
                  "K: retrieved images verified by pose estimation (default: the preset's "
                  "verification.candidates)");
  cmd->add_option("--min-inliers", a->min_inliers,
                  "Inliers a pose needs (default: the preset's verification.min_inliers)");
  cmd->add_option("--sequence", a->sequence,
                  "Sequence queries: each query with this many images in all, itself and the "
                  "nearest of its trail (gtbow synth --query-trail), combined through their "
                  "odometry as the node's localization does; 1 = single images")
      ->check(CLI::Range(1, 20))
      ->capture_default_str();
  cmd->add_option("--maintain", a->maintain,
                  "A maintained map: these splits (a robot's sessions, in order; gtbow synth "
                  "--session-days) localize against the map first and keep it up as the node's "
                  "maintenance mode does; the query splits then query the maintained map")
      ->delimiter(',');
  cmd->add_option("--maintain-refresh", a->maintenance.refresh_below_inliers,
                  "Maintenance: a fix with fewer inliers adds its view as a keyframe")
      ->capture_default_str();
  cmd->add_option("--maintain-min-inliers", a->maintenance.min_inliers,
                  "Maintenance: inliers a fix needs to place a keyframe")
      ->capture_default_str();
  cmd->add_option("--maintain-max-theta-sigma", a->maintenance.max_theta_sigma,
                  "Maintenance: radians of rotation uncertainty a fix may have to place a keyframe")
      ->capture_default_str();
  cmd->add_option("--maintain-views", a->maintenance.max_views_per_place,
                  "Maintenance: maintained views a place keeps (besides the map's own keyframes)")
      ->capture_default_str();
  cmd->add_option("--sequence-max-span", a->sequence_max_span,
                  "With --sequence, metres of odometry a trail image may lie from its query to be "
                  "combined (the node's ~sequence_max_span); a query with none is localized alone")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd->add_flag("--sequence-always", a->sequence_always,
                "With --sequence, localize from the combined view only (the node's "
                "~sequence_single_first false), not the query alone first");
  cmd->add_option("-j,--threads", a->threads,
                  "Threads for extraction and evaluation, 0 = all cores (timing uses one)");
  cmd->add_option("--cache", a->cache, "Feature and vocabulary cache directory")
      ->capture_default_str();
  cmd->add_flag("--no-cache", a->no_cache, "Neither read nor write the cache");
  cmd->add_flag("--no-plots", a->no_plots, "Skip the PNG plots");
  cmd->add_option("--words", a->words,
                  "Override V of AKM vocabularies trained here (small datasets)");
  cmd->add_flag("--ablation", a->ablation,
                "Run the paper's Table I rows (presets under config/ and config/ablation/)");
  cmd->add_option("--dump-rankings", a->dump_rankings,
                  "CSV of every query's ranked results (query,rank,image,score; top 1000)");
  cmd->add_option(
      "--dump-poses", a->dump_poses,
      "CSV of every query's estimated pose (query,x,y,theta,inliers; empty pose: no estimate)");
  cmd->add_flag("--exact-keypoints", a->exact_keypoints,
                "Verify against the map images' keypoints unquantised (the node's map stores "
                "them quantised; this measures what that costs)");
  cmd->add_flag("-q,--quiet", a->quiet, "No progress bars");
  cmd->callback([a]() { RunEval(*a); });
}

}  // namespace tools
}  // namespace gtbow
