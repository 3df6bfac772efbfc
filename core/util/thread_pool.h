// A fixed pool of worker threads running one parallel loop at a time. Work items are handed
// out through an atomic counter, so fast threads take more tiles (dynamic load balancing).
#pragma once
#include <atomic>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace pl {

class ThreadPool {
 public:
  explicit ThreadPool(int threads) {
    const int n = threads > 0 ? threads : std::max(1u, std::thread::hardware_concurrency());
    for (int i = 0; i < n; ++i) workers_.emplace_back([this, i] { worker(i); });
  }
  ~ThreadPool() {
    {
      std::lock_guard<std::mutex> lk(m_);
      quit_ = true;
    }
    cv_start_.notify_all();
    for (auto& t : workers_) t.join();
  }
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int size() const { return static_cast<int>(workers_.size()); }

  // Runs fn(item, thread_index) for item in [0, count) and returns when all are done.
  void parallel_for(size_t count, const std::function<void(size_t, int)>& fn) {
    if (count == 0) return;
    std::unique_lock<std::mutex> lk(m_);
    fn_ = &fn;
    count_ = count;
    next_.store(0);
    busy_ = static_cast<int>(workers_.size());
    ++generation_;
    cv_start_.notify_all();
    cv_done_.wait(lk, [this] { return busy_ == 0; });
    fn_ = nullptr;
  }

 private:
  void worker(int index) {
    uint64_t seen = 0;
    for (;;) {
      const std::function<void(size_t, int)>* fn;
      size_t count;
      {
        std::unique_lock<std::mutex> lk(m_);
        cv_start_.wait(lk, [&] { return quit_ || generation_ != seen; });
        if (quit_) return;
        seen = generation_;
        fn = fn_;
        count = count_;
      }
      for (size_t i = next_.fetch_add(1); i < count; i = next_.fetch_add(1)) (*fn)(i, index);
      std::lock_guard<std::mutex> lk(m_);
      if (--busy_ == 0) cv_done_.notify_all();
    }
  }

  std::vector<std::thread> workers_;
  std::mutex m_;
  std::condition_variable cv_start_, cv_done_;
  const std::function<void(size_t, int)>* fn_ = nullptr;
  size_t count_ = 0;
  std::atomic<size_t> next_{0};
  int busy_ = 0;
  uint64_t generation_ = 0;
  bool quit_ = false;
};

}  // namespace pl
