// libFuzzer target: a Zarr array (OpenVolume on a store directory). Input: one byte
// (bit 0: v3 `zarr.json`, else v2 `.zarray`), a 2-byte little-endian length L, L bytes of
// array metadata, then the bytes of chunk (0, 0, 0), stored under every key spelling the
// metadata might ask for ("0.0.0", "0/0/0", "c/0/0/0"; for a sharded array, shard
// (0, 0, 0)); other chunks are missing (fill).
#include <unistd.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 3) return 0;
  const bool v3 = (data[0] & 1) != 0;
  const size_t meta_len = std::min<size_t>(size - 3, data[1] | (size_t{data[2]} << 8));
  const uint8_t* meta = data + 3;
  const uint8_t* chunk = meta + meta_len;
  const size_t chunk_len = size - 3 - meta_len;
  static const std::string dir = [] {
    const std::string d = tandem::fuzz::ScratchDir() + "/fz.zarr";
    const std::string cmd = "mkdir -p '" + d + "/0/0' '" + d + "/c/0/0'";
    if (std::system(cmd.c_str()) != 0) std::abort();
    return d;
  }();
  ::unlink((dir + "/.zarray").c_str());
  ::unlink((dir + "/zarr.json").c_str());
  tandem::fuzz::WriteFileOrDie(dir + (v3 ? "/zarr.json" : "/.zarray"), meta, meta_len);
  for (const char* key : {"/0.0.0", "/0/0/0", "/c/0/0/0"}) {
    tandem::fuzz::WriteFileOrDie(dir + key, chunk, chunk_len);
  }
  tandem::fuzz::ReadAllSlices(dir);
  return 0;
}
