// Bounds on a DICOM file, checked before GDCM parses it (dicom_worker.cc runs it first).
//
// GDCM's parser is recursive: every sequence nested in an item is one more level of C++
// recursion, whatever the sequence's length encoding, so a file nested thousands deep
// overflows the stack inside GDCM. Reading with a stop tag cannot prevent that (GDCM parses
// every element before the stop tag, descending into each sequence as it goes), and a plain
// byte scan for item tags cannot either (defined-length sequences nest without any
// delimiter). So this walks the element stream's headers (tag, VR, length) without
// recursion and without reading values, only to bound what GDCM would do: the nesting depth
// of sequences, the number of elements, and every declared length against the bytes that
// remain (GDCM allocates a value's declared length before it reads it). It decides nothing
// about the data: a stream it cannot follow is left to GDCM, which runs in a process of its
// own with time and memory limits (dicom_worker.cc).
#ifndef TANDEM_IO_DICOM_SCAN_H_
#define TANDEM_IO_DICOM_SCAN_H_

#include <cstdint>
#include <string>

#include "absl/status/status.h"

namespace tandem::io::dicom {

struct ScanLimits {
  int max_depth = 32;                  // sequences inside sequences (real images: under 10)
  uint64_t max_elements = 1u << 20;    // data elements and items (real slices: a few thousand)
  uint64_t max_inflated = 1ull << 30;  // bytes of a deflated data set
};

// What the walk saw that a reader of the pixels needs before GDCM allocates them.
struct ScanResult {
  // The declared length of the data set's native (not encapsulated) pixel data, -1 when
  // there is none: GDCM pads a shorter element to the image's size, so a tiny file claiming
  // a huge image would make it allocate and zero gigabytes.
  int64_t pixel_bytes = -1;
};

// OK when the file stays within the limits, or when its stream is one this walk cannot
// follow (left to GDCM). InvalidArgument naming the file when it nests too deep or holds too
// many elements; DataLoss naming the file when a declared length runs past the end of the
// file (truncated: still being written, or cut short).
absl::Status ScanFile(const std::string& path, const ScanLimits& limits = {},
                      ScanResult* result = nullptr);

}  // namespace tandem::io::dicom

#endif  // TANDEM_IO_DICOM_SCAN_H_
