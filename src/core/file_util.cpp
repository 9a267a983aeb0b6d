#include "ground_texture_bow/core/file_util.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <random>
#include <sstream>
#include <stdexcept>

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
  const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
  const fs::path tmp = dir / ("." + path.filename().string() + ".tmp-" + RandomSuffix());
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) {
    throw std::runtime_error("cannot write '" + path.string() + "': " + Errno());
  }
  for (std::string_view piece : pieces) {
    size_t done = 0;
    while (done < piece.size()) {
      const ssize_t n = ::write(fd, piece.data() + done, piece.size() - done);
      if (n < 0) {
        if (errno == EINTR) continue;
        const std::string why = Errno();
        ::close(fd);
        ::unlink(tmp.c_str());
        throw std::runtime_error("cannot write '" + path.string() + "': " + why);
      }
      done += static_cast<size_t>(n);
    }
  }
  if (::fsync(fd) != 0 || ::close(fd) != 0) {
    const std::string why = Errno();
    ::unlink(tmp.c_str());
    throw std::runtime_error("cannot write '" + path.string() + "': " + why);
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = Errno();
    ::unlink(tmp.c_str());
    throw std::runtime_error("cannot write '" + path.string() + "': " + why);
  }
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
    throw std::runtime_error("cannot write to '" + parent.string() + "': " +
                             (ec ? ec.message() : std::string("staging directory exists")));
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
