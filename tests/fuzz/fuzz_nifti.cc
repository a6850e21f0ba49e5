// libFuzzer target: NIfTI-1 single file (OpenVolume on the input). Inputs starting with the
// gzip magic (1f 8b) are written as .nii.gz, the others as .nii, so both paths are fuzzed.
#include <cstddef>
#include <cstdint>

#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const bool gzip = size >= 2 && data[0] == 0x1f && data[1] == 0x8b;
  const std::string path = tandem::fuzz::ScratchDir() + (gzip ? "/fz.nii.gz" : "/fz.nii");
  tandem::fuzz::WriteFileOrDie(path, data, size);
  tandem::fuzz::ReadAllSlices(path);
  return 0;
}
