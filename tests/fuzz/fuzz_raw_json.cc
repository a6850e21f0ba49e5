// libFuzzer target: raw voxels + JSON sidecar (OpenVolume on a .json file).
// Input layout: 2 bytes (little-endian) = size of the raw file the sidecar points at by
// default (STEM.raw, filled with a fixed byte pattern), then the sidecar's JSON text. The
// seeds (corpus/fuzz_raw_json) are sidecars written by WriteVolume with their real sizes.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 2) return 0;
  const size_t raw_size = static_cast<size_t>(data[0]) | (static_cast<size_t>(data[1]) << 8);
  const std::string& dir = tandem::fuzz::ScratchDir();
  std::vector<uint8_t> raw(raw_size);
  for (size_t i = 0; i < raw_size; ++i) raw[i] = static_cast<uint8_t>(i * 37 + (i >> 8));
  tandem::fuzz::WriteFileOrDie(dir + "/fz.raw", raw.data(), raw.size());
  tandem::fuzz::WriteFileOrDie(dir + "/fz.json", data + 2, size - 2);
  tandem::fuzz::ReadAllSlices(dir + "/fz.json");
  return 0;
}
