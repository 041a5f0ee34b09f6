// Timing traces: per frame and stage, start, duration and thread, written as
// Chrome trace-event JSON (opens in Perfetto and chrome://tracing) and read
// back for replay tests.
//
// Threads: TraceRecorder::add may be called from any thread (a mutex guards
// the event list; a few events per frame, off the hot loops).
#pragma once

#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

#include "hxmap/core/expected.hpp"
#include "hxmap/scheduler/replay.hpp"

namespace hxmap::rt {

struct TraceEvent {
  std::string name;      ///< stage: preprocess, track, integrate, raycast, frame, refine, ...
  std::string category;  ///< frontend, background, sensor
  int64_t start_ns = 0;  ///< steady clock, relative to the recorder's origin
  int64_t duration_ns = 0;
  int thread = 0;         ///< small id; names via TraceRecorder::nameThread
  int64_t frame = -1;     ///< frame sequence number, -1 if none
  int64_t stamp_ns = -1;  ///< the frame's sensor timestamp, -1 if none
};

class TraceRecorder {
 public:
  void add(TraceEvent event);
  void nameThread(int thread, std::string name);
  size_t size() const;
  std::string toJson() const;
  Status write(const std::string& path) const;

 private:
  mutable std::mutex mutex_;
  std::vector<TraceEvent> events_;
  std::vector<std::pair<int, std::string>> thread_names_;
};

/// Parses Chrome trace-event JSON as written by TraceRecorder ("X" events;
/// others are ignored). Errors name `source`.
Expected<std::vector<TraceEvent>> parseTrace(const std::string& json, const std::string& source);
Expected<std::vector<TraceEvent>> readTrace(const std::string& path);

/// Frames for replay from a trace's frontend stage events: stage costs as
/// recorded; arrivals at the recorded sensor stamps, or at `fps` when > 0.
/// Frames lacking a stage event are an error naming the frame.
Expected<std::vector<ReplayFrame>> replayFramesFromTrace(const std::vector<TraceEvent>& events, double fps = 0);

}  // namespace hxmap::rt
