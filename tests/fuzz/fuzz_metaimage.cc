// libFuzzer target: ITK MetaImage (OpenVolume on a .mha file holding the input). Headers
// naming a data file find fixed 4096-byte companions in the same folder: fz.raw (16x16x16
// uint8 / 8x8x32 uint16 ...) and fz.zraw, the same bytes as a zlib stream.
#include <zlib.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include "fuzz_common.h"

namespace {

void WriteCompanions(const std::string& dir) {
  std::vector<uint8_t> raw(4096);
  for (size_t i = 0; i < raw.size(); ++i) raw[i] = static_cast<uint8_t>(i * 37 + (i >> 8));
  tandem::fuzz::WriteFileOrDie(dir + "/fz.raw", raw.data(), raw.size());
  uLongf n = compressBound(static_cast<uLong>(raw.size()));
  std::vector<uint8_t> z(n);
  if (compress(z.data(), &n, raw.data(), static_cast<uLong>(raw.size())) != Z_OK) std::abort();
  tandem::fuzz::WriteFileOrDie(dir + "/fz.zraw", z.data(), n);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& dir = tandem::fuzz::ScratchDir();
  static const bool companions = (WriteCompanions(dir), true);
  (void)companions;
  tandem::fuzz::WriteFileOrDie(dir + "/fz.mha", data, size);
  tandem::fuzz::ReadAllSlices(dir + "/fz.mha");
  return 0;
}
