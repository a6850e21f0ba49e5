// libFuzzer target: NRRD (OpenVolume on a .nrrd file holding the input). Detached headers
// ("data file: fz.raw" or "fz.raw.gz") find fixed 4096-byte companions (16x16x16 uint8 /
// 8x8x32 uint16 ...) in the same folder, plain and gzip.
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
  gzFile gz = gzopen((dir + "/fz.raw.gz").c_str(), "wb");
  if (gz == nullptr || gzwrite(gz, raw.data(), static_cast<unsigned>(raw.size())) <= 0 ||
      gzclose(gz) != Z_OK) {
    std::abort();
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& dir = tandem::fuzz::ScratchDir();
  static const bool companions = (WriteCompanions(dir), true);
  (void)companions;
  tandem::fuzz::WriteFileOrDie(dir + "/fz.nrrd", data, size);
  tandem::fuzz::ReadAllSlices(dir + "/fz.nrrd");
  return 0;
}
