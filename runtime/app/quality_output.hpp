// What the quality module found, for people: per keyframe the indicators
// and the priority S as heat maps over the keyframe (ROI boxes drawn on S),
// and at the end the ROIs as a PLY wireframe and every block's scores.
#pragma once

#include <string>

#include "hxmap/core/expected.hpp"
#include "hxmap/frontend/frontend.hpp"

namespace hxmap::rt {

/// DIR/kf<id>_{cgn,uf,obg,rm,priority}.png for the keyframe just scored
/// (call right after process() returned a keyframe).
Status writeKeyframeQuality(const std::string& dir, const Frontend& frontend, uint32_t keyframe_id);

/// DIR/rois.ply (wireframe) and DIR/blocks.csv (per block: key, raw and
/// normalized indicators, S, chosen).
Status writeQualityMaps(const std::string& dir, const Frontend& frontend);

/// Summary lines: blocks scored, chosen, ROIs.
std::string qualityText(const Frontend& frontend);

}  // namespace hxmap::rt
