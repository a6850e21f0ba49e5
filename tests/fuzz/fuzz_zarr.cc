// libFuzzer target: a Zarr array (OpenVolume on a store directory). Input: one byte
// (bit 0: v3 `zarr.json`, else v2 `.zarray`; bit 1: an OME-Zarr group instead, see below),
// a 2-byte little-endian length L, L bytes of array metadata, then the bytes of chunk
// (0, 0, 0), stored under every key spelling the metadata might ask for ("0.0.0", "0/0/0",
// "c/0/0/0"; for a sharded array, shard (0, 0, 0)); other chunks are missing (fill).
// Group mode: the L bytes are the v2 group's .zattrs (multiscales: dataset paths,
// transforms, axes), over a fixed 2x3x3 uint8 array "0" whose chunk is the rest.
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
  for (const char* f : {"/.zarray", "/zarr.json", "/.zgroup", "/.zattrs", "/0/.zarray"}) {
    ::unlink((dir + f).c_str());
  }
  if ((data[0] & 2) != 0) {
    static const char kGroup[] = "{\"zarr_format\": 2}";
    static const char kArray[] =
        "{\"zarr_format\": 2, \"shape\": [2, 3, 3], \"chunks\": [2, 3, 3], \"dtype\": "
        "\"|u1\", \"compressor\": null, \"fill_value\": 0}";
    tandem::fuzz::WriteFileOrDie(dir + "/.zgroup", reinterpret_cast<const uint8_t*>(kGroup),
                                 sizeof kGroup - 1);
    tandem::fuzz::WriteFileOrDie(dir + "/.zattrs", meta, meta_len);
    tandem::fuzz::WriteFileOrDie(dir + "/0/.zarray", reinterpret_cast<const uint8_t*>(kArray),
                                 sizeof kArray - 1);
  } else {
    tandem::fuzz::WriteFileOrDie(dir + (v3 ? "/zarr.json" : "/.zarray"), meta, meta_len);
  }
  for (const char* key : {"/0.0.0", "/0/0/0", "/c/0/0/0", "/0/0.0.0"}) {
    tandem::fuzz::WriteFileOrDie(dir + key, chunk, chunk_len);
  }
  tandem::fuzz::ReadAllSlices(dir);
  return 0;
}
