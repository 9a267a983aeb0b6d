#include "ground_texture_bow/core/progress.h"

#include <unistd.h>

#include <algorithm>

namespace gtbow {

ProgressBar::ProgressBar(std::string label, size_t total, bool enabled, FILE* out)
    : label_(std::move(label)),
      total_(total),
      enabled_(enabled),
      out_(out),
      tty_(::isatty(::fileno(out)) != 0),
      start_(std::chrono::steady_clock::now()),
      last_draw_(start_ - std::chrono::hours(1)) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (enabled_) Draw(false);
}

ProgressBar::~ProgressBar() { Finish(); }

void ProgressBar::Add(size_t n) {
  std::lock_guard<std::mutex> lock(mutex_);
  done_ = std::min(total_, done_ + n);
  if (!enabled_ || finished_) return;
  const auto now = std::chrono::steady_clock::now();
  // Redraw at most 10 times a second on a terminal, every 10 s in a log.
  const auto period = tty_ ? std::chrono::milliseconds(100) : std::chrono::milliseconds(10000);
  if (now - last_draw_ >= period) Draw(false);
}

void ProgressBar::Finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  finished_ = true;
  if (enabled_) Draw(true);
}

void ProgressBar::Draw(bool final) {
  last_draw_ = std::chrono::steady_clock::now();
  const double elapsed = std::chrono::duration<double>(last_draw_ - start_).count();
  const double frac = total_ > 0 ? static_cast<double>(done_) / total_ : 1.0;
  const double rate = elapsed > 0 ? done_ / elapsed : 0.0;
  const double eta = rate > 0 ? (total_ - done_) / rate : 0.0;
  constexpr int kWidth = 30;
  const int filled = static_cast<int>(frac * kWidth);
  char bar[kWidth + 1];
  for (int i = 0; i < kWidth; ++i) bar[i] = i < filled ? '=' : (i == filled ? '>' : ' ');
  bar[kWidth] = '\0';
  const double shown = final ? elapsed : eta;
  std::fprintf(out_, "%s%-12s [%s] %zu/%zu %3.0f%% %7.1f/s %s %02d:%02d%s", tty_ ? "\r" : "",
               label_.c_str(), bar, done_, total_, 100.0 * frac, rate, final ? "took" : "ETA",
               static_cast<int>(shown) / 60, static_cast<int>(shown) % 60,
               (final || !tty_) ? "\n" : "");
  std::fflush(out_);
}

}  // namespace gtbow
