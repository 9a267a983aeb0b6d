// A thread-safe terminal progress bar for long jobs (training, rendering, evaluation).
// Writes to stderr: redrawn in place on a terminal, as occasional plain lines otherwise.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdio>
#include <mutex>
#include <string>

namespace gtbow {

class ProgressBar {
 public:
  // `total` units of work labelled `label`; `enabled` false makes every call a no-op.
  ProgressBar(std::string label, size_t total, bool enabled = true, FILE* out = stderr);
  ~ProgressBar();
  ProgressBar(const ProgressBar&) = delete;
  ProgressBar& operator=(const ProgressBar&) = delete;

  // Adds `n` finished units; safe to call from several threads.
  void Add(size_t n = 1);
  // Draws the final state and ends the line; called by the destructor if not before.
  void Finish();

  size_t done() const { return done_; }

 private:
  void Draw(bool final);  // requires mutex_ held

  std::string label_;
  size_t total_;
  bool enabled_;
  FILE* out_;
  bool tty_;
  bool finished_ = false;
  size_t done_ = 0;  // guarded by mutex_
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_draw_;
  std::mutex mutex_;
};

}  // namespace gtbow
