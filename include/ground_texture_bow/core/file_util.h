// Small filesystem helpers shared by every writer in the package: atomic writes and checks on
// output directories. All paths are std::filesystem paths; errors throw std::runtime_error
// naming the path and the reason.
#pragma once

#include <filesystem>
#include <initializer_list>
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
