// Helpers shared by the libFuzzer targets (test/fuzz/*_fuzzer.cpp) and their corpus replay.
//
// Every target defines LLVMFuzzerTestOneInput. Built with clang and -fsanitize=fuzzer it is a
// fuzzer (scripts/fuzz.sh, `make fuzz`); built with replay_main.cpp it is a gtest that runs
// every file of the target's corpus under test/fuzz/corpus (`make test`).
//
// The package's binary files carry checksums, which a mutated input almost never satisfies:
// a fuzzer would only ever test the checksum check. So inputs whose first byte is odd are
// "repaired" first (sizes and checksums recomputed, as a writer would), and reach the parser
// behind the checksum; inputs whose first byte is even are used as they are.
#pragma once

#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "ground_texture_bow/core/binary_io.h"

namespace gtbow {
namespace fuzz {

// Inputs the parser accepted and rejected (the replay checks that a corpus exercises both).
inline size_t& Accepted() {
  static size_t n = 0;
  return n;
}
inline size_t& Rejected() {
  static size_t n = 0;
  return n;
}

// A property of an accepted input that must hold; a violation is a finding (abort).
#define GTBOW_FUZZ_CHECK(cond)                                                                 \
  do {                                                                                         \
    if (!(cond)) {                                                                             \
      std::fprintf(stderr, "fuzz property violated: %s (%s:%d)\n", #cond, __FILE__, __LINE__); \
      std::abort();                                                                            \
    }                                                                                          \
  } while (0)

// A file of this process for parsers that read from a path (on tmpfs when there is one).
inline const std::filesystem::path& ScratchFile(const char* name) {
  static const std::filesystem::path p = [name] {
    const std::filesystem::path shm = "/dev/shm";
    const auto dir =
        std::filesystem::is_directory(shm) ? shm : std::filesystem::temp_directory_path();
    return dir / ("gtbow_fuzz_" + std::string(name) + "_" + std::to_string(::getpid()));
  }();
  return p;
}

inline void WriteScratch(const std::filesystem::path& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!f.flush()) {
    std::fprintf(stderr, "cannot write %s\n", path.c_str());
    std::abort();
  }
}

inline uint64_t Read64(const std::string& s, size_t at) {
  uint64_t v;
  std::memcpy(&v, s.data() + at, 8);
  return v;
}
inline void Write64(std::string* s, size_t at, uint64_t v) { std::memcpy(&(*s)[at], &v, 8); }

// A framed file (binary_io.h: magic 8, version 4, payload size 8, payload, checksum 8) with its
// size field and checksum made consistent with the bytes present.
inline std::string RepairFramed(std::string f) {
  constexpr size_t kHeader = 20;
  if (f.size() < kHeader + 8) return f;
  const uint64_t size = f.size() - kHeader - 8;
  Write64(&f, 12, size);
  Write64(&f, kHeader + size, Checksum64(f.data() + kHeader, size));
  return f;
}

// A database file (format 3, database.cpp: fixed header of 32 bytes, variable header, its
// checksum, padding to 64 bytes, entries, one checksum per 64 MB chunk, the table's checksum)
// with every checksum recomputed where the sizes allow it.
inline std::string RepairDatabase(std::string f) {
  constexpr size_t kFixed = 32, kAlign = 64;
  constexpr uint64_t kChunk = uint64_t{64} << 20;
  if (f.size() < kFixed + 8) return f;
  const uint64_t hs = Read64(f, 16);
  if (hs > f.size() - kFixed - 8) return f;
  Write64(&f, kFixed + hs, Checksum64(f.data(), kFixed + hs));
  const uint64_t at = (kFixed + hs + 8 + kAlign - 1) / kAlign * kAlign;
  const uint64_t entries = Read64(f, 24);
  const uint64_t chunks = (entries + kChunk - 1) / kChunk;
  if (entries > f.size() || at > f.size() - entries || f.size() - at - entries != chunks * 8 + 8) {
    return f;
  }
  for (uint64_t c = 0; c < chunks; ++c) {
    const uint64_t off = c * kChunk, len = std::min(kChunk, entries - off);
    Write64(&f, at + entries + c * 8, Checksum64(f.data() + at + off, len));
  }
  Write64(&f, at + entries + chunks * 8, Checksum64(f.data() + at + entries, chunks * 8));
  return f;
}

// The sections of a map file of format version 2 or 3 (localizer_map.cpp), read from its header
// without checks beyond bounds; `ok` is false where the header cannot be read.
struct MapLayout {
  bool ok = false;
  uint64_t keyframes = 0, stride = 0;
  uint64_t offset[5] = {}, size[5] = {};  // index header, entries, records, checksums, payload
};
inline MapLayout ParseMapLayout(const std::string& f) {
  MapLayout l;
  constexpr size_t kFixed = 64;
  if (f.size() < kFixed) return l;
  const uint64_t hs = Read64(f, 16);
  if (hs > f.size() - kFixed) return l;
  size_t at = kFixed;
  const size_t end = kFixed + hs;
  auto need = [&](uint64_t n) { return n <= end - at; };
  auto skip_string = [&]() {
    if (!need(8)) return false;
    const uint64_t n = Read64(f, at);
    at += 8;
    if (!need(n)) return false;
    at += n;
    return true;
  };
  if (!skip_string() || !need(8)) return l;
  at += 8;  // fingerprint
  if (!skip_string() || !need(8 + 8 + 1 + 4 + 80)) return l;
  at += 8;  // metres per pixel
  l.keyframes = Read64(f, at);
  at += 8 + 1;
  uint32_t stride;
  std::memcpy(&stride, &f[at], 4);
  l.stride = stride;
  at += 4;
  uint32_t version;
  std::memcpy(&version, &f[8], 4);
  if (version >= 3) {  // the frame of the poses and whether they were optimised
    if (!skip_string() || !need(1 + 80)) return l;
    at += 1;
  }
  for (int s = 0; s < 5; ++s) {
    l.offset[s] = Read64(f, at);
    l.size[s] = Read64(f, at + 8);
    at += 16;
    if (l.offset[s] > f.size() || l.size[s] > f.size() - l.offset[s]) return l;
  }
  l.ok = true;
  return l;
}

// A map file of format version 2 or 3 with every checksum recomputed where the header allows:
// the header's, each keyframe payload's (in its record), each 64 MB chunk's and the table's.
inline std::string RepairMap(std::string f) {
  constexpr size_t kFixed = 64;
  constexpr uint64_t kChunk = uint64_t{64} << 20;
  if (f.size() < kFixed) return f;
  const uint64_t hs = Read64(f, 16);
  if (hs > f.size() - kFixed) return f;
  Write64(&f, 24, Checksum64(f.data() + kFixed, hs));
  Write64(&f, 32, f.size());
  const MapLayout l = ParseMapLayout(f);
  if (!l.ok || l.size[2] / 64 != l.keyframes || l.size[2] % 64 != 0) return f;
  for (uint64_t k = 0; k < l.keyframes; ++k) {
    const size_t rec = l.offset[2] + k * 64;
    uint32_t n;
    std::memcpy(&n, &f[rec + 44], 4);
    const uint64_t off = Read64(f, rec + 48), len = uint64_t{n} * l.stride;
    if (off > l.size[4] || len > l.size[4] - off) continue;
    Write64(&f, rec + 56, Checksum64(f.data() + l.offset[4] + off, len));
  }
  if (l.offset[3] < l.offset[0]) return f;
  const uint64_t region = l.offset[3] - l.offset[0], chunks = (region + kChunk - 1) / kChunk;
  if (l.size[3] != (chunks + 1) * 8) return f;
  for (uint64_t c = 0; c < chunks; ++c) {
    const uint64_t len = std::min(kChunk, region - c * kChunk);
    Write64(&f, l.offset[3] + c * 8, Checksum64(f.data() + l.offset[0] + c * kChunk, len));
  }
  Write64(&f, l.offset[3] + chunks * 8, Checksum64(f.data() + l.offset[3], chunks * 8));
  return f;
}

// The input without its mode byte, repaired by `repair` when the mode byte is odd.
template <typename Repair>
std::string FileFromInput(const uint8_t* data, size_t size, Repair&& repair) {
  if (size == 0) return {};
  std::string f(reinterpret_cast<const char*>(data) + 1, size - 1);
  return (data[0] & 1) ? repair(std::move(f)) : f;
}

}  // namespace fuzz
}  // namespace gtbow
