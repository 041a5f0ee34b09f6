// A thin RAII layer over Cyclone DDS's C API (Debian ships no C++ binding):
// entities are owned by move-only handles and deleted in reverse order of
// creation, every return code is checked and turned into an Error that names
// the call, the topic and Cyclone's reason. Samples are the C structs idlc
// generates from runtime/dds/idl/hxmap_msgs.idl; messages.hpp converts them.
//
// Thread safety: Cyclone's entities may be used from any thread; one Writer
// or Reader object is used by one thread at a time.
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include <dds/dds.h>

#include "hxmap/core/expected.hpp"

namespace hxmap::rt::dds {

/// "what: Cyclone's text for rc".
Error ddsError(const std::string& what, dds_return_t rc);

/// Owns one entity handle (participant, topic, writer, reader, waitset).
class Entity {
 public:
  Entity() = default;
  explicit Entity(dds_entity_t handle) : handle_(handle) {}
  ~Entity() { reset(); }
  Entity(Entity&& other) noexcept : handle_(other.handle_) { other.handle_ = 0; }
  Entity& operator=(Entity&& other) noexcept {
    if (this != &other) {
      reset();
      handle_ = other.handle_;
      other.handle_ = 0;
    }
    return *this;
  }
  Entity(const Entity&) = delete;
  Entity& operator=(const Entity&) = delete;

  dds_entity_t get() const { return handle_; }
  explicit operator bool() const { return handle_ > 0; }
  void reset();

 private:
  dds_entity_t handle_ = 0;
};

/// Delivery guarantees of a topic (both ends use the same).
struct TopicQos {
  bool reliable = true;
  bool transient_local = false;  ///< late joiners receive the history kept by the writer
  int depth = 1;                 ///< keep-last depth per instance
  /// Writers keep every sample until each reliable reader has it (a write
  /// waits for a slow reader, up to max_blocking_s, instead of replacing a
  /// sample not yet delivered); late joiners still get `depth` samples.
  /// For topics whose samples are increments, not states.
  bool keep_all = false;
  double max_blocking_s = 0.1;
};

class Participant {
 public:
  /// Joins `domain_id` with the configuration in CYCLONEDDS_URI (Cyclone's
  /// defaults when unset).
  static Expected<Participant> create(uint32_t domain_id);
  dds_entity_t get() const { return entity_.get(); }

 private:
  Entity entity_;
};

class Writer {
 public:
  static Expected<Writer> create(const Participant& participant, const dds_topic_descriptor_t* type,
                                 const std::string& topic, const TopicQos& qos);
  /// Serializes `sample` (an idlc struct of the topic's type) and sends it.
  Status write(const void* sample);
  /// Readers currently matched (0 on error).
  uint32_t matchedReaders() const;
  /// Readers ever matched (a reader that came, went and came back counts twice).
  uint32_t matchedReadersTotal() const;
  /// Blocks until every reliable reader has acknowledged what was written,
  /// or `timeout_s` passes (false then).
  bool waitForAcks(double timeout_s) const;
  const std::string& topic() const { return topic_; }
  dds_entity_t get() const { return writer_.get(); }

 private:
  std::string topic_;
  Entity topic_entity_, writer_;
};

class Reader {
 public:
  static Expected<Reader> create(const Participant& participant, const dds_topic_descriptor_t* type,
                                 const std::string& topic, const TopicQos& qos);
  /// Blocks until data is available or `timeout_s` passes; true when data is there.
  Expected<bool> wait(double timeout_s);
  /// Takes up to `max` samples, calling `on_sample(sample, info)` for each
  /// one carrying data (loaned: valid during the call only). Returns how
  /// many carried data.
  Expected<size_t> take(const std::function<void(const void*, const dds_sample_info_t&)>& on_sample, size_t max = 64);
  uint32_t matchedWriters() const;
  const std::string& topic() const { return topic_; }

 private:
  std::string topic_;
  Entity topic_entity_, reader_, waitset_, condition_;
};

}  // namespace hxmap::rt::dds
