// The DDS publisher as the hxmap program configures and reports it.
#pragma once

#include <string>

#include "hxmap/config/config.hpp"
#include "hxmap/dds/publisher.hpp"

namespace hxmap::rt {

dds::PublisherParams publisherParams(const HxmapConfig& config);
/// The summary's lines about what was published.
std::string publisherStatsText(const dds::PublisherStats& stats, double wall_s);

}  // namespace hxmap::rt
