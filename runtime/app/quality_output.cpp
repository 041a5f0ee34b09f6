#include "quality_output.hpp"

#include <filesystem>
#include <unordered_set>

#include <fmt/format.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "hxmap/dataset/ply.hpp"

namespace hxmap::rt {

namespace fs = std::filesystem;

Status writeKeyframeQuality(const std::string& dir, const Frontend& frontend, uint32_t keyframe_id) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return Error{dir + ": cannot create the quality folder: " + ec.message()};
  const alg::PreprocessedFrame& frame = frontend.lastFrame();
  // The level the quality module sampled (the model level).
  const alg::FrameLevel* level = &frame.levels.front();
  for (const auto& l : frame.levels) {
    if (!l.normal.empty()) {
      level = &l;
      break;
    }
  }
  const Eigen::Isometry3f T_world_cam = frontend.lastPose().cast<float>();
  for (int k = 0; k <= alg::kIndicatorCount; ++k) {
    const cv::Mat values =
        alg::indicatorImage(frontend.blockScores(), *level, T_world_cam, frontend.map().blockSize(), k);
    cv::Mat image = alg::overlayHeatmap(frame.rgb, values);
    if (k == alg::kIndicatorCount) alg::drawRoiBoxes(image, frontend.rois(), frontend.camera(), T_world_cam);
    cv::cvtColor(image, image, cv::COLOR_RGB2BGR);
    const std::string path = (fs::path(dir) / fmt::format("kf{:04d}_{}.png", keyframe_id, alg::indicatorName(k))).string();
    try {
      if (!cv::imwrite(path, image)) return Error{path + ": cannot write the image"};
    } catch (const cv::Exception& e) {
      return Error{path + ": cannot write the image: " + e.what()};
    }
  }
  return {};
}

Status writeQualityMaps(const std::string& dir, const Frontend& frontend) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return Error{dir + ": cannot create the quality folder: " + ec.message()};
  std::vector<Eigen::AlignedBox3f> boxes;
  std::unordered_set<uint64_t> chosen;
  const auto pack = alg::packBlockKey;
  for (const auto& roi : frontend.rois()) {
    boxes.push_back(roi.box_world);
    for (const auto& k : roi.blocks) chosen.insert(pack(k));
  }
  if (auto s = drv::writePlyBoxes((fs::path(dir) / "rois.ply").string(), boxes); !s) return s;
  std::string csv = "bx,by,bz,cgn,uf,obg,rm,cgn_n,uf_n,obg_n,rm_n,priority,chosen\n";
  for (const auto& s : frontend.blockScores()) {
    csv += fmt::format("{},{},{},{:.5f},{:.5f},{:.5f},{:.5f},{:.4f},{:.4f},{:.4f},{:.4f},{:.4f},{}\n", s.key.x(),
                       s.key.y(), s.key.z(), s.raw[0], s.raw[1], s.raw[2], s.raw[3], s.normalized[0], s.normalized[1],
                       s.normalized[2], s.normalized[3], s.priority, chosen.count(pack(s.key)) ? 1 : 0);
  }
  return drv::writeTextFile((fs::path(dir) / "blocks.csv").string(), csv);
}

std::string qualityText(const Frontend& frontend) {
  size_t chosen = 0;
  for (const auto& roi : frontend.rois()) chosen += roi.blocks.size();
  return fmt::format("quality: {} blocks scored, {} chosen for refinement in {} ROIs (as of the last keyframe)\n",
                     frontend.blockScores().size(), chosen, frontend.rois().size());
}

}  // namespace hxmap::rt
