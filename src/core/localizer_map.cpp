// The Localizer's map file (Save, Load, ImportVersion1, ReadMapInfo).
//
// Version 3 (version 2 without the pose frame and flag is read too), little-endian, every
// section at a 64-byte aligned offset:
//   fixed head (64 bytes): magic "GTBWMAP\0", version, 0, header size, header checksum,
//                          file size
//   header:       vocabulary path and fingerprint, the preset's text, metres per pixel,
//                 keyframe count, whether descriptors are kept, payload bytes per keypoint,
//                 (version 3:) the frame of the keyframe poses and whether they were optimised,
//                 and the sections' offsets and sizes
//   index header  BowDatabase's header (rows, counts, options, removed flags)   \  verified at
//   index entries its entries, memory-mapped in place                           |  Load, 64 MB
//   records       a 64-byte record per keyframe (detail::KeyframeRecord)        /  per checksum
//   checksum table one checksum per 64 MB of the three sections above, and the table's own
//   payloads      per keyframe: packed keypoints, then descriptors when kept; each has its
//                 checksum in its record, checked when the keyframe is read (a load reads only
//                 the index and records, not gigabytes of keypoints it may never need)
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/parallel.h"
#include "keyframe_store.h"

namespace gtbow {

namespace {

constexpr char kMapMagic[8] = {'G', 'T', 'B', 'W', 'M', 'A', 'P', '\0'};
constexpr uint32_t kVersion1 = 1;  // one framed blob, read whole (before issue 17)
constexpr uint32_t kVersion2 = 2;  // version 3 without the pose frame and flag
constexpr uint32_t kMapVersion = 3;
constexpr size_t kFixedHead = 64;
constexpr size_t kAlign = 64;
constexpr uint64_t kChunk = uint64_t{64} << 20;
constexpr uint64_t kMaxKeypoints = 1u << 16;
constexpr uint64_t kMaxHeader = 1u << 24;

enum Section { kIndexHeader, kIndexEntries, kRecords, kChecksums, kPayload, kSections };

struct Layout {
  uint64_t offset[kSections] = {};
  uint64_t size[kSections] = {};
  uint64_t file_size = 0;
};

uint64_t AlignUp(uint64_t v) { return (v + kAlign - 1) / kAlign * kAlign; }

std::string ConvertHint(const std::string& source) {
  return source + ": map format version 1 (written before memory-mapped maps) is not loaded " +
         "directly any more; convert it once: gtbow convert-map --in " + source + " --out NEW_FILE";
}

// An environment variable's value, or `fallback` when it is unset (the save's measurement
// switches, read once each).
std::string EnvOr(const char* name, const char* fallback) {
  const char* env = std::getenv(name);
  return env != nullptr ? env : fallback;
}

bool IndexWriteBehind() {
  static const bool on = EnvOr("GTBOW_SAVE_WRITE_BEHIND", "1") != "0";
  return on;
}

// The sections' bytes [offset of kIndexHeader, offset of kChecksums) go through this: it writes
// them and keeps a checksum per 64 MB of them.
class ChunkedRegion {
 public:
  ChunkedRegion(AtomicFileWriter* file, uint64_t size)
      : file_(file), size_(size), chunk_(std::min(kChunk, size)), flushed_(file->written()) {}
  void Write(const void* data, size_t n) {
    const char* p = static_cast<const char*>(data);
    while (n > 0) {
      const size_t take = std::min<uint64_t>(n, chunk_size() - in_chunk_);
      chunk_.Add(p, take);
      file_->Write(p, take);
      p += take;
      n -= take;
      in_chunk_ += take;
      done_ += take;
      if (in_chunk_ == chunk_size()) {
        sums_.push_back(chunk_.Finish());
        in_chunk_ = 0;
        chunk_ = Checksum64Builder(std::min(kChunk, size_ - done_));
        // Each 64 MB to disk from this (low-priority) thread, kept in the page cache: the index
        // is memory-mapped from it right after the save. GTBOW_SAVE_WRITE_BEHIND=0 leaves it to
        // the kernel's flusher threads (as before December 2026), for measurements.
        if (IndexWriteBehind()) file_->WriteBehind(flushed_, file_->written() - flushed_, false);
        flushed_ = file_->written();
      }
    }
  }
  void Pad(uint64_t to) {
    static const char zeros[kAlign] = {};
    while (done_ < to) Write(zeros, std::min<uint64_t>(kAlign, to - done_));
  }
  uint64_t done() const { return done_; }
  const std::vector<uint64_t>& sums() const { return sums_; }

 private:
  uint64_t chunk_size() const { return std::min(kChunk, size_ - (done_ - in_chunk_)); }
  AtomicFileWriter* file_;
  uint64_t size_;
  Checksum64Builder chunk_;
  uint64_t flushed_;  // the file's bytes written to disk so far
  uint64_t in_chunk_ = 0, done_ = 0;
  std::vector<uint64_t> sums_;
};

void PadFile(AtomicFileWriter* file, uint64_t to) {
  static const char zeros[kAlign] = {};
  while (file->written() < to) file->Write(zeros, std::min<uint64_t>(kAlign, to - file->written()));
}

// Maps the pages of [data, data + size) of a mapped file into the process now, 64 MB per call of
// madvise(MADV_POPULATE_READ) (Linux 5.14: the kernel maps a range in one call, where reading one
// byte per page from here took a page fault each); where the kernel refuses it, one read per page.
// GTBOW_SAVE_POPULATE=0 reads one byte per page throughout (as before December 2026), to compare.
void TouchPages(const char* data, size_t size) {
  constexpr uintptr_t kPage = 4096, kStep = uintptr_t{64} << 20;
  static const bool populate = EnvOr("GTBOW_SAVE_POPULATE", "1") != "0";
  const uintptr_t end = reinterpret_cast<uintptr_t>(data) + size;
  for (uintptr_t at = reinterpret_cast<uintptr_t>(data) & ~(kPage - 1); at < end; at += kStep) {
    const size_t n = static_cast<size_t>(std::min(kStep, end - at));
#ifdef MADV_POPULATE_READ
    if (populate && ::madvise(reinterpret_cast<void*>(at), n, MADV_POPULATE_READ) == 0) continue;
#endif
    volatile char sink = 0;
    for (size_t p = 0; p < n; p += kPage) sink = sink ^ reinterpret_cast<const char*>(at)[p];
    (void)sink;
  }
}

// The writer's priorities (GTBOW_SAVE_PRIORITY, for measurements; bench-map): "cpu-idle" (the
// default): SCHED_IDLE and the lowest best-effort I/O level; "nice": nice 19 and the same I/O
// level (the writer until December 2026); "idle": SCHED_IDLE and the idle I/O class.
// GTBOW_SAVE_IDLE=1, the earlier switch, still means "idle".
enum class WriterPriority { kCpuIdle, kNice, kIdle };
WriterPriority SavePriority() {
  static const WriterPriority p = [] {
    if (EnvOr("GTBOW_SAVE_IDLE", "0") == "1") return WriterPriority::kIdle;
    const std::string v = EnvOr("GTBOW_SAVE_PRIORITY", "cpu-idle");
    if (v == "nice") return WriterPriority::kNice;
    if (v == "idle") return WriterPriority::kIdle;
    if (v != "cpu-idle") {
      std::fprintf(stderr,
                   "gtbow: GTBOW_SAVE_PRIORITY=%s is not cpu-idle, nice or idle: cpu-idle\n",
                   v.c_str());
    }
    return WriterPriority::kCpuIdle;
  }();
  return p;
}

// Runs `work` on a thread of its own at low priority (its own thread: an unprivileged process
// can lower a thread's priority but not raise it back) and waits; its exception is rethrown
// here. CPU: SCHED_IDLE, at nice 19 within it. Disk: the best-effort I/O class at its lowest
// level, which is never starved (the idle I/O class, tried in December 2026, is served only when
// no other I/O waits, so a busy disk can hold it without end). SCHED_IDLE is not a strict idle
// class either: on a core kept busy it still gets a small share (a fifth of nice 19's), so a save
// always finishes; what it changes is that a thread of normal priority that wakes up takes the
// core from it at once, where a nice-19 thread may keep it for the rest of its time slice (the
// 1,000,000-keyframe map's save stall: RESULTS.md "Save stalls"). The work holds no lock of the
// Localizer's.
template <class Work>
void RunAtLowPriority(Work&& work) {
  std::exception_ptr error;
  std::thread worker([&] {
    const pid_t tid = static_cast<pid_t>(::syscall(SYS_gettid));
    ::setpriority(PRIO_PROCESS, static_cast<id_t>(tid), 19);
    constexpr int kIoprioWhoProcess = 1, kIoprioClassBestEffort = 2, kIoprioClassIdle = 3;
    constexpr int kIoprioClassShift = 13, kLowestLevel = 7;
    int io = (kIoprioClassBestEffort << kIoprioClassShift) | kLowestLevel;
    const WriterPriority priority = SavePriority();
    if (priority != WriterPriority::kNice) {
      sched_param idle{};
      ::pthread_setschedparam(::pthread_self(), SCHED_IDLE, &idle);
    }
    if (priority == WriterPriority::kIdle) io = kIoprioClassIdle << kIoprioClassShift;
    ::syscall(SYS_ioprio_set, kIoprioWhoProcess, tid, io);
    try {
      work();
    } catch (...) {
      error = std::current_exception();
    }
  });
  worker.join();
  if (error) std::rethrow_exception(error);
}

uint64_t Get64(const char* p) {
  uint64_t v;
  std::memcpy(&v, p, 8);
  return v;
}

// The fixed head and header of a version-2 file; `size` is the file's.
MapFileInfo ParseHeader(const char* d, size_t size, const std::string& source, Layout* layout,
                        uint32_t* stride) {
  auto fail = [&source](const std::string& what) {
    throw std::runtime_error(source + ": " + what);
  };
  if (size < kFixedHead) fail("not a map file (too short: " + std::to_string(size) + " bytes)");
  if (std::memcmp(d, kMapMagic, 8) != 0) fail("not a map file (wrong magic number)");
  uint32_t version;
  std::memcpy(&version, d + 8, 4);
  if (version == kVersion1) throw std::runtime_error(ConvertHint(source));
  if (version != kMapVersion && version != kVersion2) {
    fail("map format version " + std::to_string(version) +
         " is not supported (this build reads versions 2 and " + std::to_string(kMapVersion) + ")");
  }
  const uint64_t hs = Get64(d + 16);
  if (hs > kMaxHeader || hs > size - kFixedHead) fail("map file is truncated (header)");
  if (Checksum64(d + kFixedHead, hs) != Get64(d + 24)) {
    fail("map file is corrupt (header checksum mismatch)");
  }
  const uint64_t file_size = Get64(d + 32);
  if (file_size != size) {
    fail("map file is truncated or has trailing bytes (" + std::to_string(size) + " bytes, the " +
         "header says " + std::to_string(file_size) + ")");
  }
  BinaryReader r(d + kFixedHead, hs, source);
  MapFileInfo info;
  info.version = version;
  info.file_bytes = size;
  info.vocabulary_path = r.GetString(1u << 16);
  info.vocabulary_fingerprint = r.Get<uint64_t>();
  info.retrieval_config = r.GetString(1u << 20);
  info.meters_per_pixel = r.Get<double>();
  info.keyframes = r.Get<uint64_t>();
  info.descriptors = r.Get<uint8_t>() != 0;
  *stride = r.Get<uint32_t>();
  if (version >= 3) {
    info.pose_frame = r.GetString(1u << 12);
    const uint8_t optimised = r.Get<uint8_t>();
    if (optimised > 1) r.Fail("invalid map header (pose flag)");
    info.poses_optimised = optimised != 0;
  }
  for (int s = 0; s < kSections; ++s) {
    layout->offset[s] = r.Get<uint64_t>();
    layout->size[s] = r.Get<uint64_t>();
  }
  if (r.remaining() != 0) r.Fail("trailing bytes after the header");
  // Sections in order, aligned, inside the file; the payloads end it.
  uint64_t at = AlignUp(kFixedHead + hs);
  for (int s = 0; s < kSections; ++s) {
    if (layout->offset[s] != AlignUp(at) || layout->size[s] > size ||
        layout->offset[s] > size - layout->size[s]) {
      fail("map file's section table is inconsistent (section " + std::to_string(s) + ")");
    }
    at = layout->offset[s] + layout->size[s];
  }
  if (at != size) fail("map file has trailing bytes after the keyframes");
  const uint64_t region = layout->offset[kChecksums] - layout->offset[kIndexHeader];
  if (layout->size[kChecksums] != ((region + kChunk - 1) / kChunk + 1) * 8) {
    fail("map file's checksum table has the wrong size");
  }
  if (info.keyframes > (uint64_t{1} << 24) ||
      layout->size[kRecords] != info.keyframes * sizeof(detail::KeyframeRecord)) {
    fail("map file's keyframe records do not match its keyframe count");
  }
  if (*stride < sizeof(detail::PackedKeypoint)) fail("map file's keyframe payload is malformed");
  layout->file_size = size;
  return info;
}

}  // namespace

void Localizer::CheckHeader(const MapFileInfo& info, const std::string& source,
                            bool adopt_scale) const {
  auto fail = [&source](const std::string& what) {
    throw std::runtime_error(source + ": " + what);
  };
  if (info.vocabulary_fingerprint != vocabulary_->fingerprint()) {
    fail("the map was built with another vocabulary than " + vocabulary_path_ + " (the map names " +
         info.vocabulary_path + ")");
  }
  if (info.retrieval_config != FormatRetrievalConfig(options_.retrieval)) {
    // Only the BoW options shape the stored index (the database checks them); feature
    // options change what new images look like. Both must match for answers to be consistent.
    // A map written before a key existed has that key's default.
    std::string diff;
    try {
      diff = RetrievalConfigDifference(
          ParseRetrievalConfig(info.retrieval_config, "the map's options"), "the map",
          options_.retrieval, "this node");
    } catch (const std::exception& e) {
      fail(std::string("the map's retrieval options cannot be read: ") + e.what());
    }
    if (!diff.empty()) {
      fail("the map was built with other retrieval options (another preset or extractor): " + diff);
    }
  }
  if (!adopt_scale && info.meters_per_pixel != meters_per_pixel()) {
    fail("the map was built with meters_per_pixel " + std::to_string(info.meters_per_pixel) +
         ", this node uses " + std::to_string(meters_per_pixel()));
  }
  if (!(info.meters_per_pixel > 0) || !std::isfinite(info.meters_per_pixel)) {
    fail("the map's meters_per_pixel is not positive and finite");
  }
  if (info.version >= kVersion2 && info.descriptors != options_.keep_descriptors) {
    fail(std::string("the map ") + (info.descriptors ? "keeps" : "keeps no") +
         " keyframe descriptors, this node's keep_descriptors is " +
         (options_.keep_descriptors ? "true" : "false"));
  }
}

SaveStats Localizer::Save(const std::filesystem::path& path, bool paced) const {
  using Clock = std::chrono::steady_clock;
  auto ms = [](Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
  };
  SaveStats stats;
  std::lock_guard<std::mutex> one(save_mutex_);
  std::shared_ptr<BowDatabase> db;
  BowDatabase::Frozen frozen;
  std::vector<std::shared_ptr<const detail::KeyframeSegment>> segments;
  uint64_t generation = 0;
  double scale = 0;
  std::shared_ptr<const std::vector<Pose2D>> moved;  // UpdateKeyframePoses' poses, as sealed
  std::string pose_frame;
  bool poses_optimised = false;
  for (bool sealed = false; !sealed;) {
    {
      std::shared_lock<std::shared_mutex> lock(mutex_);
      db = database_;
    }
    // The fresh tails are made before the lock (a million empty rows take milliseconds).
    frozen = db->PrepareFreeze();
    // One of the two waits a save imposes: sealing the index's tails and the keyframes' tail.
    std::unique_lock<std::shared_mutex> lock(mutex_);
    const auto t0 = Clock::now();
    if (database_ != db) continue;  // a map was loaded meanwhile: prepare for that one
    db->Freeze(&frozen);
    segments = keyframes_->Freeze();
    generation = generation_;
    scale = meters_per_pixel();  // the scale of the keyframes sealed
    moved = moved_;
    pose_frame = pose_frame_;
    poses_optimised = poses_optimised_;
    stats.seal_ms = ms(t0, Clock::now());
    sealed = true;
  }
  const auto write_start = Clock::now();
  // Written by a thread of its own at the lowest CPU priority: on a busy robot, insertion,
  // queries and image processing come first, and the save takes what is left.
  uint64_t n = 0;
  size_t stride = 0;
  Layout l;
  std::shared_ptr<const MappedFile> mapped;
  RunAtLowPriority([&] {
    db->DescribeFrozen(&frozen);
    n = frozen.images;
    stride = PayloadStride();
    uint64_t payload_bytes = 0, count = 0;
    for (const auto& s : segments) {
      for (size_t i = 0; i < s->size(); ++i) {
        payload_bytes += static_cast<uint64_t>(s->Get(i).record->num_keypoints) * stride;
      }
      count += s->size();
    }
    if (count != n) throw std::logic_error("Localizer::Save: keyframes out of step with the index");

    BinaryWriter h;
    h.PutString(vocabulary_path_);
    h.Put<uint64_t>(vocabulary_->fingerprint());
    h.PutString(FormatRetrievalConfig(options_.retrieval));
    h.Put<double>(scale);
    h.Put<uint64_t>(n);
    h.Put<uint8_t>(options_.keep_descriptors ? 1 : 0);
    h.Put<uint32_t>(static_cast<uint32_t>(stride));
    h.PutString(pose_frame);
    h.Put<uint8_t>(poses_optimised ? 1 : 0);
    const uint64_t header_size = h.buffer().size() + kSections * 16;
    l.size[kIndexHeader] = frozen.header.size();
    l.size[kIndexEntries] = frozen.entries_bytes;
    l.size[kRecords] = n * sizeof(detail::KeyframeRecord);
    l.size[kPayload] = payload_bytes;
    uint64_t at = AlignUp(kFixedHead + header_size);
    for (int s = 0; s < kSections; ++s) {
      l.offset[s] = AlignUp(at);
      if (s == kChecksums) {
        const uint64_t region = l.offset[kChecksums] - l.offset[kIndexHeader];
        l.size[kChecksums] = ((region + kChunk - 1) / kChunk + 1) * 8;
      }
      at = l.offset[s] + l.size[s];
    }
    l.file_size = at;
    for (int s = 0; s < kSections; ++s) {
      h.Put<uint64_t>(l.offset[s]);
      h.Put<uint64_t>(l.size[s]);
    }
    char head[kFixedHead] = {};
    std::memcpy(head, kMapMagic, 8);
    std::memcpy(head + 8, &kMapVersion, 4);
    const uint64_t fixed[3] = {h.buffer().size(), Checksum64(h.buffer().data(), h.buffer().size()),
                               l.file_size};
    std::memcpy(head + 16, fixed, sizeof(fixed));

    AtomicFileWriter file(path);
    // Paced (LocalizerOptions::save_rate_mb): at full speed the writer's copies into the page
    // cache slow the queries and insertions beside it (RESULTS.md "The writer paced").
    if (paced) file.Pace(options_.save_rate_mb * 1e6, &stop_pacing_);
    file.Write(head, kFixedHead);
    file.Write(h.buffer());
    PadFile(&file, l.offset[kIndexHeader]);
    const uint64_t base = l.offset[kIndexHeader];
    ChunkedRegion region(&file, l.offset[kChecksums] - base);
    region.Write(frozen.header.data(), frozen.header.size());
    region.Pad(l.offset[kIndexEntries] - base);
    db->WriteFrozen([&](const void* data, size_t size) { region.Write(data, size); });
    region.Pad(l.offset[kRecords] - base);
    {
      std::vector<detail::KeyframeRecord> batch;
      batch.reserve(16384);
      uint64_t offset = 0;
      size_t id = 0;
      for (const auto& s : segments) {
        for (size_t i = 0; i < s->size(); ++i, ++id) {
          detail::KeyframeRecord r = *s->Get(i).record;
          if (moved && id < moved->size() && !std::isnan((*moved)[id].x)) {
            r.x = (*moved)[id].x;
            r.y = (*moved)[id].y;
            r.theta = (*moved)[id].theta;
            r.flags |= detail::KeyframeRecord::kHasPose;
          }
          r.payload_offset = offset;
          offset += static_cast<uint64_t>(r.num_keypoints) * stride;
          batch.push_back(r);
          if (batch.size() == batch.capacity()) {
            region.Write(batch.data(), batch.size() * sizeof(batch[0]));
            batch.clear();
          }
        }
      }
      region.Write(batch.data(), batch.size() * sizeof(batch[0]));
    }
    region.Pad(l.offset[kChecksums] - base);
    std::vector<uint64_t> sums = region.sums();
    sums.push_back(Checksum64(sums.data(), sums.size() * 8));
    file.Write(sums.data(), sums.size() * 8);
    PadFile(&file, l.offset[kPayload]);
    // The payloads (most of a map that keeps descriptors) are pushed to disk and dropped from
    // the page cache as they are written: a save of gigabytes then does not crowd the robot's
    // memory (the page cache filling up made the kernel reclaim inside Add's allocations).
    // Verification maps a keyframe's payload again when it reads it.
    uint64_t dropped = l.offset[kPayload];
    for (const auto& s : segments) {
      for (size_t i = 0; i < s->size(); ++i) {
        const detail::KeyframeView v = s->Get(i);
        file.Write(v.payload, static_cast<size_t>(v.record->num_keypoints) * stride);
        if (file.written() - dropped >= kChunk) {
          file.WriteBehind(dropped, file.written() - dropped);
          dropped = file.written();
        }
      }
    }
    if (file.written() != l.file_size) throw std::logic_error("Localizer::Save: layout mismatch");
    const auto commit_start = Clock::now();
    mapped = file.CommitAndMap();
    const auto populate_start = Clock::now();
    stats.commit_ms = ms(commit_start, populate_start);
    // The index's pages mapped now, here (they are in the page cache, just written): the first
    // queries after the swap below then do not page-fault through gigabytes while they run. The
    // keyframes' payloads are left to be mapped as verification reads them.
    TouchPages(mapped->data() + l.offset[kIndexEntries], l.size[kIndexEntries]);
    stats.populate_ms = ms(populate_start, Clock::now());
  });
  stats.write_ms = ms(write_start, Clock::now());
  stats.keyframes = n;
  stats.bytes = l.file_size;

  // From now on the written file holds what was frozen: use it instead of the heap copies.
  const char* d = mapped->data();
  auto segment = std::make_shared<const detail::KeyframeSegment>(
      reinterpret_cast<const detail::KeyframeRecord*>(d + l.offset[kRecords]), n,
      reinterpret_cast<const uint8_t*>(d + l.offset[kPayload]), l.size[kPayload], stride, mapped);
  // The swaps hold the lock for a few pointer exchanges, on this thread (at its own priority: a
  // lock held at low priority would stall the queries waiting for it); the heap copies they
  // replace (gigabytes of a large map) are freed on the low-priority thread, outside the lock.
  std::shared_ptr<void> replaced;
  stats.swap_ms = db->Rebase(frozen, d + l.offset[kIndexEntries], mapped, &replaced);
  {
    std::unique_lock<std::shared_mutex> lock(mutex_);
    const auto t0 = Clock::now();
    if (generation_ == generation) keyframes_->Rebase(std::move(segment));
    stats.swap_ms += ms(t0, Clock::now());
  }
  const auto free_start = Clock::now();
  RunAtLowPriority([&] {
    replaced.reset();
    segments.clear();  // the sealed heap keyframes
  });
  stats.free_ms = ms(free_start, Clock::now());
  return stats;
}

MapFileInfo Localizer::ReadMapInfo(const std::filesystem::path& path) {
  const auto map = MappedFile::Open(path);
  const std::string source = path.string();
  const char* d = map->data();
  uint32_t version = 0;
  if (map->size() >= 12) std::memcpy(&version, d + 8, 4);
  if (version == kVersion1 && std::memcmp(d, kMapMagic, 8) == 0) {
    // Version 1: a framed payload (magic, version, size), read without the checksum.
    constexpr size_t kFrame = 8 + 4 + 8;
    if (map->size() < kFrame) throw std::runtime_error(source + ": map file is truncated");
    BinaryReader r(d + kFrame, map->size() - kFrame, source);
    MapFileInfo info;
    info.version = kVersion1;
    info.file_bytes = map->size();
    info.vocabulary_path = r.GetString(1u << 16);
    info.vocabulary_fingerprint = r.Get<uint64_t>();
    info.retrieval_config = r.GetString(1u << 20);
    info.meters_per_pixel = r.Get<double>();
    const uint64_t db_bytes = r.Get<uint64_t>();
    if (db_bytes > r.remaining()) r.Fail("map file is truncated (database)");
    r.Skip(db_bytes);
    info.keyframes = r.Get<uint64_t>();
    info.descriptors = true;
    return info;
  }
  Layout l;
  uint32_t stride = 0;
  return ParseHeader(d, map->size(), source, &l, &stride);
}

std::string Localizer::VocabularyPathOf(const std::filesystem::path& path) {
  return ReadMapInfo(path).vocabulary_path;
}

size_t Localizer::Load(const std::filesystem::path& path, bool adopt_scale) {
  const std::string source = path.string();
  const auto map = MappedFile::Open(path);
  const char* d = map->data();
  Layout l;
  uint32_t stride = 0;
  const MapFileInfo info = ParseHeader(d, map->size(), source, &l, &stride);
  CheckHeader(info, source, adopt_scale);
  if (stride != PayloadStride()) {
    throw std::runtime_error(source + ": the map's keyframes hold " + std::to_string(stride) +
                             " bytes per keypoint, this node's features " +
                             std::to_string(PayloadStride()));
  }
  // Every 64 MB of the index and records against its checksum, on all cores.
  const char* region = d + l.offset[kIndexHeader];
  const uint64_t region_size = l.offset[kChecksums] - l.offset[kIndexHeader];
  const uint64_t chunks = (region_size + kChunk - 1) / kChunk;
  const char* table = d + l.offset[kChecksums];
  if (Checksum64(table, chunks * 8) != Get64(table + chunks * 8)) {
    throw std::runtime_error(source + ": map file is corrupt (checksum table mismatch)");
  }
  const size_t threads = std::max<size_t>(1, std::min<size_t>(ThreadCount(0), chunks));
  std::vector<uint64_t> bad(threads, UINT64_MAX);
  RunTasks(static_cast<int>(threads), [&](int t) {
    for (uint64_t c = static_cast<uint64_t>(t); c < chunks; c += threads) {
      const uint64_t len = std::min(kChunk, region_size - c * kChunk);
      if (Checksum64(region + c * kChunk, len) != Get64(table + c * 8)) {
        bad[static_cast<size_t>(t)] = c;
        return;
      }
    }
  });
  for (uint64_t c : bad) {
    if (c != UINT64_MAX) {
      throw std::runtime_error(source + ": map file is corrupt (checksum mismatch in the 64 MB " +
                               "at byte " + std::to_string(l.offset[kIndexHeader] + c * kChunk) +
                               ")");
    }
  }
  std::shared_ptr<BowDatabase> db = NewDatabase();
  db->AttachMapped(region, l.size[kIndexHeader], d + l.offset[kIndexEntries], l.size[kIndexEntries],
                   map, source + " (index)");
  if (db->next_id() != info.keyframes) {
    throw std::runtime_error(source + ": keyframe count does not match the index");
  }
  const auto* records = reinterpret_cast<const detail::KeyframeRecord*>(d + l.offset[kRecords]);
  uint64_t offset = 0;
  for (uint64_t i = 0; i < info.keyframes; ++i) {
    const detail::KeyframeRecord& r = records[i];
    auto bad_record = [&](const std::string& what) {
      throw std::runtime_error(source + ": keyframe " + std::to_string(i) + " " + what);
    };
    if (r.width < static_cast<uint32_t>(kMinImageSide) ||
        r.height < static_cast<uint32_t>(kMinImageSide) ||
        static_cast<double>(r.width) * r.height > kMaxImagePixels ||
        r.num_keypoints > kMaxKeypoints || (r.flags & ~detail::KeyframeRecord::kKnownFlags) != 0 ||
        r.payload_offset != offset) {
      bad_record("is malformed");
    }
    if ((r.flags & detail::KeyframeRecord::kHasPose) &&
        !(std::isfinite(r.x) && std::isfinite(r.y) && std::isfinite(r.theta))) {
      bad_record("has a non-finite pose");
    }
    offset += static_cast<uint64_t>(r.num_keypoints) * stride;
  }
  if (offset != l.size[kPayload]) {
    throw std::runtime_error(source + ": the keyframes' payloads do not fill their section");
  }
  auto store = NewStore();
  store->Attach(std::make_shared<const detail::KeyframeSegment>(
      records, info.keyframes, reinterpret_cast<const uint8_t*>(d + l.offset[kPayload]),
      l.size[kPayload], stride, map));
  std::unique_lock<std::shared_mutex> lock(mutex_);
  repeats_.Clear();  // the map changes: the copies its repeat checks kept too
  database_.swap(db);
  keyframes_.swap(store);
  if (adopt_scale) meters_per_pixel_ = info.meters_per_pixel;
  moved_.reset();
  pose_frame_ = info.pose_frame;
  poses_optimised_ = info.poses_optimised;
  ++generation_;
  lock.unlock();  // the old map is freed without holding up callers
  return info.keyframes;
}

void Localizer::ImportVersion1(const std::filesystem::path& path) {
  const FramedPayload payload = ReadFramedFile(path, kMapMagic, kVersion1, "map");
  const std::string source = path.string();
  BinaryReader r(payload.data(), payload.size(), source);
  MapFileInfo info;
  info.version = kVersion1;
  info.vocabulary_path = r.GetString(1u << 16);
  info.vocabulary_fingerprint = r.Get<uint64_t>();
  info.retrieval_config = r.GetString(1u << 20);
  info.meters_per_pixel = r.Get<double>();
  CheckHeader(info, source, false);
  const std::string db_blob = r.GetString(payload.size());
  std::shared_ptr<BowDatabase> db = NewDatabase();
  db->Deserialize(db_blob.data(), db_blob.size(), source + " (database)");
  const uint64_t n = r.Get<uint64_t>();
  if (n != db->next_id()) r.Fail("keyframe count does not match the database");
  auto store = NewStore();
  const bool sift = options_.retrieval.features.type == FeatureType::kSift;
  for (uint64_t i = 0; i < n; ++i) {
    detail::KeyframeRecord k;
    k.stamp_ns = r.Get<int64_t>();
    const bool has_pose = r.Get<uint8_t>() != 0;
    k.x = r.Get<double>();
    k.y = r.Get<double>();
    k.theta = r.Get<double>();
    const int32_t width = r.Get<int32_t>(), height = r.Get<int32_t>();
    const std::vector<Keypoint> keypoints = r.GetVector<Keypoint>(kMaxKeypoints);
    const int rows = r.Get<int32_t>(), cols = r.Get<int32_t>(), type = r.Get<int32_t>();
    const auto bytes = r.GetVector<uint8_t>(kMaxKeypoints * 512);
    if (rows < 0 || cols < 0 || static_cast<size_t>(rows) != keypoints.size() ||
        (type != CV_8U && type != CV_32F) ||
        bytes.size() != static_cast<size_t>(rows) * cols * (type == CV_8U ? 1 : 4) ||
        width < kMinImageSide || height < kMinImageSide) {
      r.Fail("keyframe " + std::to_string(i) + " is malformed");
    }
    if (has_pose && !(std::isfinite(k.x) && std::isfinite(k.y) && std::isfinite(k.theta))) {
      r.Fail("keyframe " + std::to_string(i) + " has a non-finite pose");
    }
    for (const Keypoint& kp : keypoints) {
      if (!(std::isfinite(kp.x) && std::isfinite(kp.y) && std::isfinite(kp.angle) &&
            std::isfinite(kp.size))) {
        r.Fail("keyframe " + std::to_string(i) + " has a non-finite keypoint");
      }
    }
    // Descriptors as this node's extractor makes them (ORB: 32 bytes; SIFT: 128 floats).
    if (rows > 0 && (type != (sift ? CV_32F : CV_8U) || cols != (sift ? 128 : 32))) {
      r.Fail("keyframe " + std::to_string(i) + " has descriptors of another kind (" +
             std::to_string(cols) + " columns) than this node's features");
    }
    k.flags = has_pose ? detail::KeyframeRecord::kHasPose : 0;
    k.width = static_cast<uint32_t>(width);
    k.height = static_cast<uint32_t>(height);
    k.num_keypoints = static_cast<uint32_t>(keypoints.size());
    cv::Mat descriptors;
    if (rows > 0 && options_.keep_descriptors) {
      descriptors = cv::Mat(rows, cols, type, const_cast<uint8_t*>(bytes.data()));
    }
    store->Append(k, detail::MakePayload(keypoints, descriptors, k.width, k.height));
  }
  if (r.remaining() != 0) r.Fail("trailing bytes after the keyframes");
  std::unique_lock<std::shared_mutex> lock(mutex_);
  repeats_.Clear();  // the map changes: the copies its repeat checks kept too
  database_.swap(db);
  keyframes_.swap(store);
  moved_.reset();
  pose_frame_.clear();  // a version-1 map does not say
  poses_optimised_ = false;
  ++generation_;
  lock.unlock();
}

}  // namespace gtbow
