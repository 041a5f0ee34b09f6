// Map files: seconds and bytes per million voxels to save and load a map
// (hxmap run --save-map / --load-map), and the block store's cost per block
// moved out of memory and back (tsdf.max_resident_mib).
//
//   bench_mapfile MAP.hxm [RUNS]     (a map saved by hxmap run --save-map)
#include <cstdio>
#include <filesystem>
#include <string>

#include "bench_stats.hpp"
#include "hxmap/mapfile/block_store.hpp"
#include "hxmap/mapfile/map_file.hpp"

using namespace hxmap;

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: bench_mapfile MAP.hxm [RUNS]\n");
    return 2;
  }
  const std::string path = argv[1];
  const int runs = argc > 2 ? std::max(1, std::atoi(argv[2])) : 5;
  auto first = drv::loadMap(path);
  if (!first) {
    std::fprintf(stderr, "%s\n", first.message().c_str());
    return 1;
  }
  const double mvox = static_cast<double>(first->map.blockCount()) * alg::kBlockVoxels / 1e6;
  const std::string copy = (std::filesystem::temp_directory_path() / "bench_mapfile.hxm").string();
  std::vector<double> load_ms, save_ms, out_us, write_us, back_us;
  uint64_t bytes = 0;
  for (int r = 0; r < runs; ++r) {
    auto t0 = bench::Clock::now();
    auto loaded = drv::loadMap(path);
    auto t1 = bench::Clock::now();
    auto saved = drv::saveMap(copy, loaded->map, &loaded->keyframes);
    auto t2 = bench::Clock::now();
    if (!saved) {
      std::fprintf(stderr, "%s\n", saved.message().c_str());
      return 1;
    }
    bytes = saved->bytes;
    load_ms.push_back(bench::ms(t0, t1));
    save_ms.push_back(bench::ms(t1, t2));
    // Every block out to a block store and back.
    auto store = drv::BlockStore::create(std::filesystem::temp_directory_path().string());
    if (!store) {
      std::fprintf(stderr, "%s\n", store.message().c_str());
      return 1;
    }
    alg::TsdfMap& map = loaded->map;
    map.setBacking(store->get());
    std::vector<alg::BlockKey> keys;
    std::vector<int32_t> all;
    for (size_t i = 0; i < map.blockCount(); ++i) {
      keys.push_back(map.key(i));
      all.push_back(static_cast<int32_t>(i));
    }
    auto t3 = bench::Clock::now();
    map.removeBlocks(all);
    auto t4 = bench::Clock::now();
    (*store)->flush();  // the writer's share: compressed and written
    auto t5 = bench::Clock::now();
    for (const auto& k : keys) map.findOrAllocate(k);
    auto t6 = bench::Clock::now();
    const double n = static_cast<double>(keys.size());
    out_us.push_back(1000 * bench::ms(t3, t4) / n);
    write_us.push_back(1000 * bench::ms(t3, t5) / n);
    back_us.push_back(1000 * bench::ms(t5, t6) / n);
  }
  std::filesystem::remove(copy);
  std::printf("map %s: %zu blocks (%.2f M voxels), %zu keyframes; file %.2f MiB; medians of %d runs\n", path.c_str(),
              first->map.blockCount(), mvox, first->keyframes.size(), static_cast<double>(bytes) / (1 << 20), runs);
  std::printf("save: %.1f ms (%.3f s and %.2f MiB per million voxels)\n", bench::median(save_ms),
              bench::median(save_ms) / 1000 / mvox, static_cast<double>(bytes) / (1 << 20) / mvox);
  std::printf("load: %.1f ms (%.3f s per million voxels)\n", bench::median(load_ms),
              bench::median(load_ms) / 1000 / mvox);
  std::printf(
      "block store: %.1f us per block moved out (the map's thread), %.1f us until written (the store's writer), "
      "%.1f us per block brought back from the file\n",
      bench::median(out_us), bench::median(write_us), bench::median(back_us));
  return 0;
}
