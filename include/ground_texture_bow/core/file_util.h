// Small filesystem helpers shared by every writer in the package: atomic writes and checks on
// output directories. All paths are std::filesystem paths; errors throw std::runtime_error
// naming the path and the reason.
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <filesystem>
#include <initializer_list>
#include <memory>
#include <string>
#include <string_view>

namespace gtbow {

// Writes `contents` to `path` atomically: a temporary file in the same directory is written,
// flushed and renamed over `path`. On failure nothing at `path` changes and the temporary is
// removed.
void WriteFileAtomic(const std::filesystem::path& path, const std::string& contents);
// The same for contents given in pieces, written one after the other (no joined copy).
void WriteFileAtomic(const std::filesystem::path& path,
                     std::initializer_list<std::string_view> pieces);

class MappedFile;

// A file written in pieces of any number and size, then published atomically: the pieces go
// to a temporary file next to `path`; Commit() flushes it to disk and renames it over `path`.
// Destroyed without Commit() (an error, an exception), the temporary is removed and `path` is
// untouched. Errors throw std::runtime_error naming `path` and the reason.
// Small pieces are gathered in a buffer and written out in whole, aligned blocks of kBlock bytes
// of the file (a piece that reaches a block boundary goes out directly): a write that ends inside
// a file-system block makes the kernel zero the rest of that block first, and a map's index comes
// in a million pieces of a few kilobytes. An error of the disk may therefore surface at a later
// Write, WriteBehind or Commit than the piece that caused it; it fails the same way.
class AtomicFileWriter {
 public:
  explicit AtomicFileWriter(std::filesystem::path path);
  ~AtomicFileWriter();
  AtomicFileWriter(const AtomicFileWriter&) = delete;
  AtomicFileWriter& operator=(const AtomicFileWriter&) = delete;
  static constexpr size_t kBlock = size_t{1} << 20;
  void Write(const void* data, size_t size);
  void Write(std::string_view piece) { Write(piece.data(), piece.size()); }
  size_t written() const { return written_; }  // bytes given to Write, buffered ones included
  // Writes bytes [offset, offset + size) to disk and waits for it, from the calling thread
  // (write-behind for files of gigabytes: the kernel's flusher threads, which run at normal
  // priority, then have nothing left to write, and the final fsync little), and with `drop`
  // drops them from the page cache. Buffered bytes in that range are written out first, which
  // fails as Write does; the rest is best effort and never fails.
  void WriteBehind(size_t offset, size_t size, bool drop = true);
  // Paces the writes from now on: after each block written out, the writer sleeps for as long as
  // it is ahead of `bytes_per_second` (0: no pacing, the default). For a save of gigabytes
  // beside work that must not wait (the map writer; RESULTS.md "The writer paced"). Time the
  // writer spent behind (a busy core, a disk slower than the pace) is not made up at full speed
  // afterwards: it may get ahead by one block's time at most. Once `*hurry` (optional, read after
  // each block and every 50 ms of a pause) is true, the rest is written unpaced: a node that
  // shuts down does not wait out a paced save.
  void Pace(double bytes_per_second, const std::atomic<bool>* hurry = nullptr);
  bool paced() const { return pace_ > 0; }  // false also once hurried
  void Commit();
  // Commit, and a read-only mapping of the bytes written (taken before the rename).
  std::shared_ptr<const MappedFile> CommitAndMap();

 private:
  std::shared_ptr<const MappedFile> Publish(bool map);
  void WriteOut(const char* data, size_t size);  // to the file, now
  void Flush();                                  // the buffer to the file
  [[noreturn]] void Fail(const std::string& why);
  std::filesystem::path path_;
  std::filesystem::path tmp_;
  int fd_ = -1;
  size_t written_ = 0;
  std::unique_ptr<char[]> buffer_;  // kBlock bytes, made on the first small piece
  size_t buffered_ = 0;             // the last buffered_ bytes of written_
  size_t out_ = 0;                  // bytes written out to the file
  void PaceAfterWrite();
  double pace_ = 0;  // bytes per second, 0: unpaced
  const std::atomic<bool>* hurry_ = nullptr;
  size_t paced_from_ = 0;  // out_ at pace_start_
  std::chrono::steady_clock::time_point pace_start_;
};

// A whole file mapped read-only into memory (mmap, pages read on first touch and shared with
// the page cache). The mapping stays valid while the object lives, even if the file is
// replaced (renamed over) or deleted meanwhile.
class MappedFile {
 public:
  // Throws std::runtime_error naming the path when it cannot be opened or mapped.
  static std::shared_ptr<const MappedFile> Open(const std::filesystem::path& path);
  // The file open as `fd` (not closed here); `path` names it in errors.
  static std::shared_ptr<const MappedFile> FromDescriptor(int fd,
                                                          const std::filesystem::path& path);
  ~MappedFile();
  MappedFile(const MappedFile&) = delete;
  MappedFile& operator=(const MappedFile&) = delete;
  const char* data() const { return data_; }
  size_t size() const { return size_; }

 private:
  MappedFile(const char* data, size_t size) : data_(data), size_(size) {}
  const char* data_;
  size_t size_;
};

// Asks the kernel to read [data, data + size) of a mapped file ahead (madvise MADV_WILLNEED on
// the pages it touches) and returns at once: several ranges asked for one after the other are
// read from the disk together instead of one page fault at a time. Best effort: never fails.
void AdviseWillNeed(const void* data, size_t size);

// Reads a whole file; throws std::runtime_error naming the path when it cannot be read.
std::string ReadFile(const std::filesystem::path& path);

// Prepares to create directory `target` atomically. Returns a fresh, empty staging directory
// next to `target` (same filesystem) that the caller fills and then hands to
// CommitStagedDirectory. Throws std::runtime_error when `target` exists and is a non-empty
// directory (unless `force`), exists and is not a directory, or its parent is not writable.
std::filesystem::path StageDirectory(const std::filesystem::path& target, bool force);

// Moves a filled staging directory to `target`, replacing an old `target` only after the new
// one is complete. The old contents are deleted only once the rename succeeded.
void CommitStagedDirectory(const std::filesystem::path& staging,
                           const std::filesystem::path& target);

// Removes a staging directory after a failure; never throws.
void DiscardStagedDirectory(const std::filesystem::path& staging) noexcept;

}  // namespace gtbow
