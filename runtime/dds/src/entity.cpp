#include "hxmap/dds/entity.hpp"

#include <memory>
#include <vector>

#include <fmt/format.h>

#include "hxmap/dds/type_hash.hpp"

namespace hxmap::rt::dds {

namespace {

struct QosDeleter {
  void operator()(dds_qos_t* q) const { dds_delete_qos(q); }
};
using QosPtr = std::unique_ptr<dds_qos_t, QosDeleter>;

// `type`'s ROS 2 type hash in USER_DATA, as rmw_cyclonedds sets it on the
// endpoints of ROS 2 nodes (Jazzy reads it to place the endpoint in the
// ROS graph and to check that both ends agree on the type).
void setTypeHash(dds_qos_t* qos, const dds_topic_descriptor_t* type) {
  const auto& hashes = wireTypeHashes();
  const auto it = hashes.find(type->m_typename);
  if (it == hashes.end()) return;
  const std::string user_data = "typehash=" + it->second + ";";
  dds_qset_userdata(qos, user_data.data(), user_data.size());
}

QosPtr makeQos(const TopicQos& q) {
  QosPtr qos(dds_create_qos());
  dds_qset_reliability(qos.get(), q.reliable ? DDS_RELIABILITY_RELIABLE : DDS_RELIABILITY_BEST_EFFORT,
                       static_cast<dds_duration_t>(q.max_blocking_s * 1e9));
  dds_qset_durability(qos.get(), q.transient_local ? DDS_DURABILITY_TRANSIENT_LOCAL : DDS_DURABILITY_VOLATILE);
  if (q.keep_all) {
    // Keep-all for delivery; what a late joiner gets is the durability
    // service's history (Cyclone serves transient-local data from it).
    dds_qset_history(qos.get(), DDS_HISTORY_KEEP_ALL, 0);
    dds_qset_durability_service(qos.get(), 0, DDS_HISTORY_KEEP_LAST, q.depth, DDS_LENGTH_UNLIMITED,
                                DDS_LENGTH_UNLIMITED, DDS_LENGTH_UNLIMITED);
  } else {
    dds_qset_history(qos.get(), DDS_HISTORY_KEEP_LAST, q.depth);
  }
  // XCDR1, stated rather than left to Cyclone's choice by the types'
  // extensibility (XCDR2 for appendable types): ROS 2's readers take XCDR1.
  const dds_data_representation_id_t xcdr1 = DDS_DATA_REPRESENTATION_XCDR1;
  dds_qset_data_representation(qos.get(), 1, &xcdr1);
  return qos;
}

Expected<Entity> createTopic(const Participant& participant, const dds_topic_descriptor_t* type, const std::string& topic) {
  const dds_entity_t t = dds_create_topic(participant.get(), type, topic.c_str(), nullptr, nullptr);
  if (t < 0) return ddsError(fmt::format("creating topic '{}' of type {}", topic, type->m_typename), t);
  return Entity(t);
}

}  // namespace

Error ddsError(const std::string& what, dds_return_t rc) {
  return Error{fmt::format("DDS: {}: {}", what, dds_strretcode(rc))};
}

void Entity::reset() {
  // Deleting a participant deletes its children: a handle whose parent went
  // first reports ALREADY_DELETED, which is fine here.
  if (handle_ > 0) dds_delete(handle_);
  handle_ = 0;
}

Expected<Participant> Participant::create(uint32_t domain_id) {
  // As a ROS 2 node's participant says it (the default security enclave).
  QosPtr qos(dds_create_qos());
  const std::string enclave = "enclave=/;";
  dds_qset_userdata(qos.get(), enclave.data(), enclave.size());
  const dds_entity_t p = dds_create_participant(domain_id, qos.get(), nullptr);
  if (p < 0) {
    return ddsError(fmt::format("creating a participant in domain {} (check CYCLONEDDS_URI and the network interface it names)",
                                domain_id),
                    p);
  }
  Participant out;
  out.entity_ = Entity(p);
  return out;
}

Expected<Writer> Writer::create(const Participant& participant, const dds_topic_descriptor_t* type,
                                const std::string& topic, const TopicQos& qos) {
  Writer w;
  w.topic_ = topic;
  auto t = createTopic(participant, type, topic);
  if (!t) return t.error();
  w.topic_entity_ = std::move(*t);
  const QosPtr q = makeQos(qos);
  setTypeHash(q.get(), type);
  const dds_entity_t h = dds_create_writer(participant.get(), w.topic_entity_.get(), q.get(), nullptr);
  if (h < 0) return ddsError(fmt::format("creating a writer on '{}'", topic), h);
  w.writer_ = Entity(h);
  return w;
}

Status Writer::write(const void* sample) {
  const dds_return_t rc = dds_write(writer_.get(), sample);
  if (rc != DDS_RETCODE_OK) return ddsError(fmt::format("writing to '{}'", topic_), rc);
  return Status::ok();
}

uint32_t Writer::matchedReaders() const {
  dds_publication_matched_status_t s{};
  if (dds_get_publication_matched_status(writer_.get(), &s) != DDS_RETCODE_OK) return 0;
  return s.current_count;
}

uint32_t Writer::matchedReadersTotal() const {
  dds_publication_matched_status_t s{};
  if (dds_get_publication_matched_status(writer_.get(), &s) != DDS_RETCODE_OK) return 0;
  return s.total_count;
}

bool Writer::waitForAcks(double timeout_s) const {
  return dds_wait_for_acks(writer_.get(), static_cast<dds_duration_t>(timeout_s * 1e9)) == DDS_RETCODE_OK;
}

Expected<Reader> Reader::create(const Participant& participant, const dds_topic_descriptor_t* type,
                                const std::string& topic, const TopicQos& qos) {
  Reader r;
  r.topic_ = topic;
  auto t = createTopic(participant, type, topic);
  if (!t) return t.error();
  r.topic_entity_ = std::move(*t);
  const QosPtr q = makeQos(qos);
  setTypeHash(q.get(), type);
  const dds_entity_t h = dds_create_reader(participant.get(), r.topic_entity_.get(), q.get(), nullptr);
  if (h < 0) return ddsError(fmt::format("creating a reader on '{}'", topic), h);
  r.reader_ = Entity(h);
  const dds_entity_t ws = dds_create_waitset(participant.get());
  if (ws < 0) return ddsError(fmt::format("creating a waitset for '{}'", topic), ws);
  r.waitset_ = Entity(ws);
  const dds_entity_t cond = dds_create_readcondition(h, DDS_ANY_STATE);
  if (cond < 0) return ddsError(fmt::format("creating a read condition on '{}'", topic), cond);
  r.condition_ = Entity(cond);
  const dds_return_t rc = dds_waitset_attach(ws, cond, 0);
  if (rc != DDS_RETCODE_OK) return ddsError(fmt::format("attaching the read condition of '{}'", topic), rc);
  return r;
}

Expected<bool> Reader::wait(double timeout_s) {
  const dds_return_t n = dds_waitset_wait(waitset_.get(), nullptr, 0, static_cast<dds_duration_t>(timeout_s * 1e9));
  if (n < 0) return ddsError(fmt::format("waiting for data on '{}'", topic_), n);
  return n > 0;
}

Expected<size_t> Reader::take(const std::function<void(const void*, const dds_sample_info_t&)>& on_sample, size_t max) {
  std::vector<void*> samples(max, nullptr);
  std::vector<dds_sample_info_t> infos(max);
  const dds_return_t n = dds_take(reader_.get(), samples.data(), infos.data(), max, static_cast<uint32_t>(max));
  if (n < 0) return ddsError(fmt::format("taking samples from '{}'", topic_), n);
  size_t valid = 0;
  for (dds_return_t i = 0; i < n; ++i) {
    if (!infos[static_cast<size_t>(i)].valid_data) continue;
    on_sample(samples[static_cast<size_t>(i)], infos[static_cast<size_t>(i)]);
    ++valid;
  }
  if (n > 0) {
    const dds_return_t rc = dds_return_loan(reader_.get(), samples.data(), n);
    if (rc != DDS_RETCODE_OK) return ddsError(fmt::format("returning samples to '{}'", topic_), rc);
  }
  return valid;
}

uint32_t Reader::matchedWriters() const {
  dds_subscription_matched_status_t s{};
  if (dds_get_subscription_matched_status(reader_.get(), &s) != DDS_RETCODE_OK) return 0;
  return s.current_count;
}

}  // namespace hxmap::rt::dds
