// DICOM files are read in a process of their own, tandem-dicom-worker (dicom_worker.cc; found
// like the modules: next to the executable, or in ../lib/tandem/), so that no file can take
// the reading program down: a file that crashes GDCM or one of its codecs, overflows its
// stack, hangs it or makes it allocate without bound costs that process (killed after a
// time limit, under a memory limit) and gives an error naming the file; the next file gets
// a fresh process. The processes are kept between files (one per thread reading at a time),
// so a series pays the start once.
#ifndef TANDEM_IO_DICOM_WORKER_CLIENT_H_
#define TANDEM_IO_DICOM_WORKER_CLIENT_H_

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "dicom_codec.h"

namespace tandem::io::dicom {

inline constexpr char kWorkerName[] = "tandem-dicom-worker";

// Codec::read_header and Codec::read_pixels, run in a reader process.
absl::StatusOr<std::optional<SliceHeader>> ReadHeader(const std::string& path);
absl::Status ReadPixels(const std::string& path, size_t stored_bytes, std::vector<uint8_t>* out);

namespace testing {
// Makes a reader process crash (1), hang (2) or allocate without bound (3), and returns
// the error a read would get.
absl::Status Misbehave(int what);
// The time limit of one request, in seconds (0: the default).
void SetTimeLimit(double seconds);
}  // namespace testing

}  // namespace tandem::io::dicom

#endif  // TANDEM_IO_DICOM_WORKER_CLIENT_H_
