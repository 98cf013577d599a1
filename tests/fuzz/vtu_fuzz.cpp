// libFuzzer target: the VTU reader (XML, appended raw binary, VTK Lagrange cells) on arbitrary bytes,
// then, for small meshes that read, the quality statistics. Anything but success or a
// MeshIOError (the readers' clean error, naming file and line/byte offset) is a bug.
// The bytes go through a temporary file: the reader's public entry point reads a path.
// tests/io/fuzz_replay_test.cpp includes this file (with MESHFLOW_VTU_FUZZ_ENTRY renamed) to
// replay corpus/vtu/ in the normal build.
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#ifndef MESHFLOW_VTU_FUZZ_ENTRY
#define MESHFLOW_VTU_FUZZ_ENTRY LLVMFuzzerTestOneInput
#endif

extern "C" int MESHFLOW_VTU_FUZZ_ENTRY(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path file =
      std::filesystem::temp_directory_path() / ("meshflow_vtu_fuzz_" + std::to_string(::getpid()) + ".vtu");
  {
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
  try {
    meshflow::model::Mesh m = meshflow::io::read_vtu(file);
    bool small = m.num_elements() <= 200;
    for (auto& b : m.blocks) small = small && b.order <= 4;
    if (small) (void)meshflow::model::mesh_stats(m, 1);
  } catch (const meshflow::io::MeshIOError&) {
  }
  return 0;
}
