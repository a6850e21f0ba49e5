// libFuzzer target: a DICOM series folder of two slice files (OpenVolume on the folder, then
// every slice). Input: [u32 LE size of file a][file a][file b], so mutations reach both the
// headers (ordering, geometry checks, the truncation check) and the pixel data. GDCM runs in
// the DICOM reader process (tandem-dicom-worker), where a crash or a hang costs that process
// and gives an error, which the contract checks here require; the structure walk that runs
// before GDCM (dicom_scan.h) is also called here, in this process, for its coverage.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>

#include "dicom_scan.h"
#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 4) return 0;
  uint32_t a = 0;
  std::memcpy(&a, data, 4);  // little-endian hosts only (x86-64, arm64)
  data += 4;
  size -= 4;
  if (a > size) a = static_cast<uint32_t>(size);
  // The reader processes this starts: under ASan they have no address-space limit, and GDCM
  // allocates (and zeroes) what a corrupt length declares; a process asking for more than
  // the largest slice read here (fuzz_common.h) is stopped at once instead.
  static const bool limited = [] {
    const char* asan = std::getenv("ASAN_OPTIONS");
    const std::string options = std::string(asan != nullptr ? asan : "") +
                                ":max_allocation_size_mb=64:allocator_may_return_null=0";
    return ::setenv("ASAN_OPTIONS", options.c_str(), 1) == 0;
  }();
  (void)limited;
  static const std::string dir = [] {
    const std::string d = tandem::fuzz::ScratchDir() + "/series";
    std::string cmd = "mkdir -p '" + d + "'";
    if (std::system(cmd.c_str()) != 0) std::abort();
    return d;
  }();
  tandem::fuzz::WriteFileOrDie(dir + "/a", data, a);
  tandem::fuzz::WriteFileOrDie(dir + "/b", data + a, size - a);
  for (const char* f : {"/a", "/b"}) {
    const absl::Status st = tandem::io::dicom::ScanFile(dir + f);
    if (!st.ok() && st.message().find(dir + f) == std::string::npos) {
      tandem::fuzz::Violation("ScanFile error without the file's name: " +
                              std::string(st.message()));
    }
  }
  tandem::fuzz::ReadAllSlices(dir);
  return 0;
}
