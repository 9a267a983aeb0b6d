#include "ground_texture_bow/core/file_util.h"

#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <random>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace fs = std::filesystem;

namespace gtbow {

namespace {

std::string RandomSuffix() {
  std::random_device rd;
  std::ostringstream s;
  s << std::hex << rd() << rd();
  return s.str();
}

std::string Errno() { return std::strerror(errno); }

}  // namespace

void WriteFileAtomic(const fs::path& path, const std::string& contents) {
  WriteFileAtomic(path, {std::string_view(contents)});
}

void WriteFileAtomic(const fs::path& path, std::initializer_list<std::string_view> pieces) {
  AtomicFileWriter out(path);
  for (std::string_view piece : pieces) out.Write(piece);
  out.Commit();
}

namespace {

// Temporaries are named .<file>.tmp-<pid>-<random>, with <file> cut to its first 200 bytes so
// that the name stays under NAME_MAX (255) for any file name that is itself valid. A writer
// killed before it could clean up (SIGKILL, power loss) leaves one behind; the next writer of
// the same file removes those of processes that no longer exist. Never throws.
std::string TemporaryPrefix(const std::string& file) {
  constexpr size_t kMaxKept = 200;  // + ".tmp-" + pid (<= 10) + "-" + 16 hex digits < 255
  return "." + file.substr(0, kMaxKept) + ".tmp-";
}

void RemoveStaleTemporaries(const fs::path& dir, const std::string& file) noexcept {
  const std::string prefix = TemporaryPrefix(file);
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.compare(0, prefix.size(), prefix) != 0) continue;
    char* rest = nullptr;
    const long pid = std::strtol(name.c_str() + prefix.size(), &rest, 10);
    if (pid <= 0 || rest == nullptr || *rest != '-') continue;
    if (::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH) {
      std::error_code ignored;
      fs::remove(it->path(), ignored);
    }
  }
}

}  // namespace

AtomicFileWriter::AtomicFileWriter(fs::path path) : path_(std::move(path)) {
  const fs::path dir = path_.has_parent_path() ? path_.parent_path() : fs::path(".");
  RemoveStaleTemporaries(dir, path_.filename().string());
  tmp_ = dir / (TemporaryPrefix(path_.filename().string()) + std::to_string(::getpid()) + "-" +
                RandomSuffix());
  // Read access too: CommitAndMap maps what was written.
  fd_ = ::open(tmp_.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd_ < 0) throw std::runtime_error("cannot write '" + path_.string() + "': " + Errno());
}

AtomicFileWriter::~AtomicFileWriter() {
  if (fd_ >= 0) {
    ::close(fd_);
    ::unlink(tmp_.c_str());
  }
}

void AtomicFileWriter::Fail(const std::string& why) {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  ::unlink(tmp_.c_str());
  throw std::runtime_error("cannot write '" + path_.string() + "': " + why);
}

void AtomicFileWriter::Write(const void* data, size_t size) {
  if (fd_ < 0) throw std::logic_error("AtomicFileWriter: write after commit or failure");
  const char* p = static_cast<const char*>(data);
  while (size > 0) {
    const size_t room = kBlock - written_ % kBlock;  // bytes to the next block boundary
    if (buffered_ == 0 && size >= room) {
      // Straight to the file, up to the last block boundary the piece reaches.
      const size_t n = room + (size - room) / kBlock * kBlock;
      WriteOut(p, n);
      p += n;
      size -= n;
      written_ += n;
      continue;
    }
    if (!buffer_) buffer_ = std::make_unique<char[]>(kBlock);
    const size_t n = std::min(size, room);
    std::memcpy(buffer_.get() + buffered_, p, n);
    buffered_ += n;
    p += n;
    size -= n;
    written_ += n;
    if (n == room) Flush();  // a whole block (or the rest of one) gathered
  }
}

void AtomicFileWriter::Flush() {
  if (buffered_ == 0) return;
  const size_t n = buffered_;
  buffered_ = 0;
  WriteOut(buffer_.get(), n);
}

void AtomicFileWriter::WriteOut(const char* p, size_t size) {
  size_t done = 0;
  while (done < size) {
    // A file-size limit (ulimit -f, systemd's LimitFSIZE) makes write() raise SIGXFSZ, whose
    // default action kills the whole process: a nodelet manager with every nodelet in it, for
    // one oversized map. Blocked in this thread for the call, write() fails with EFBIG instead,
    // the signal it raised is consumed, and the save fails like on a full disk.
    sigset_t xfsz, previous;
    sigemptyset(&xfsz);
    sigaddset(&xfsz, SIGXFSZ);
    pthread_sigmask(SIG_BLOCK, &xfsz, &previous);
    // Paced, a block at a time up to the file's next block boundary, the pause after each (a
    // large piece would otherwise go out in one burst).
    const size_t want = pace_ > 0 ? std::min(size - done, kBlock - out_ % kBlock) : size - done;
    const ssize_t n = ::write(fd_, p + done, want);
    const int error = errno;
    if (n < 0 && error == EFBIG) {
      const timespec no_wait{0, 0};
      while (sigtimedwait(&xfsz, nullptr, &no_wait) == SIGXFSZ) {
      }
    }
    pthread_sigmask(SIG_SETMASK, &previous, nullptr);
    if (n < 0) {
      if (error == EINTR) continue;
      Fail(std::strerror(error));
    }
    done += static_cast<size_t>(n);
    out_ += static_cast<size_t>(n);
    if (pace_ > 0) PaceAfterWrite();
  }
}

void AtomicFileWriter::Pace(double bytes_per_second, const std::atomic<bool>* hurry) {
  pace_ = bytes_per_second > 0 && std::isfinite(bytes_per_second) ? bytes_per_second : 0;
  hurry_ = hurry;
  paced_from_ = out_;
  pace_start_ = std::chrono::steady_clock::now();
}

void AtomicFileWriter::PaceAfterWrite() {
  using Clock = std::chrono::steady_clock;
  using Seconds = std::chrono::duration<double>;
  const double slack = static_cast<double>(kBlock) / pace_;  // one block's time
  for (;;) {
    if (hurry_ != nullptr && hurry_->load()) {
      pace_ = 0;
      return;
    }
    const Clock::time_point now = Clock::now();
    // Seconds the writer is ahead of the pace (negative: behind), as a double: no overflow of
    // the clock's integer ticks at any rate.
    const double ahead = static_cast<double>(out_ - paced_from_) / pace_ -
                         std::chrono::duration_cast<Seconds>(now - pace_start_).count();
    if (ahead < -slack) {
      // Behind by more than a block: restart the reckoning here, a block's time in hand, so that
      // the time behind is not made up in a burst.
      paced_from_ = out_;
      pace_start_ = now - std::chrono::duration_cast<Clock::duration>(Seconds(slack));
      return;
    }
    if (ahead <= 0) return;
    std::this_thread::sleep_for(Seconds(std::min(ahead, 0.05)));
  }
}

void AtomicFileWriter::WriteBehind(size_t offset, size_t size, bool drop) {
  if (fd_ < 0 || size == 0) return;
  if (offset + size > written_ - buffered_) Flush();
  ::sync_file_range(
      fd_, static_cast<off_t>(offset), static_cast<off_t>(size),
      SYNC_FILE_RANGE_WAIT_BEFORE | SYNC_FILE_RANGE_WRITE | SYNC_FILE_RANGE_WAIT_AFTER);
  if (drop) {
    ::posix_fadvise(fd_, static_cast<off_t>(offset), static_cast<off_t>(size), POSIX_FADV_DONTNEED);
  }
}

void AtomicFileWriter::Commit() { Publish(false); }

std::shared_ptr<const MappedFile> AtomicFileWriter::CommitAndMap() { return Publish(true); }

std::shared_ptr<const MappedFile> AtomicFileWriter::Publish(bool map) {
  if (fd_ < 0) throw std::logic_error("AtomicFileWriter: commit after commit or failure");
  Flush();
  if (::fsync(fd_) != 0) Fail(Errno());
  std::shared_ptr<const MappedFile> mapped;
  if (map) {
    // Mapped before the rename: the mapping holds exactly these bytes, whatever replaces the
    // path later.
    try {
      mapped = MappedFile::FromDescriptor(fd_, path_);
    } catch (const std::exception& e) {
      Fail(e.what());
    }
  }
  const int fd = fd_;
  fd_ = -1;
  if (::close(fd) != 0) {
    const std::string why = Errno();
    ::unlink(tmp_.c_str());
    throw std::runtime_error("cannot write '" + path_.string() + "': " + why);
  }
  if (::rename(tmp_.c_str(), path_.c_str()) != 0) {
    const std::string why = Errno();
    ::unlink(tmp_.c_str());
    throw std::runtime_error("cannot write '" + path_.string() + "': " + why);
  }
  // The rename itself is durable once the directory is flushed (best effort: some file
  // systems refuse fsync on a directory, and the file is complete either way).
  const fs::path dir = path_.has_parent_path() ? path_.parent_path() : fs::path(".");
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
  return mapped;
}

std::shared_ptr<const MappedFile> MappedFile::Open(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw std::runtime_error("cannot read '" + path.string() + "': " + Errno());
  try {
    auto m = FromDescriptor(fd, path);
    ::close(fd);  // the mapping keeps the file
    return m;
  } catch (...) {
    ::close(fd);
    throw;
  }
}

std::shared_ptr<const MappedFile> MappedFile::FromDescriptor(int fd, const fs::path& path) {
  struct stat st {};
  const bool stat_ok = ::fstat(fd, &st) == 0;
  if (!stat_ok || !S_ISREG(st.st_mode)) {
    const std::string why = stat_ok ? std::string("not a regular file") : Errno();
    throw std::runtime_error("cannot read '" + path.string() + "': " + why);
  }
  const size_t size = static_cast<size_t>(st.st_size);
  void* p = nullptr;
  if (size > 0) {
    p = ::mmap(nullptr, size, PROT_READ, MAP_PRIVATE, fd, 0);
    if (p == MAP_FAILED) {
      throw std::runtime_error("cannot map '" + path.string() + "': " + Errno());
    }
  }
  return std::shared_ptr<const MappedFile>(new MappedFile(static_cast<const char*>(p), size));
}

MappedFile::~MappedFile() {
  if (size_ > 0) ::munmap(const_cast<char*>(data_), size_);
}

void AdviseWillNeed(const void* data, size_t size) {
  if (data == nullptr || size == 0) return;
  static const uintptr_t page = static_cast<uintptr_t>(::sysconf(_SC_PAGESIZE));
  const uintptr_t begin = reinterpret_cast<uintptr_t>(data) & ~(page - 1);
  const uintptr_t end = reinterpret_cast<uintptr_t>(data) + size;
  ::madvise(reinterpret_cast<void*>(begin), end - begin, MADV_WILLNEED);
}

std::string ReadFile(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw std::runtime_error("cannot read '" + path.string() + "': " + Errno());
  std::string data;
  struct stat st {};
  if (::fstat(fd, &st) == 0 && S_ISREG(st.st_mode)) data.reserve(static_cast<size_t>(st.st_size));
  char buf[1 << 16];
  for (;;) {
    // Straight into the string when its size is known, through a buffer otherwise.
    if (data.capacity() > data.size()) {
      const size_t old = data.size();
      data.resize(data.capacity());
      const ssize_t n = ::read(fd, data.data() + old, data.size() - old);
      data.resize(old + static_cast<size_t>(std::max<ssize_t>(n, 0)));
      if (n > 0) continue;
      if (n == 0) break;
    } else {
      const ssize_t n = ::read(fd, buf, sizeof(buf));
      if (n > 0) {
        data.append(buf, static_cast<size_t>(n));
        continue;
      }
      if (n == 0) break;
    }
    if (errno == EINTR) continue;
    const std::string why = Errno();
    ::close(fd);
    throw std::runtime_error("error reading '" + path.string() + "': " + why);
  }
  ::close(fd);
  return data;
}

fs::path StageDirectory(const fs::path& target_in, bool force) {
  const fs::path target = fs::absolute(target_in).lexically_normal();
  std::error_code ec;
  const fs::file_status st = fs::status(target, ec);
  if (fs::exists(st)) {
    if (!fs::is_directory(st)) {
      throw std::runtime_error("output '" + target.string() + "' exists and is not a directory");
    }
    if (!fs::is_empty(target, ec) && !force) {
      throw std::runtime_error("output directory '" + target.string() +
                               "' exists and is not empty; pass --force to replace it");
    }
  }
  fs::path parent = target.parent_path();
  if (!fs::exists(parent)) {
    fs::create_directories(parent, ec);
    if (ec) {
      throw std::runtime_error("cannot create '" + parent.string() + "': " + ec.message());
    }
  }
  const fs::path staging =
      parent / ("." + target.filename().string() + ".staging-" + RandomSuffix());
  if (!fs::create_directory(staging, ec) || ec) {
    throw std::runtime_error("cannot write to '" + parent.string() +
                             "': " + (ec ? ec.message() : std::string("staging directory exists")));
  }
  return staging;
}

void CommitStagedDirectory(const fs::path& staging, const fs::path& target_in) {
  const fs::path target = fs::absolute(target_in).lexically_normal();
  std::error_code ec;
  fs::path old;
  if (fs::exists(target)) {
    old = target.parent_path() / ("." + target.filename().string() + ".old-" + RandomSuffix());
    fs::rename(target, old, ec);
    if (ec) {
      throw std::runtime_error("cannot replace '" + target.string() + "': " + ec.message());
    }
  }
  fs::rename(staging, target, ec);
  if (ec) {
    const std::string why = ec.message();
    if (!old.empty()) fs::rename(old, target, ec);  // put the previous output back
    throw std::runtime_error("cannot move output into '" + target.string() + "': " + why);
  }
  if (!old.empty()) fs::remove_all(old, ec);
}

void DiscardStagedDirectory(const fs::path& staging) noexcept {
  std::error_code ec;
  fs::remove_all(staging, ec);
}

}  // namespace gtbow
