// The DDS publisher as the hxmap program configures and reports it.
#pragma once

#include <string>

#include "hxmap/config/config.hpp"
#include "hxmap/core/expected.hpp"
#include "hxmap/dds/publisher.hpp"

namespace hxmap::rt {

/// The publisher's settings; Error when the domain comes from a bad
/// ROS_DOMAIN_ID (see ddsDomain).
Expected<dds::PublisherParams> publisherParams(const HxmapConfig& config);
/// `configured` (dds.domain_id) when >= 0; otherwise ROS_DOMAIN_ID from the
/// environment as ROS 2 reads it (unset or empty: 0), an Error naming the
/// variable when it is not an integer in [0, 232].
Expected<uint32_t> ddsDomain(int configured);
/// The summary's lines about what was published.
std::string publisherStatsText(const dds::PublisherStats& stats, double wall_s);

}  // namespace hxmap::rt
