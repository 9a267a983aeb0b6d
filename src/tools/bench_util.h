// Helpers shared by the benchmarks (gtbow bench, gtbow bench-map): the process's resident
// memory, a file dropped from the page cache (cold loads), byte counts for people, and checks
// made before hours of work.
#pragma once

#include <fcntl.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/eval/dataset.h"

namespace gtbow {
namespace tools {

// A size field of /proc/self/status ("VmRSS:", say), bytes; 0 when missing.
inline size_t StatusBytes(const std::string& field) {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind(field, 0) == 0) return std::stoull(line.substr(field.size())) * 1024;
  }
  return 0;
}

// Resident set of this process, bytes.
inline size_t ResidentBytes() { return StatusBytes("VmRSS:"); }

// The largest resident set since ResetPeakResident() (or since the start), bytes.
inline size_t PeakResidentBytes() { return StatusBytes("VmHWM:"); }

// Restarts PeakResidentBytes() at the current resident set; false when the kernel refuses
// (before Linux 4.0).
inline bool ResetPeakResident() {
  std::ofstream f("/proc/self/clear_refs");
  f << "5";
  f.flush();
  return static_cast<bool>(f);
}

// Drops a file's pages from the page cache (clean pages only: the file must have been fsynced).
inline bool EvictFromPageCache(const std::filesystem::path& p) {
  const int fd = ::open(p.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return false;
  const bool ok = ::posix_fadvise(fd, 0, 0, POSIX_FADV_DONTNEED) == 0;
  ::close(fd);
  return ok;
}

inline std::string Human(double bytes) {
  char b[32];
  if (bytes >= 1e9) {
    std::snprintf(b, sizeof(b), "%.2f GB", bytes / 1e9);
  } else {
    std::snprintf(b, sizeof(b), "%.1f MB", bytes / 1e6);
  }
  return b;
}

// Creates `dir` and writes a file there: fails now, not after an hour, when the results cannot
// be written. The error names `option` (the command-line option giving the directory).
inline void CheckWritableDirectory(const std::filesystem::path& dir, const std::string& option) {
  try {
    std::filesystem::create_directories(dir);
    WriteFileAtomic(dir / ".write_test", "");
    std::filesystem::remove(dir / ".write_test");
  } catch (const std::exception& e) {
    throw std::runtime_error(option + " " + dir.string() + " is not writable: " + e.what());
  }
}

// Writes `name`.json and `name`.md atomically into `out`, prints the Markdown, and unless
// `no_plot` draws `name`.png with scripts/`plot_script` (a failed plot is reported, not fatal).
inline void WriteBenchResults(const std::filesystem::path& out, const std::string& name,
                              const std::string& json, const std::string& md,
                              const std::string& plot_script, bool no_plot) {
  WriteFileAtomic(out / (name + ".json"), json);
  WriteFileAtomic(out / (name + ".md"), md);
  std::fputs(md.c_str(), stdout);
  if (!no_plot) {
    const std::string cmd = "/usr/bin/python3 " GTBOW_SCRIPTS_DIR "/" + plot_script + " '" +
                            (out / (name + ".json")).string() + "' '" +
                            (out / (name + ".png")).string() + "'";
    if (std::system(cmd.c_str()) != 0) std::fprintf(stderr, "plot: %s failed\n", cmd.c_str());
  }
  std::fprintf(stderr, "results in %s: %s.json, %s.md%s\n", out.c_str(), name.c_str(), name.c_str(),
               no_plot ? "" : (", " + name + ".png").c_str());
}

// The dataset's first query split (sequences/query*.txt), "" when it has none.
inline std::string FirstQuerySplit(const Dataset& ds) {
  for (const auto& s : ds.SplitNames()) {
    if (s.rfind("query", 0) == 0) return s;
  }
  return "";
}

}  // namespace tools
}  // namespace gtbow
