#include "checkpoint.hpp"

#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <utility>

namespace hxmap::rt {

CheckpointWriter::CheckpointWriter(std::function<void(const MapCheckpoint&)> write, int nice)
    : write_(std::move(write)), nice_(nice) {
  thread_ = std::thread([this] { run(); });
}

CheckpointWriter::~CheckpointWriter() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
    pending_.reset();
  }
  wake_.notify_one();
  thread_.join();
}

void CheckpointWriter::offer(MapCheckpoint&& checkpoint) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    pending_ = std::move(checkpoint);
  }
  wake_.notify_one();
}

uint64_t CheckpointWriter::written() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return written_;
}

void CheckpointWriter::run() {
  pthread_setname_np(pthread_self(), "hx-checkpoint");
  // Linux nice values are per thread: the frontend keeps the cores first.
  if (nice_ > 0) (void)setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), nice_);
  for (;;) {
    MapCheckpoint c;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [this] { return stop_ || pending_.has_value(); });
      if (stop_) return;
      c = std::move(*pending_);
      pending_.reset();
    }
    write_(c);
    std::lock_guard<std::mutex> lock(mutex_);
    ++written_;
  }
}

}  // namespace hxmap::rt
