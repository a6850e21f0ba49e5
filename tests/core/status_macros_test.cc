// TANDEM_RETURN_IF_ERROR and TANDEM_ASSIGN_OR_RETURN: the error passes up unchanged, the
// expression runs once, the value is moved (not copied) out.
#include "tandem/status_macros.h"

#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <utility>

namespace tandem {
namespace {

absl::Status Check(int* calls, absl::Status result) {
  ++*calls;
  return result;
}

absl::Status TwoChecks(int* calls, absl::Status first, bool* reached_second) {
  TANDEM_RETURN_IF_ERROR(Check(calls, std::move(first)));
  *reached_second = true;
  TANDEM_RETURN_IF_ERROR(Check(calls, absl::OkStatus()));
  return absl::OkStatus();
}

TEST(StatusMacros, ReturnIfErrorPassesTheErrorUpAndEvaluatesOnce) {
  int calls = 0;
  bool second = false;
  const absl::Status st = TwoChecks(&calls, absl::DataLossError("truncated"), &second);
  EXPECT_EQ(st, absl::DataLossError("truncated"));
  EXPECT_EQ(calls, 1);
  EXPECT_FALSE(second);
  calls = 0;
  EXPECT_TRUE(TwoChecks(&calls, absl::OkStatus(), &second).ok());
  EXPECT_EQ(calls, 2);
  EXPECT_TRUE(second);
}

// A StatusOr<T> also works as a function's result: the error converts.
absl::StatusOr<int> Doubled(absl::Status first) {
  TANDEM_RETURN_IF_ERROR(first);
  return 2;
}

TEST(StatusMacros, ReturnIfErrorInAStatusOrFunction) {
  EXPECT_EQ(Doubled(absl::NotFoundError("x")).status(), absl::NotFoundError("x"));
  EXPECT_EQ(*Doubled(absl::OkStatus()), 2);
}

absl::StatusOr<std::unique_ptr<std::string>> Make(int* calls, bool ok) {
  ++*calls;
  if (!ok) return absl::InvalidArgumentError("--iso: 'x' is not a number");
  return std::make_unique<std::string>("mesh");
}

// unique_ptr cannot be copied: this compiles only if the value is moved out.
absl::StatusOr<std::string> UseTwo(int* calls, bool first_ok, bool second_ok) {
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<std::string> a, Make(calls, first_ok));
  std::unique_ptr<std::string> b;
  TANDEM_ASSIGN_OR_RETURN(b, Make(calls, second_ok));  // an existing variable
  return *a + "+" + *b;
}

TEST(StatusMacros, AssignOrReturnMovesTheValueOrPassesTheErrorUp) {
  int calls = 0;
  absl::StatusOr<std::string> r = UseTwo(&calls, true, true);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(*r, "mesh+mesh");
  EXPECT_EQ(calls, 2);
  calls = 0;
  r = UseTwo(&calls, false, true);
  EXPECT_EQ(r.status(), absl::InvalidArgumentError("--iso: 'x' is not a number"));
  EXPECT_EQ(calls, 1);
  calls = 0;
  r = UseTwo(&calls, true, false);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(calls, 2);
}

// The value is moved out of the StatusOr, never copied.
TEST(StatusMacros, AssignOrReturnDoesNotCopy) {
  struct CountsCopies {
    int* copies;
    explicit CountsCopies(int* c) : copies(c) {}
    CountsCopies(const CountsCopies& o) : copies(o.copies) { ++*copies; }
    CountsCopies(CountsCopies&&) = default;
    CountsCopies& operator=(const CountsCopies& o) {
      copies = o.copies;
      ++*copies;
      return *this;
    }
    CountsCopies& operator=(CountsCopies&&) = default;
  };
  int copies = 0;
  auto f = [&]() -> absl::Status {
    TANDEM_ASSIGN_OR_RETURN(CountsCopies v, absl::StatusOr<CountsCopies>(CountsCopies(&copies)));
    (void)v;
    return absl::OkStatus();
  };
  EXPECT_TRUE(f().ok());
  EXPECT_EQ(copies, 0);
}

}  // namespace
}  // namespace tandem
