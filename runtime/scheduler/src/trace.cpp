#include "hxmap/scheduler/trace.hpp"

#include <algorithm>
#include <fstream>
#include <map>
#include <sstream>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

namespace hxmap::rt {

void TraceRecorder::add(TraceEvent event) {
  std::lock_guard<std::mutex> lock(mutex_);
  events_.push_back(std::move(event));
}

void TraceRecorder::nameThread(int thread, std::string name) {
  std::lock_guard<std::mutex> lock(mutex_);
  thread_names_.emplace_back(thread, std::move(name));
}

size_t TraceRecorder::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return events_.size();
}

namespace {
std::string escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) >= 0x20) out += c;
  }
  return out;
}
}  // namespace

std::string TraceRecorder::toJson() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::string out = "{\"displayTimeUnit\":\"ms\",\"traceEvents\":[\n";
  bool first = true;
  for (const auto& [tid, name] : thread_names_) {
    out += fmt::format("{}{{\"name\":\"thread_name\",\"ph\":\"M\",\"pid\":1,\"tid\":{},\"args\":{{\"name\":\"{}\"}}}}",
                       first ? "" : ",\n", tid, escape(name));
    first = false;
  }
  for (const auto& e : events_) {
    // Chrome traces count microseconds; three decimals keep nanoseconds.
    out += fmt::format(
        "{}{{\"name\":\"{}\",\"cat\":\"{}\",\"ph\":\"X\",\"ts\":{:.3f},\"dur\":{:.3f},\"pid\":1,\"tid\":{},"
        "\"args\":{{\"frame\":{},\"stamp_ns\":{}}}}}",
        first ? "" : ",\n", escape(e.name), escape(e.category), static_cast<double>(e.start_ns) * 1e-3,
        static_cast<double>(e.duration_ns) * 1e-3, e.thread, e.frame, e.stamp_ns);
    first = false;
  }
  out += "\n]}\n";
  return out;
}

Status TraceRecorder::write(const std::string& path) const {
  std::ofstream f(path, std::ios::binary);
  if (!f) return Error{path + ": cannot open for writing"};
  f << toJson();
  f.close();
  if (!f) return Error{path + ": write failed (disk full?)"};
  return {};
}

Expected<std::vector<TraceEvent>> parseTrace(const std::string& json, const std::string& source) {
  YAML::Node root;
  try {
    root = YAML::Load(json);  // JSON is YAML
  } catch (const YAML::Exception& e) {
    return Error{fmt::format("{}:{}: not valid JSON: {}", source, e.mark.line + 1, e.msg)};
  }
  const YAML::Node list = root.IsMap() ? root["traceEvents"] : YAML::Node();
  if (!list || !list.IsSequence()) return Error{source + ": no \"traceEvents\" array (not a Chrome trace)"};
  std::vector<TraceEvent> events;
  for (size_t i = 0; i < list.size(); ++i) {
    const YAML::Node e = list[i];
    try {
      if (!e.IsMap() || !e["ph"] || e["ph"].as<std::string>() != "X") continue;
      TraceEvent t;
      t.name = e["name"] ? e["name"].as<std::string>() : "";
      t.category = e["cat"] ? e["cat"].as<std::string>() : "";
      t.start_ns = static_cast<int64_t>(std::llround(e["ts"].as<double>() * 1e3));
      t.duration_ns = static_cast<int64_t>(std::llround(e["dur"].as<double>() * 1e3));
      t.thread = e["tid"] ? e["tid"].as<int>() : 0;
      if (const YAML::Node a = e["args"]; a && a.IsMap()) {
        if (a["frame"]) t.frame = a["frame"].as<int64_t>();
        if (a["stamp_ns"]) t.stamp_ns = a["stamp_ns"].as<int64_t>();
      }
      if (t.duration_ns < 0) return Error{fmt::format("{}: event {} ('{}') has a negative duration", source, i, t.name)};
      events.push_back(std::move(t));
    } catch (const YAML::Exception& ex) {
      return Error{fmt::format("{}: event {}: missing or malformed field ({})", source, i, ex.msg)};
    }
  }
  return events;
}

Expected<std::vector<TraceEvent>> readTrace(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return Error{path + ": cannot open the trace"};
  std::stringstream ss;
  ss << f.rdbuf();
  return parseTrace(ss.str(), path);
}

Expected<std::vector<ReplayFrame>> replayFramesFromTrace(const std::vector<TraceEvent>& events, double fps) {
  static const char* kStages[4] = {"preprocess", "track", "integrate", "raycast"};
  struct Acc {
    std::array<double, 4> ms{};
    std::array<bool, 4> seen{};
    int64_t stamp_ns = -1;
  };
  std::map<int64_t, Acc> by_frame;
  for (const auto& e : events) {
    if (e.frame < 0 || e.category != "frontend") continue;
    for (int s = 0; s < 4; ++s) {
      if (e.name == kStages[s]) {
        Acc& a = by_frame[e.frame];
        a.ms[static_cast<size_t>(s)] += static_cast<double>(e.duration_ns) * 1e-6;
        a.seen[static_cast<size_t>(s)] = true;
        if (e.stamp_ns >= 0) a.stamp_ns = e.stamp_ns;
      }
    }
  }
  if (by_frame.empty()) return Error{"trace: no frontend stage events with a frame number"};
  std::vector<ReplayFrame> frames;
  int64_t first_stamp = -1;
  size_t k = 0;
  for (const auto& [frame, a] : by_frame) {
    for (int s = 0; s < 4; ++s) {
      // Frames that failed tracking have no track/integrate/raycast events:
      // those stages cost 0 there. Only preprocess is required.
      if (s == 0 && !a.seen[0]) return Error{fmt::format("trace: frame {} has no preprocess event", frame)};
    }
    ReplayFrame f;
    f.stage_ms = a.ms;
    if (fps > 0) {
      f.arrival_ns = static_cast<int64_t>(std::llround(static_cast<double>(k) * 1e9 / fps));
    } else {
      if (a.stamp_ns < 0) return Error{fmt::format("trace: frame {} has no sensor stamp (give an fps)", frame)};
      if (first_stamp < 0) first_stamp = a.stamp_ns;
      f.arrival_ns = a.stamp_ns - first_stamp;
    }
    frames.push_back(f);
    ++k;
  }
  return frames;
}

}  // namespace hxmap::rt
