// libFuzzer target: multi-page TIFF (OpenVolume on a .tif file holding the input; libtiff
// itself is the system library, not instrumented, but every buffer tandem hands it is).
#include <cstddef>
#include <cstdint>

#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = tandem::fuzz::ScratchDir() + "/fz.tif";
  tandem::fuzz::WriteFileOrDie(path, data, size);
  tandem::fuzz::ReadAllSlices(path);
  return 0;
}
