// libFuzzer target: a DICOM series folder of two slice files (OpenVolume on the folder, then
// every slice). Input: [u32 LE size of file a][file a][file b], so mutations reach both the
// headers (ordering, geometry checks, the truncation check) and the pixel data. GDCM is the
// system library, not instrumented; everything tandem does with what it returns is.
#include <cstddef>
#include <cstdint>
#include <cstring>

#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 4) return 0;
  uint32_t a = 0;
  std::memcpy(&a, data, 4);  // little-endian hosts only (x86-64, arm64)
  data += 4;
  size -= 4;
  if (a > size) a = static_cast<uint32_t>(size);
  static const std::string dir = [] {
    const std::string d = tandem::fuzz::ScratchDir() + "/series";
    std::string cmd = "mkdir -p '" + d + "'";
    if (std::system(cmd.c_str()) != 0) std::abort();
    return d;
  }();
  tandem::fuzz::WriteFileOrDie(dir + "/a", data, a);
  tandem::fuzz::WriteFileOrDie(dir + "/b", data + a, size - a);
  tandem::fuzz::ReadAllSlices(dir);
  return 0;
}
