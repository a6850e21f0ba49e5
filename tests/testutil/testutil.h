// Small helpers shared by the test suites.
#ifndef TANDEM_TESTS_TESTUTIL_H_
#define TANDEM_TESTS_TESTUTIL_H_

#include <string>

#include <gtest/gtest.h>

namespace tandem::testing {

// Full path of a file in ../shared/data, or "" when that folder is absent (a user's clone).
std::string SharedDataPath(const std::string& name);

// A fresh empty directory under the system temp dir, unique per call.
std::string MakeTempDir();

// Path of a built executable (build/bin/NAME).
std::string BinPath(const std::string& name);

}  // namespace tandem::testing

// Skips the current test with a message when the shared data file is missing.
#define TANDEM_SHARED_OR_SKIP(var, name)                                              \
  const std::string var = ::tandem::testing::SharedDataPath(name);                    \
  if (var.empty()) GTEST_SKIP() << "../shared/data/" << (name)                        \
                                << " is absent (only CI and developers have it)"

#endif  // TANDEM_TESTS_TESTUTIL_H_
