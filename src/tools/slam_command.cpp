// gtbow slam: the localizer node's mapping pipeline (gtbow::Mapper) and the pose-graph backend
// (gtbow::backend::PoseGraph) over a recorded drive, offline: the drive split of a dataset in
// order, its wheel odometry (drive_odometry.csv, the camera footprint), each image stamped as
// gtbow_images_to_bag stamps it (--start + index / --rate), so that the node replaying that
// bag sees the same input. Writes the loop closures, the trajectory (odometry, optimised,
// ground truth), the keyframes, ATE and closure precision/recall (summary.json, summary.md),
// a plot, and a map whose keyframes carry the optimised poses.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "commands.h"
#include "ground_texture_bow/backend/pose_graph.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/mapper.h"
#include "ground_texture_bow/core/progress.h"
#include "ground_texture_bow/core/simd.h"
#include "ground_texture_bow/eval/dataset.h"
#include "image_source.h"
#include "json_writer.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace tools {

namespace {

constexpr double kMaxPositionM = 0.0048;             // a closure is wrong beyond 4.8 mm ...
constexpr double kMaxHeadingRad = 1.5 * M_PI / 180;  // ... or 1.5 degrees (as gtbow eval)

struct SlamArgs {
  std::string dataset;
  std::string split = "drive";
  std::string odometry;  // default: DATASET/drive_odometry.csv
  std::string vocab;
  std::string preset;
  std::string params = ConfigFile("localizer.yaml");
  std::string backend = ConfigFile("backend.yaml");
  std::string out = "gtbow_slam";
  std::string map_frame = "map";  // the frame the saved map's poses are in
  double start = 1000.0;          // s: the first image's stamp
  double rate = 10.0;             // images per second
  int exclude_recent = -1, temporal_consistency = -1;
  double optimize_every = 1.0;  // s of drive between optimisations (the backend's timer)
  std::string cache = DefaultCacheDir().string();
  bool no_cache = false;
  bool no_plots = false;
  bool quiet = false;
};

// The node's parameters that shape mapping, from a ROS parameter file (config/localizer.yaml).
void ReadParams(const std::string& path, MapperOptions* m, LocalizerOptions* lo) {
  const YAML::Node y = YAML::LoadFile(path);
  auto get = [&](const char* key, auto* value) {
    if (y[key]) *value = y[key].as<std::decay_t<decltype(*value)>>();
  };
  get("keyframe_min_distance", &m->keyframe_min_distance);
  get("keyframe_min_angle", &m->keyframe_min_angle);
  get("keyframe_every_n", &m->keyframe_every_n);
  get("exclude_recent", &m->exclude_recent);
  get("temporal_consistency", &m->temporal.required);
  get("temporal_distance", &m->temporal.distance);
  get("temporal_angle", &m->temporal.angle);
  get("temporal_max_motion", &m->temporal.max_motion);
  get("keep_descriptors", &lo->keep_descriptors);
  int candidates = 0, min_inliers = 0;
  get("candidates", &candidates);
  get("min_inliers", &min_inliers);
  if (candidates > 0) lo->retrieval.verification.candidates = candidates;
  if (min_inliers > 0) lo->retrieval.verification.pose.min_inliers = min_inliers;
}

// The backend's parameters (config/backend.yaml; the pose_graph_backend node's names).
backend::PoseGraphOptions ReadBackend(const std::string& path) {
  backend::PoseGraphOptions o;
  const YAML::Node y = YAML::LoadFile(path);
  auto get = [&](const char* key, auto* value) {
    if (y[key]) *value = y[key].as<std::decay_t<decltype(*value)>>();
  };
  get("odom_sigma_xy", &o.odom_sigma_xy);
  get("odom_sigma_theta", &o.odom_sigma_theta);
  get("odom_sigma_turn", &o.odom_sigma_turn);
  get("closure_min_sigma_xy", &o.closure_min_sigma_xy);
  get("closure_min_sigma_theta", &o.closure_min_sigma_theta);
  get("loss", &o.loss);
  get("loss_scale", &o.loss_scale);
  get("consistency_check", &o.consistency_check);
  get("consistency_window", &o.consistency_window);
  get("consistency_chi2", &o.consistency_chi2);
  get("max_iterations", &o.max_iterations);
  o.Check();
  return o;
}

struct Errors {
  double rmse = 0, max = 0;
  size_t n = 0;
  void Add(const Pose2D& a, const Pose2D& b) {
    const double e = std::hypot(a.x - b.x, a.y - b.y);
    rmse += e * e;
    max = std::max(max, e);
    ++n;
  }
  void Finish() { rmse = n ? std::sqrt(rmse / static_cast<double>(n)) : 0.0; }
};

const char* StateName(backend::ClosureState s) {
  switch (s) {
    case backend::ClosureState::kAccepted:
      return "accepted";
    case backend::ClosureState::kPending:
      return "pending";
    case backend::ClosureState::kRejected:
      return "rejected";
  }
  return "?";
}

std::string Num(double v) {
  char b[32];
  std::snprintf(b, sizeof(b), "%.9g", v);
  return b;
}

void RunSlam(const SlamArgs& a) {
  const auto t_start = std::chrono::steady_clock::now();
  if (!(a.rate > 0)) throw std::invalid_argument("--rate must be > 0");
  const Dataset ds = Dataset::Load(a.dataset);
  const std::vector<std::string> names = ds.Split(a.split);
  if (names.size() < 2)
    throw std::invalid_argument("split '" + a.split + "' has fewer than 2 images");
  const fs::path odom_path =
      a.odometry.empty() ? fs::path(a.dataset) / "drive_odometry.csv" : fs::path(a.odometry);
  std::map<std::string, Pose2D> odom;
  {
    std::ifstream f(odom_path);
    if (!f) throw std::runtime_error("cannot read the odometry " + odom_path.string());
    std::stringstream text;
    text << f.rdbuf();
    for (const PoseRecord& r : ParsePosesCsv(text.str(), odom_path.string()))
      odom[r.image] = r.pose;
  }
  for (const auto& n : names) {
    if (!odom.count(n)) throw std::invalid_argument(odom_path.string() + " has no pose for " + n);
  }

  RetrievalConfig config =
      LoadRetrievalConfig(a.preset.empty() ? ConfigFile("high_accuracy.yaml") : a.preset);
  LocalizerOptions lo;
  lo.retrieval = config;
  lo.meters_per_pixel = ds.info().geometry.meters_per_pixel;
  lo.threads = 1;
  MapperOptions mo;
  ReadParams(a.params, &mo, &lo);
  if (a.exclude_recent >= 0) mo.exclude_recent = a.exclude_recent;
  if (a.temporal_consistency >= 0) mo.temporal.required = a.temporal_consistency;
  const backend::PoseGraphOptions po = ReadBackend(a.backend);

  VocabularyRequest vr;
  vr.file = a.vocab;
  vr.dataset = a.dataset;
  vr.cache = a.no_cache ? fs::path() : fs::path(a.cache);
  vr.progress = !a.quiet;
  std::string vocab_desc;
  std::shared_ptr<Vocabulary> vocab = DatasetVocabulary(vr, config, &vocab_desc);
  const std::string vocab_path = a.vocab.empty() ? "(trained on " + a.dataset + ")" : a.vocab;
  Localizer loc(vocab, vocab_path, lo);
  Mapper mapper(&loc, mo);
  backend::PoseGraph graph(po);

  struct KeyframeOf {
    uint32_t id;
    size_t image;
    int64_t stamp;
  };
  std::vector<KeyframeOf> keyframes;
  struct ClosureRow {
    size_t query_image;
    uint32_t match_id;
    float score;
    int inliers;
    Pose2D relative;
    size_t graph_id;
  };
  std::vector<ClosureRow> closures;
  std::vector<int64_t> stamps(names.size());
  const int64_t start_ns = static_cast<int64_t>(std::llround(a.start * 1e9));
  int64_t next_optimize = start_ns;
  ProgressBar bar("slam", names.size(), !a.quiet);
  for (size_t i = 0; i < names.size(); ++i) {
    stamps[i] =
        start_ns + static_cast<int64_t>(std::llround(static_cast<double>(i) / a.rate * 1e9));
    const Pose2D& o = odom.at(names[i]);
    graph.AddOdometry(stamps[i], o);
    ProcessedImage img = loc.Process(ds.LoadGray(names[i]));
    const MapperStep step = mapper.Process(img, stamps[i], o);
    if (step.keyframe) keyframes.push_back({*step.keyframe, i, stamps[i]});
    if (step.closure >= 0 && step.publish) {
      const Candidate& c = step.candidates[static_cast<size_t>(step.closure)];
      backend::Closure bc;
      bc.match_ns = c.stamp_ns;
      bc.query_ns = stamps[i];
      bc.match_from_query = c.relative.floor_from_query;
      bc.covariance = c.relative.covariance;
      graph.AddClosure(bc);
      closures.push_back({i, c.id, c.score, c.relative.inliers, c.relative.floor_from_query,
                          graph.closures_added() - 1});
    }
    if (stamps[i] >= next_optimize) {
      graph.Optimize();
      next_optimize = stamps[i] + static_cast<int64_t>(a.optimize_every * 1e9);
    }
    bar.Add();
  }
  bar.Finish();
  const backend::SolveReport solve = graph.Optimize();

  // Ground truth, where the dataset has it for every drive image.
  bool has_truth = true;
  for (const auto& n : names) has_truth = has_truth && ds.HasImage(n);
  auto truth = [&](size_t i) { return ds.PoseOf(names[i]); };

  fs::create_directories(a.out);
  // The trajectory.
  std::string traj = "image,stamp,odom_x,odom_y,odom_theta,x,y,theta,true_x,true_y,true_theta\n";
  Errors ate_odom, ate_opt, kf_odom, kf_opt;
  for (size_t i = 0; i < names.size(); ++i) {
    const Pose2D& o = odom.at(names[i]);
    const Pose2D p = graph.PoseAt(stamps[i]);
    traj += names[i] + "," + Num(stamps[i] * 1e-9) + "," + Num(o.x) + "," + Num(o.y) + "," +
            Num(o.theta) + "," + Num(p.x) + "," + Num(p.y) + "," + Num(p.theta);
    if (has_truth) {
      const Pose2D t = truth(i);
      traj += "," + Num(t.x) + "," + Num(t.y) + "," + Num(t.theta);
      ate_odom.Add(o, t);
      ate_opt.Add(p, t);
    } else {
      traj += ",,,";
    }
    traj += "\n";
  }
  ate_odom.Finish();
  ate_opt.Finish();
  WriteFileAtomic(fs::path(a.out) / "trajectory.csv", traj);
  // The keyframes, and the map with their optimised poses: the mapper's own map, its keyframes
  // re-posed as the localizer node re-poses them from pose_graph_backend's keyframe_poses.
  std::string kfs = "id,image,stamp,odom_x,odom_y,odom_theta,x,y,theta,error_odom_mm,error_mm\n";
  std::vector<KeyframePose> moved;
  for (size_t k = 0; k < keyframes.size(); ++k) {
    const size_t i = keyframes[k].image;
    const Pose2D& o = odom.at(names[i]);
    const Pose2D p = graph.PoseAt(keyframes[k].stamp);
    moved.push_back({keyframes[k].id, keyframes[k].stamp, p});
    kfs += std::to_string(keyframes[k].id) + "," + names[i] + "," + Num(keyframes[k].stamp * 1e-9) +
           "," + Num(o.x) + "," + Num(o.y) + "," + Num(o.theta) + "," + Num(p.x) + "," + Num(p.y) +
           "," + Num(p.theta);
    if (has_truth) {
      const Pose2D t = truth(i);
      kf_odom.Add(o, t);
      kf_opt.Add(p, t);
      kfs += "," + Num(1e3 * std::hypot(o.x - t.x, o.y - t.y)) + "," +
             Num(1e3 * std::hypot(p.x - t.x, p.y - t.y));
    } else {
      kfs += ",,";
    }
    kfs += "\n";
  }
  kf_odom.Finish();
  kf_opt.Finish();
  WriteFileAtomic(fs::path(a.out) / "keyframes.csv", kfs);
  if (loc.UpdateKeyframePoses(moved) != moved.size()) {
    throw std::logic_error("gtbow slam: the map did not take every optimised keyframe pose");
  }
  loc.SetPoseFrame(a.map_frame);
  const fs::path map_path = fs::path(a.out) / "map.gtmap";
  loc.Save(map_path, /*paced=*/false);
  // The closures: correct when the match keyframe's true pose composed with the relative pose
  // is the query's true pose within 4.8 mm and 1.5 degrees.
  std::string cl =
      "query_image,match_id,match_image,score,inliers,x,y,theta,state,error_mm,error_deg,correct\n";
  size_t correct = 0, accepted = 0, accepted_wrong = 0;
  for (const ClosureRow& c : closures) {
    const size_t mi = keyframes.at(c.match_id).image;
    const backend::ClosureState st = graph.State(c.graph_id);
    cl += names[c.query_image] + "," + std::to_string(c.match_id) + "," + names[mi] + "," +
          Num(c.score) + "," + std::to_string(c.inliers) + "," + Num(c.relative.x) + "," +
          Num(c.relative.y) + "," + Num(c.relative.theta) + "," + StateName(st);
    accepted += st == backend::ClosureState::kAccepted ? 1 : 0;
    if (has_truth) {
      const Pose2D implied = Compose(truth(mi), c.relative);
      const Pose2D t = truth(c.query_image);
      const double e = std::hypot(implied.x - t.x, implied.y - t.y);
      const double h = std::abs(WrapAngle(implied.theta - t.theta));
      const bool ok = e <= kMaxPositionM && h <= kMaxHeadingRad;
      correct += ok ? 1 : 0;
      accepted_wrong += (!ok && st == backend::ClosureState::kAccepted) ? 1 : 0;
      cl += "," + Num(1e3 * e) + "," + Num(h * 180 / M_PI) + "," + (ok ? "1" : "0");
    } else {
      cl += ",,,";
    }
    cl += "\n";
  }
  WriteFileAtomic(fs::path(a.out) / "closures.csv", cl);
  // Recall: of the images that revisit a keyframe older than the recent window (a keyframe
  // whose true centre is within a quarter of the image's smaller side), the share with a
  // published closure.
  size_t revisits = 0, revisits_closed = 0;
  if (has_truth) {
    const double reach =
        0.25 * lo.meters_per_pixel * std::min(ds.info().geometry.width, ds.info().geometry.height);
    std::vector<bool> closed(names.size(), false);
    for (const ClosureRow& c : closures) closed[c.query_image] = true;
    size_t kf_before = 0;  // keyframes added before image i
    for (size_t i = 0; i < names.size(); ++i) {
      while (kf_before < keyframes.size() && keyframes[kf_before].image < i) ++kf_before;
      const size_t usable = kf_before > static_cast<size_t>(mo.exclude_recent)
                                ? kf_before - static_cast<size_t>(mo.exclude_recent)
                                : 0;
      bool revisit = false;
      for (size_t k = 0; k < usable && !revisit; ++k) {
        const Pose2D t = truth(keyframes[k].image), q = truth(i);
        revisit = std::hypot(t.x - q.x, t.y - q.y) <= reach;
      }
      if (revisit) {
        ++revisits;
        revisits_closed += closed[i] ? 1 : 0;
      }
    }
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();

  Json j;
  j.Open('{');
  j.Key("dataset").Str(a.dataset).Key("split").Str(a.split);
  j.Key("images").Int(static_cast<long long>(names.size()));
  j.Key("keyframes").Int(static_cast<long long>(keyframes.size()));
  j.Key("vocabulary").Str(vocab_desc);
  j.Key("kernels").Str(ActiveSimdKernels());
  j.Key("exclude_recent").Int(mo.exclude_recent);
  j.Key("temporal_consistency").Int(mo.temporal.required);
  j.Key("ground_truth").Bool(has_truth);
  j.Key("closures").Open('{');
  j.Key("published").Int(static_cast<long long>(closures.size()));
  j.Key("correct").Int(static_cast<long long>(correct));
  j.Key("accepted").Int(static_cast<long long>(accepted));
  j.Key("accepted_wrong").Int(static_cast<long long>(accepted_wrong));
  j.Key("precision").Num(closures.empty() ? 1.0 : static_cast<double>(correct) / closures.size());
  j.Key("revisit_images").Int(static_cast<long long>(revisits));
  j.Key("recall").Num(revisits ? static_cast<double>(revisits_closed) / revisits : 0.0);
  j.Close('}');
  auto errors = [&](const char* key, const Errors& e) {
    j.Key(key).Open('{').Key("rmse_mm").Num(1e3 * e.rmse).Key("max_mm").Num(1e3 * e.max).Close('}');
  };
  j.Key("ate").Open('{');
  errors("odometry", ate_odom);
  errors("optimised", ate_opt);
  j.Close('}');
  j.Key("keyframe_error").Open('{');
  errors("odometry", kf_odom);
  errors("optimised", kf_opt);
  j.Close('}');
  j.Key("solve").Open('{').Key("iterations").Int(solve.iterations);
  j.Key("converged").Bool(solve.converged).Key("nodes").Int(static_cast<long long>(solve.nodes));
  j.Key("closure_edges").Int(static_cast<long long>(solve.closure_edges)).Close('}');
  j.Key("map").Str(map_path.string());
  j.Key("seconds").Num(seconds);
  j.Close('}');
  WriteFileAtomic(fs::path(a.out) / "summary.json", j.str());

  std::ostringstream md;
  md << "# gtbow slam: " << a.dataset << " (" << a.split << ")\n\n";
  md << names.size() << " images, " << keyframes.size() << " keyframes, " << closures.size()
     << " loop closures published (" << accepted << " accepted by the backend), " << seconds
     << " s; kernels: " << ActiveSimdKernels() << ".\n\n";
  if (has_truth) {
    char b[512];
    md << "| | odometry alone | optimised |\n| --- | --- | --- |\n";
    std::snprintf(b, sizeof(b),
                  "| trajectory ATE, RMSE / max | %.2f / %.2f mm | %.2f / %.2f mm |\n",
                  1e3 * ate_odom.rmse, 1e3 * ate_odom.max, 1e3 * ate_opt.rmse, 1e3 * ate_opt.max);
    md << b;
    std::snprintf(b, sizeof(b),
                  "| keyframe poses in the map, RMSE / max | %.2f / %.2f mm | %.2f / %.2f mm |\n\n",
                  1e3 * kf_odom.rmse, 1e3 * kf_odom.max, 1e3 * kf_opt.rmse, 1e3 * kf_opt.max);
    md << b;
    std::snprintf(b, sizeof(b),
                  "Closure precision %zu / %zu (within 4.8 mm and 1.5 degrees), %zu wrong ones "
                  "accepted; recall %zu / %zu revisiting images.\n",
                  correct, closures.size(), accepted_wrong, revisits_closed, revisits);
    md << b;
  }
  WriteFileAtomic(fs::path(a.out) / "summary.md", md.str());
  std::printf("%s", md.str().c_str());
  std::printf(
      "wrote %s (map with optimised keyframe poses), trajectory.csv, keyframes.csv, "
      "closures.csv, summary.json\n",
      map_path.string().c_str());
  if (!a.no_plots) {
    const std::string cmd = "/usr/bin/python3 " GTBOW_SCRIPTS_DIR "/plot_slam.py '" + a.out + "'";
    if (std::system(cmd.c_str()) != 0) std::fprintf(stderr, "gtbow slam: the plot failed\n");
  }
}

}  // namespace

void RegisterSlam(CLI::App& app) {
  auto a = std::make_shared<SlamArgs>();
  CLI::App* cmd = app.add_subcommand(
      "slam", "The node's mapping pipeline and the pose-graph backend over a recorded drive");
  cmd->add_option("--dataset", a->dataset, "Dataset with a drive split and its odometry")
      ->required();
  cmd->add_option("--split", a->split, "The drive's split")->capture_default_str();
  cmd->add_option("--odometry", a->odometry,
                  "Odometry CSV of the camera footprint (default: DATASET/drive_odometry.csv)");
  cmd->add_option("--vocab", a->vocab, "Vocabulary file (default: train on the train split)");
  cmd->add_option("--preset", a->preset, "Retrieval preset (default: high accuracy)");
  cmd->add_option("--params", a->params, "The localizer node's parameter file")
      ->capture_default_str();
  cmd->add_option("--backend", a->backend, "The backend's parameter file")->capture_default_str();
  cmd->add_option("--start", a->start, "Stamp of the first image, s (as gtbow_images_to_bag)")
      ->capture_default_str();
  cmd->add_option("--rate", a->rate, "Images per second (as gtbow_images_to_bag)")
      ->capture_default_str();
  cmd->add_option("--exclude-recent", a->exclude_recent, "Override ~exclude_recent");
  cmd->add_option("--temporal-consistency", a->temporal_consistency,
                  "Override ~temporal_consistency");
  cmd->add_option("-o,--out", a->out, "Output directory")->capture_default_str();
  cmd->add_option("--map-frame", a->map_frame,
                  "The frame the saved map records for its optimised poses (the backend's "
                  "~map_frame)")
      ->capture_default_str();
  cmd->add_option("--cache", a->cache, "Feature and vocabulary cache directory");
  cmd->add_flag("--no-cache", a->no_cache, "Neither read nor write the cache");
  cmd->add_flag("--no-plots", a->no_plots, "Skip the plot");
  cmd->add_flag("-q,--quiet", a->quiet, "No progress bars");
  cmd->callback([a] { RunSlam(*a); });
}

}  // namespace tools
}  // namespace gtbow
