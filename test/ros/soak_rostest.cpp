// soak.test (Soak.*): `make soak`, and 60 s under ThreadSanitizer in make test-sanitize.
#include <list>

#include "rostest_util.h"

namespace {

using namespace rostest_util;

// ---------------------------------------------------------------------------------------------
// Soak (test/ros/soak.test, `make soak`; 60 s under TSan in CI): rosbag play --loop --rate 4 feeds
// the nodelet in mapping mode for ~seconds while this process calls every read service and save_map
// concurrently. Passes when the manager never dies, no call fails or hangs, images keep being
// processed, and the manager's memory grows no more than the map does.

// The resident set of the process whose command line holds `needle` (0 when none).
pid_t FindProcess(const std::string& needle) {
  for (const auto& e : fs::directory_iterator("/proc")) {
    const std::string name = e.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream f(e.path() / "cmdline", std::ios::binary);
    std::string cmd((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    std::replace(cmd.begin(), cmd.end(), '\0', ' ');
    if (cmd.find(needle) != std::string::npos &&
        cmd.find("localizer_rostest") == std::string::npos &&
        cmd.find("localizer_soak_rostest") == std::string::npos) {
      return static_cast<pid_t>(std::stol(name));
    }
  }
  return 0;
}

double RssMb(pid_t pid) {
  std::ifstream f("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  }
  return -1.0;
}

struct CallStats {
  std::string name;
  std::atomic<uint64_t> calls{0}, failures{0};
  std::atomic<double> max_ms{0.0};
  std::atomic<double> last_done{0.0};  // wall seconds
  std::vector<double> ms;              // every latency (one writer)
  std::string last_failure;
};

// A persistent connection to a service, as a SLAM backend keeps one (a fresh connection per
// call asks the master each time). A failed call is reported and the connection remade.
template <typename Srv>
class Client {
 public:
  explicit Client(std::string name) : name_(std::move(name)) { Connect(); }
  bool Call(Srv& srv) {
    if (client_.call(srv)) return true;
    Connect();
    return false;
  }

 private:
  void Connect() {
    ros::service::waitForService(name_, ros::Duration(5));
    client_ = ros::NodeHandle().serviceClient<Srv>(name_, true);
  }
  std::string name_;
  ros::ServiceClient client_;
};

constexpr uint64_t kMinCalls = 10;      // calls of each read service, at least
constexpr double kHungSeconds = 120.0;  // one call unanswered this long: a deadlock

TEST(Soak, ReplayAtFourTimesRealTimeWithConcurrentServiceCalls) {
  ros::NodeHandle pnh("~");
  double seconds = 600, save_every = 30;
  bool check_memory = true;  // off under ThreadSanitizer, whose shadow memory swamps the RSS
  std::string out = "/tmp/gtbow_soak";
  pnh.param("seconds", seconds, seconds);
  pnh.param("save_every", save_every, save_every);
  pnh.param("check_memory", check_memory, check_memory);
  pnh.param("out", out, out);
  fs::create_directories(out);
  ASSERT_TRUE(ros::service::waitForService("/localizer/get_info", ros::Duration(60)));
  const pid_t manager = FindProcess("__name:=localizer_manager");
  ASSERT_GT(manager, 0) << "no localizer_manager process";
  const auto probes = ReadBag(g_data + "/localization.bag");
  ASSERT_FALSE(probes.empty());
  const auto wall = [] { return ros::WallTime::now().toSec(); };
  const double t0 = wall();
  std::atomic<bool> stop{false};

  CallStats query, by_id, localize, info_stats, save;
  query.name = "query_candidates (image, k=5, verified)";
  by_id.name = "query_candidates (keyframe id)";
  localize.name = "localize";
  info_stats.name = "get_info";
  save.name = "save_map (every " + std::to_string(static_cast<int>(save_every)) + " s)";
  auto record = [&](CallStats& st, double start, bool ok, const std::string& why) {
    const double ms = 1000.0 * (wall() - start);
    st.calls++;
    st.ms.push_back(ms);
    if (ms > st.max_ms) st.max_ms = ms;
    if (!ok) {
      st.failures++;
      st.last_failure = why.empty() ? "the call itself failed (connection)" : why;
    }
    st.last_done = wall();
  };
  // A list: no thread is moved (a vector's growth gave GCC 12 a false -Warray-bounds).
  std::list<std::thread> callers;
  callers.emplace_back([&] {
    Client<ground_texture_bow::QueryCandidates> client("/localizer/query_candidates");
    for (size_t i = 0; !stop; ++i) {
      ground_texture_bow::QueryCandidates q;
      q.request.image = *probes[i % probes.size()].image;
      q.request.k = 5;
      q.request.verify = true;
      const double s0 = wall();
      const bool ok = client.Call(q);
      record(query, s0, ok && q.response.status.code == Status::OK, q.response.status.message);
    }
  });
  callers.emplace_back([&] {
    std::mt19937 rng(1);
    Client<ground_texture_bow::GetInfo> info_client("/localizer/get_info");
    Client<ground_texture_bow::QueryCandidates> client("/localizer/query_candidates");
    while (!stop) {
      ground_texture_bow::GetInfo gi;
      info_client.Call(gi);
      ground_texture_bow::QueryCandidates q;
      q.request.use_keyframe_id = true;
      q.request.keyframe_id = gi.response.database_size > 0 ? rng() % gi.response.database_size : 0;
      q.request.k = 5;
      q.request.verify = true;
      const double s0 = wall();
      const bool ok = client.Call(q);
      // NOT_FOUND only for an empty map.
      record(
          by_id, s0,
          ok && (q.response.status.code == Status::OK ||
                 (gi.response.database_size == 0 && q.response.status.code == Status::NOT_FOUND)),
          q.response.status.message);
    }
  });
  callers.emplace_back([&] {
    Client<ground_texture_bow::Localize> client("/localizer/localize");
    for (size_t i = 0; !stop; ++i) {
      ground_texture_bow::Localize l;
      l.request.image = *probes[(i * 7) % probes.size()].image;
      const double s0 = wall();
      const bool ok = client.Call(l);
      // NOT_FOUND: answered, but no candidate verified (a fix needs posed keyframes nearby).
      record(localize, s0,
             ok && (l.response.status.code == Status::OK ||
                    l.response.status.code == Status::NOT_FOUND),
             l.response.status.message);
    }
  });
  callers.emplace_back([&] {
    Client<ground_texture_bow::GetInfo> client("/localizer/get_info");
    while (!stop) {
      ground_texture_bow::GetInfo gi;
      const double s0 = wall();
      const bool ok = client.Call(gi);
      record(info_stats, s0, ok && gi.response.status.code == Status::OK,
             gi.response.status.message);
      ros::WallDuration(0.1).sleep();
    }
  });
  callers.emplace_back([&] {
    double next = wall() + save_every;
    save.last_done = wall();
    Client<ground_texture_bow::SaveMap> client("/localizer/save_map");
    while (!stop) {
      if (wall() < next) {
        ros::WallDuration(0.2).sleep();
        save.last_done = wall();  // idle is not hung
        continue;
      }
      next += save_every;
      ground_texture_bow::SaveMap sm;
      sm.request.path = out + "/soak.gtmap";
      const double s0 = wall();
      const bool ok = client.Call(sm);
      record(save, s0, ok && sm.response.status.code == Status::OK, sm.response.status.message);
    }
  });

  // Every second: the manager's memory and the node's counters.
  struct Sample {
    double t, rss_mb;
    uint32_t keyframes;
    uint64_t received, processed, dropped, rejected;
  };
  std::vector<Sample> samples;
  bool hung = false, died = false;
  // Runs for `seconds`, and on until every caller has its calls counted below and one save has
  // been answered: a slow machine (ThreadSanitizer on a busy CI runner) takes longer, it does not
  // fail. A call unanswered for kHungSeconds is a deadlock; the rostest time-limit bounds the rest.
  const auto counted = [&] {
    for (CallStats* st : {&query, &by_id, &localize, &info_stats}) {
      if (st->calls <= kMinCalls) return false;
    }
    return save.calls >= 1;
  };
  while (wall() - t0 < seconds || !counted()) {
    ros::WallDuration(1.0).sleep();
    const double now = wall();
    if (::kill(manager, 0) != 0) {
      died = true;
      break;
    }
    for (CallStats* st : {&query, &by_id, &localize, &info_stats, &save}) {
      if (st->last_done > 0 && now - st->last_done > kHungSeconds) {
        ADD_FAILURE() << st->name << ": no answer for " << kHungSeconds << " s (deadlock?)";
        hung = true;
      }
    }
    if (hung) break;
    ground_texture_bow::GetInfo gi;
    if (!ros::service::call("/localizer/get_info", gi)) continue;
    const auto& r = gi.response;
    samples.push_back({now - t0, RssMb(manager), r.database_size, r.images_received,
                       r.images_processed, r.images_dropped, r.images_rejected});
    if (samples.size() % 60 == 0) {
      std::printf("soak %4.0f s: %u keyframes, %llu images processed, RSS %.0f MB\n", now - t0,
                  r.database_size, static_cast<unsigned long long>(r.images_processed),
                  samples.back().rss_mb);
      std::fflush(stdout);
    }
  }
  stop = true;
  if (hung || died) {
    ADD_FAILURE() << (died ? "the nodelet manager died" : "a service hung");
    std::fflush(nullptr);
    std::_Exit(1);  // a hung call cannot be joined
  }
  for (auto& th : callers) th.join();
  ASSERT_GE(samples.size(), 10u);

  // The map at the end, and memory growth against map growth after a one-minute warm-up.
  ground_texture_bow::SaveMap final_save;
  final_save.request.path = out + "/soak.gtmap";
  ASSERT_EQ(Call("/localizer/save_map", final_save).response.status.code, Status::OK);
  const double map_mb = static_cast<double>(fs::file_size(out + "/soak.gtmap")) / (1024.0 * 1024.0);
  const Sample& last = samples.back();
  const Sample& warm = *std::find_if(samples.begin(), samples.end(), [&](const Sample& s) {
    return s.t >= std::min(60.0, seconds / 4);
  });
  const double map_growth_mb =
      map_mb * (last.keyframes - warm.keyframes) / std::max<uint32_t>(last.keyframes, 1);
  const double rss_growth_mb = last.rss_mb - warm.rss_mb;
  double peak = 0;
  for (const Sample& s : samples) peak = std::max(peak, s.rss_mb);
  const double allowed_mb = 2.0 * map_growth_mb + 64.0;
  if (check_memory) {
    EXPECT_LE(rss_growth_mb, allowed_mb)
        << "memory grew " << rss_growth_mb << " MB while the map grew " << map_growth_mb << " MB";
  }
  // Images kept flowing: every minute saw processing.
  for (size_t i = 60; i < samples.size(); i += 60) {
    EXPECT_GT(samples[i].processed, samples[i - 60].processed)
        << "no image processed in minute " << i / 60;
  }
  for (CallStats* st : {&query, &by_id, &localize, &info_stats}) {
    EXPECT_GT(st->calls, kMinCalls) << st->name;
  }
  for (CallStats* st : {&query, &by_id, &localize, &info_stats, &save}) {
    EXPECT_EQ(st->failures, 0u) << st->name << ": " << st->last_failure;
  }

  // Results for docs/RESULTS.md (scripts/write_soak.py).
  auto pct = [](std::vector<double> v, double p) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, static_cast<size_t>(p * (v.size() - 1) + 0.5))];
  };
  std::ofstream js(out + "/soak.json");
  js << "{\n  \"seconds\": " << (last.t)
     << ",\n  \"rate\": 4,\n  \"images_received\": " << last.received
     << ",\n  \"images_processed\": " << last.processed
     << ",\n  \"images_dropped\": " << last.dropped << ",\n  \"images_rejected\": " << last.rejected
     << ",\n  \"keyframes\": " << last.keyframes << ",\n  \"map_mb\": " << map_mb
     << ",\n  \"rss_warm_mb\": " << warm.rss_mb << ",\n  \"rss_end_mb\": " << last.rss_mb
     << ",\n  \"rss_peak_mb\": " << peak << ",\n  \"rss_growth_mb\": " << rss_growth_mb
     << ",\n  \"map_growth_mb\": " << map_growth_mb << ",\n  \"allowed_growth_mb\": " << allowed_mb
     << ",\n  \"warmup_s\": " << warm.t << ",\n  \"services\": [\n";
  bool first = true;
  for (CallStats* st : {&query, &by_id, &localize, &info_stats, &save}) {
    js << (first ? "" : ",\n") << "    {\"name\": \"" << st->name << "\", \"calls\": " << st->calls
       << ", \"failures\": " << st->failures << ", \"median_ms\": " << pct(st->ms, 0.5)
       << ", \"p99_ms\": " << pct(st->ms, 0.99) << ", \"max_ms\": " << st->max_ms.load() << "}";
    first = false;
  }
  js << "\n  ],\n  \"samples\": [\n";
  for (size_t i = 0; i < samples.size(); ++i) {
    const Sample& s = samples[i];
    js << "    [" << s.t << ", " << s.rss_mb << ", " << s.keyframes << ", " << s.processed << ", "
       << s.dropped << "]" << (i + 1 < samples.size() ? ",\n" : "\n");
  }
  js << "  ]\n}\n";
  uint64_t failed = 0;
  for (CallStats* st : {&query, &by_id, &localize, &info_stats, &save}) failed += st->failures;
  std::printf(
      "soak: %.0f s, %llu images processed, %u keyframes (map %.1f MB), RSS %.0f -> %.0f MB "
      "(growth %.1f MB, allowed %.1f MB), %llu + %llu + %llu + %llu service calls, %llu failed\n",
      last.t, static_cast<unsigned long long>(last.processed), last.keyframes, map_mb, warm.rss_mb,
      last.rss_mb, rss_growth_mb, allowed_mb, static_cast<unsigned long long>(query.calls.load()),
      static_cast<unsigned long long>(by_id.calls.load()),
      static_cast<unsigned long long>(localize.calls.load()),
      static_cast<unsigned long long>(info_stats.calls.load()),
      static_cast<unsigned long long>(failed));
}

}  // namespace
