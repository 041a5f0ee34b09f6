// ROS 2 type hashes (REP 2011, "RIHS01"), as ROS 2 Jazzy's rosidl computes
// them, for the types hxmap puts on the wire: rmw_cyclonedds reads
// `typehash=RIHS01_<hex>;` from every endpoint's USER_DATA (and `enclave=/;`
// from the participant's) to place a DDS endpoint in the ROS graph.
//
// The hashes come from the IDL hxmap's wire types are compiled from (the
// ROS 2 convention: module <pkg>::msg::dds_, struct <Name>_, fields in the
// .msg order), so they cannot drift from what is sent.
#pragma once

#include <map>
#include <string>
#include <string_view>

#include "hxmap/core/expected.hpp"

namespace hxmap::rt::dds {

/// SHA-256 of `data` as 64 lowercase hex digits (FIPS 180-4).
std::string sha256Hex(std::string_view data);

/// Every struct of an IDL text in ROS 2's wire convention, by its DDS type
/// name ("geometry_msgs::msg::dds_::PoseStamped_"), with its RIHS01 hash
/// ("RIHS01_<64 hex>"). Errors name `source` and the line.
Expected<std::map<std::string, std::string>> rosTypeHashes(const std::string& idl, const std::string& source);

/// The hashes of hxmap's own wire types (hxmap_msgs.idl, computed once).
const std::map<std::string, std::string>& wireTypeHashes();

}  // namespace hxmap::rt::dds
