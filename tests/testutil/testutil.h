// Small helpers shared by the test suites.
#ifndef TANDEM_TESTS_TESTUTIL_H_
#define TANDEM_TESTS_TESTUTIL_H_

#include <cstdint>
#include <string>

#include <gtest/gtest.h>

#include "tandem/volume.h"
#include "tandem/volume_writers.h"

namespace tandem::testing {

// Full path of a file in ../shared/data, or "" when that folder is absent (a user's clone).
std::string SharedDataPath(const std::string& name);

// A fresh empty directory under the system temp dir, unique per call.
std::string MakeTempDir();

// Path of a built executable (build/bin/NAME).
std::string BinPath(const std::string& name);

// Voxel (i, j, k) of the readers' test pattern: uses both bytes of 16-bit types, negatives
// for int16 and fractions for float32, so byte-order, sign and placement mistakes show
// (int16 stays in range up to 37 x 21 x 25 voxels).
double PatternValue(DType t, int64_t i, int64_t j, int64_t k);

// Stores v as one voxel of type t (host byte order) at dst.
void StoreValue(DType t, double v, uint8_t* dst);

// The voxel of type t (host byte order) at p, as float.
double LoadValue(DType t, const uint8_t* p);

// Slices of PatternValue for a writer.
SliceFn PatternSlices(const VolumeInfo& info);

}  // namespace tandem::testing

// Skips the current test with a message when the shared data file is missing.
#define TANDEM_SHARED_OR_SKIP(var, name)                                              \
  const std::string var = ::tandem::testing::SharedDataPath(name);                    \
  if (var.empty()) GTEST_SKIP() << "../shared/data/" << (name)                        \
                                << " is absent (only CI and developers have it)"

#endif  // TANDEM_TESTS_TESTUTIL_H_
