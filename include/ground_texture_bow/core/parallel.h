// Parallel loops: the one place where the package starts worker threads for data-parallel work
// (the node's worker thread and the tests' concurrency aside).
//
// Every loop runs its first part on the calling thread, joins every thread it started, and then
// rethrows the first exception any part threw (the lowest part's, for ParallelParts), so a
// failing worker never calls std::terminate and never leaves a thread running.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace gtbow {

// `requested` threads, or every core for 0 or less (at least 1).
inline int ThreadCount(int requested) {
  return requested > 0 ? requested
                       : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

// Runs task(t) for t in [0, tasks), each on its own thread (task 0 on the calling thread).
template <typename F>
void RunTasks(int tasks, F&& task) {
  if (tasks <= 1) {
    if (tasks == 1) task(0);
    return;
  }
  std::vector<std::exception_ptr> errors(static_cast<size_t>(tasks));
  auto guarded = [&](int t) {
    try {
      task(t);
    } catch (...) {
      errors[static_cast<size_t>(t)] = std::current_exception();
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(static_cast<size_t>(tasks - 1));
  try {
    for (int t = 1; t < tasks; ++t) pool.emplace_back(guarded, t);
  } catch (...) {
    for (auto& th : pool) th.join();
    throw;  // the system refused a thread
  }
  guarded(0);
  for (auto& th : pool) th.join();
  for (const auto& e : errors) {
    if (e) std::rethrow_exception(e);
  }
}

// Runs body(begin, end, part) over [0, n) cut into contiguous parts of ceil(n / parts) items,
// parts = min(threads, n / min_per_part + 1) (threads: 0 = every core). Parts depend only on n,
// threads and min_per_part, so a reduction over parts is reproducible.
template <typename F>
void ParallelParts(size_t n, int threads, size_t min_per_part, F&& body) {
  if (n == 0) return;
  const size_t cap = n / std::max<size_t>(1, min_per_part) + 1;
  const int parts =
      static_cast<int>(std::max<size_t>(1, std::min<size_t>(ThreadCount(threads), cap)));
  const size_t chunk = (n + parts - 1) / parts;
  RunTasks(parts, [&](int t) {
    const size_t b = static_cast<size_t>(t) * chunk, e = std::min(n, b + chunk);
    if (b < e) body(b, e, t);
  });
}

// Runs body(state, i) for every i in [0, n), items handed out one at a time to `threads`
// threads (0 = every core); each thread makes its state once with make_state(). After an
// exception no further items are handed out.
template <typename MakeState, typename F>
void ParallelForEach(size_t n, int threads, MakeState&& make_state, F&& body) {
  if (n == 0) return;
  const int nt = static_cast<int>(std::min<size_t>(ThreadCount(threads), n));
  std::atomic<size_t> next{0};
  RunTasks(nt, [&](int) {
    auto state = make_state();
    for (size_t i; (i = next.fetch_add(1)) < n;) {
      try {
        body(state, i);
      } catch (...) {
        next = n;  // stop handing out items
        throw;
      }
    }
  });
}

// Runs body(i) for every i in [0, n), items handed out one at a time (see above).
template <typename F>
void ParallelForEach(size_t n, int threads, F&& body) {
  ParallelForEach(
      n, threads, [] { return 0; }, [&](int, size_t i) { body(i); });
}

}  // namespace gtbow
