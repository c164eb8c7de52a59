// octofuse: a parallel loop whose exceptions reach the calling thread.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace octofuse::detail {

/// Runs f(i) for i in [0, n) on up to `threads` threads (the caller's included; dynamic
/// scheduling). An exception thrown by f on any thread (std::bad_alloc included) stops the
/// loop and is rethrown on the calling thread once every thread has ended; the first one wins.
/// If the system refuses to start a thread, the loop runs on the threads it has.
template <class F>
void parallel_for(std::size_t n, unsigned threads, F f) {
  const std::size_t nt = std::min<std::size_t>(std::max(1u, threads), n);
  if (nt <= 1) {
    for (std::size_t i = 0; i < n; ++i) f(i);
    return;
  }
  std::atomic<std::size_t> next{0};
  std::atomic<bool> failed{false};
  std::exception_ptr error;
  std::mutex error_mutex;
  auto work = [&]() noexcept {
    try {
      for (std::size_t i = next++; i < n && !failed.load(std::memory_order_relaxed); i = next++) {
        f(i);
      }
    } catch (...) {
      const std::lock_guard<std::mutex> lock(error_mutex);
      if (!error) error = std::current_exception();
      failed = true;
    }
  };
  std::vector<std::thread> pool;
  try {
    pool.reserve(nt - 1);
    for (std::size_t t = 1; t < nt; ++t) pool.emplace_back(work);
  } catch (...) {
    // fewer threads than asked (std::system_error or std::bad_alloc): go on with those started
  }
  work();
  for (auto& th : pool) th.join();
  if (error) std::rethrow_exception(error);
}

/// Runs f(i) for i in [0, workers), each on a thread of its own, while the calling thread waits:
/// for work that allocates, so that the allocations come from the workers' own free lists and
/// do not contend with the caller's. An index whose thread the system refuses runs on the
/// caller after the others started. Exceptions as in parallel_for: the first one is rethrown
/// on the calling thread once every thread has ended.
template <class F>
void run_on_workers(std::size_t workers, F f) {
  std::exception_ptr error;
  std::mutex error_mutex;
  auto work = [&](std::size_t i) noexcept {
    try {
      f(i);
    } catch (...) {
      const std::lock_guard<std::mutex> lock(error_mutex);
      if (!error) error = std::current_exception();
    }
  };
  std::vector<std::thread> pool;
  std::size_t started = 0;
  try {
    pool.reserve(workers);
    for (; started < workers; ++started) pool.emplace_back(work, started);
  } catch (...) {
    // fewer threads than asked: the caller runs the rest
  }
  for (std::size_t i = started; i < workers; ++i) work(i);
  for (auto& th : pool) th.join();
  if (error) std::rethrow_exception(error);
}

}  // namespace octofuse::detail
