// The bad-input corpus of the service tests: a small good stream (Good()) and edits that
// break it, each with the status code and a piece of the message the server must answer.
// Shared by service_robustness_test (one stream at a time) and service_reliability_test
// (while a good stream runs concurrently). The server under test must run with
// kBadInputServerArgs.
#ifndef TANDEM_TESTS_SERVICE_BAD_INPUT_CASES_H_
#define TANDEM_TESTS_SERVICE_BAD_INPUT_CASES_H_

#include <grpcpp/grpcpp.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <initializer_list>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "service/service_testutil.h"
#include "tandem/eval/synthetic.h"

namespace tandem::testing {

// 12 x 12 float32 slices = 576 bytes, sent in chunks of 200 (three per slice).
inline constexpr int64_t kN = 12;
inline constexpr size_t kChunk = 200;

inline std::vector<v1::ExtractRequest> Good(int64_t n = kN, size_t chunk = kChunk) {
  v1::SessionConfig config;
  config.set_error(0.5);
  auto source = eval::MakeSyntheticSource(eval::Shape::kSphere, n, n, n);
  return VolumeRequests(*source, config, chunk);
}

// Index of the first chunk of slice z in Good().
inline size_t FirstChunk(const std::vector<v1::ExtractRequest>& r, int64_t z) {
  for (size_t i = 0; i < r.size(); ++i) {
    if (r[i].has_chunk() && r[i].chunk().slice() == z) return i;
  }
  return r.size();
}

inline void SetFloat(v1::ExtractRequest* r, size_t index, float value) {
  std::string* data = r->mutable_chunk()->mutable_data();
  std::memcpy(data->data() + index * sizeof(float), &value, sizeof value);
}

inline void SetSpacing(v1::ExtractRequest* config, std::initializer_list<double> spacing) {
  config->mutable_config()->clear_spacing();
  for (double s : spacing) config->mutable_config()->add_spacing(s);
}

inline constexpr int64_t kMaxMessageBytes = 1 << 20;
inline const std::vector<std::string> kBadInputServerArgs = {
    "--max-voxels-per-slice",        "10000", "--max-slices", "64", "--max-message-bytes",
    std::to_string(kMaxMessageBytes),
    // Cancelled streams wait 1 s for a resume, not 60, before "nothing left behind".
    "--resume-window-seconds", "1"};

struct BadInputCase {
  const char* name;
  std::function<void(std::vector<v1::ExtractRequest>*)> edit;
  grpc::StatusCode code;
  const char* text;
};

inline std::vector<BadInputCase> BadInputCases() {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  return {
      {"no config first", [](auto* r) { r->erase(r->begin()); }, grpc::StatusCode::INVALID_ARGUMENT,
       "the first message must be a SessionConfig"},
      {"empty first message", [](auto* r) { (*r)[0].Clear(); }, grpc::StatusCode::INVALID_ARGUMENT,
       "got an empty ExtractRequest"},
      {"wrong slice size (declared)",
       [](auto* r) { (*r)[1].mutable_chunk()->set_slice_size(1000); },
       grpc::StatusCode::INVALID_ARGUMENT, "wrong slice size: chunk.slice_size = 1000"},
      {"wrong slice size (grid says more)",
       [](auto* r) { (*r)[0].mutable_config()->set_nx(kN + 1); },
       grpc::StatusCode::INVALID_ARGUMENT, "wrong slice size"},
      {"wrong slice size (too many bytes)",
       [](auto* r) { (*r)[3].mutable_chunk()->mutable_data()->append(40, '\0'); },
       grpc::StatusCode::INVALID_ARGUMENT, "runs past the end of the slice"},
      {"dtype mismatch", [](auto* r) { (*r)[1].mutable_chunk()->set_dtype(v1::DTYPE_UINT8); },
       grpc::StatusCode::INVALID_ARGUMENT, "chunk.dtype DTYPE_UINT8 does not match"},
      {"out-of-order slice",
       [](auto* r) { r->erase(r->begin() + FirstChunk(*r, 2), r->begin() + FirstChunk(*r, 3)); },
       grpc::StatusCode::INVALID_ARGUMENT, "slice 3 out of order: expected slice 2"},
      {"repeated slice",
       [](auto* r) {
         std::vector<v1::ExtractRequest> again(r->begin() + FirstChunk(*r, 1),
                                               r->begin() + FirstChunk(*r, 2));
         r->insert(r->begin() + FirstChunk(*r, 2), again.begin(), again.end());
       },
       grpc::StatusCode::INVALID_ARGUMENT, "slice 1 repeated"},
      {"chunk offset past the slice", [](auto* r) { (*r)[2].mutable_chunk()->set_offset(5000); },
       grpc::StatusCode::INVALID_ARGUMENT, "chunk.offset = 5000 is past the end of the slice"},
      {"chunk offset with a gap", [](auto* r) { (*r)[2].mutable_chunk()->set_offset(300); },
       grpc::StatusCode::INVALID_ARGUMENT, "chunk.offset = 300, expected 200"},
      {"NaN voxel", [nan](auto* r) { SetFloat(&(*r)[FirstChunk(*r, 4)], 13, nan); },
       grpc::StatusCode::INVALID_ARGUMENT, "slice 4: voxel (i=1, j=1) is NaN"},
      {"infinite voxel", [inf](auto* r) { SetFloat(&(*r)[FirstChunk(*r, 0)], 0, -inf); },
       grpc::StatusCode::INVALID_ARGUMENT, "slice 0: voxel (i=0, j=0) is infinite"},
      {"E0 = 0", [](auto* r) { (*r)[0].mutable_config()->set_error(0); },
       grpc::StatusCode::INVALID_ARGUMENT, "config.error (E0) = 0"},
      {"E0 < 0", [](auto* r) { (*r)[0].mutable_config()->set_error(-2); },
       grpc::StatusCode::INVALID_ARGUMENT, "config.error (E0) = -2"},
      // Each of these aborted the whole server once (std::length_error from a queue sized
      // by the reach in slice units), or gave a wrong mesh slowly.
      {"spacing 1e160",
       [](auto* r) { SetSpacing(&(*r)[0], {1e160, 1e160, 1}); },
       grpc::StatusCode::INVALID_ARGUMENT, "invalid spacing 1e+160 on axis 0"},
      {"spacing 1e-300", [](auto* r) { SetSpacing(&(*r)[0], {1e-300, 1e-300, 1e-300}); },
       grpc::StatusCode::INVALID_ARGUMENT, "invalid spacing 1e-300 on axis 0"},
      // The grid's rules are core's (ValidateVolumeInfo), their message prefixed with the config.
      {"nx = 1", [](auto* r) { (*r)[0].mutable_config()->set_nx(1); },
       grpc::StatusCode::INVALID_ARGUMENT,
       "config: invalid dimensions: nx = 1 (need at least 2 samples per axis)"},
      {"nz = 1", [](auto* r) { (*r)[0].mutable_config()->set_nz(1); },
       grpc::StatusCode::INVALID_ARGUMENT, "config: invalid dimensions: nz = 1"},
      {"spacing 0", [](auto* r) { SetSpacing(&(*r)[0], {1, 0, 1}); },
       grpc::StatusCode::INVALID_ARGUMENT,
       "config: invalid spacing 0 on axis 1 (must be finite and > 0)"},
      {"NaN origin",
       [](auto* r) {
         for (double o : {0.0, 0.0, std::nan("")}) (*r)[0].mutable_config()->add_origin(o);
       },
       grpc::StatusCode::INVALID_ARGUMENT, "config: invalid origin nan on axis 2 (must be finite)"},
      {"spacing 1e5 times longer on z", [](auto* r) { SetSpacing(&(*r)[0], {1, 1, 1e5}); },
       grpc::StatusCode::INVALID_ARGUMENT, "times longer on one axis"},
      {"origin 1e30",
       [](auto* r) {
         for (double o : {1e30, 0.0, 0.0}) (*r)[0].mutable_config()->add_origin(o);
       },
       grpc::StatusCode::INVALID_ARGUMENT, "invalid origin 1e+30 on axis 0"},
      {"directions with 8 values",
       [](auto* r) {
         for (int i = 0; i < 8; ++i) (*r)[0].mutable_config()->add_directions(i % 4 == 0);
       },
       grpc::StatusCode::INVALID_ARGUMENT, "config.directions has 8 values"},
      {"sheared directions",
       [](auto* r) {
         for (double d : {1.0, 0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 1.0}) {
           (*r)[0].mutable_config()->add_directions(d);
         }
       },
       grpc::StatusCode::INVALID_ARGUMENT, "orthonormal"},
      {"NaN in directions",
       [](auto* r) {
         for (double d : {1.0, 0.0, 0.0, 0.0, std::nan(""), 0.0, 0.0, 0.0, 1.0}) {
           (*r)[0].mutable_config()->add_directions(d);
         }
       },
       grpc::StatusCode::INVALID_ARGUMENT, "orthonormal"},
      {"E0 far below the spacing", [](auto* r) { (*r)[0].mutable_config()->set_error(1e-12); },
       grpc::StatusCode::INVALID_ARGUMENT, "x the smallest voxel spacing"},
      {"E0 far above the spacing", [](auto* r) { (*r)[0].mutable_config()->set_error(1e300); },
       grpc::StatusCode::INVALID_ARGUMENT, "x the largest voxel spacing"},
      {"alpha > 1", [](auto* r) { (*r)[0].mutable_config()->set_alpha(1.5); },
       grpc::StatusCode::INVALID_ARGUMENT, "config.alpha = 1.5"},
      {"alpha < 0", [](auto* r) { (*r)[0].mutable_config()->set_alpha(-0.5); },
       grpc::StatusCode::INVALID_ARGUMENT, "config.alpha = -0.5"},
      {"dims over the limit",
       [](auto* r) {
         (*r)[0].mutable_config()->set_nx(200);
         (*r)[0].mutable_config()->set_ny(200);
       },
       grpc::StatusCode::RESOURCE_EXHAUSTED, "--max-voxels-per-slice"},
      {"nz over the limit", [](auto* r) { (*r)[0].mutable_config()->set_nz(65); },
       grpc::StatusCode::RESOURCE_EXHAUSTED, "--max-slices"},
      {"unknown nz, too many slices",
       [](auto* r) {
         (*r)[0].mutable_config()->set_nz(0);
         r->pop_back();  // End
         std::vector<v1::ExtractRequest> more;
         for (int64_t z = kN; z < 70; ++z) {
           for (size_t i = FirstChunk(*r, 0); i < FirstChunk(*r, 1); ++i) {
             more.push_back((*r)[i]);
             more.back().mutable_chunk()->set_slice(z);
           }
         }
         r->insert(r->end(), more.begin(), more.end());
       },
       grpc::StatusCode::RESOURCE_EXHAUSTED, "slice 64 exceeds this server's limit of 64"},
      {"stream ends without End", [](auto* r) { r->pop_back(); },
       grpc::StatusCode::INVALID_ARGUMENT, "without an End marker after 12 complete slices"},
      {"End with the wrong count", [](auto* r) { r->back().mutable_end()->set_slices(5); },
       grpc::StatusCode::INVALID_ARGUMENT, "End.slices = 5 but the server received 12"},
      {"missing slice before End",
       [](auto* r) { r->erase(r->begin() + FirstChunk(*r, kN - 1), r->end() - 1); },
       grpc::StatusCode::INVALID_ARGUMENT, "End.slices = 12 but the server received 11"},
      {"second config", [](auto* r) { r->insert(r->begin() + 2, (*r)[0]); },
       grpc::StatusCode::INVALID_ARGUMENT, "got a SessionConfig"},
      // Hostile variants (issue 5).
      {"garbage float32 slice with NaN patterns",
       [](auto* r) {
         std::mt19937 rng(5);
         for (size_t i = FirstChunk(*r, 5); i < FirstChunk(*r, 6); ++i) {
           std::string* data = (*r)[i].mutable_chunk()->mutable_data();
           for (char& byte : *data) byte = static_cast<char>(rng());
         }
         // Make sure: a quiet and a signalling NaN pattern at random voxels.
         for (uint32_t bits : {0x7fc00000u, 0x7f800001u}) {
           std::string* data = (*r)[FirstChunk(*r, 5) + 1].mutable_chunk()->mutable_data();
           const size_t at = rng() % (data->size() / 4);
           std::memcpy(data->data() + 4 * at, &bits, 4);
         }
       },
       grpc::StatusCode::INVALID_ARGUMENT, "slice 5: voxel (i="},
      {"config after complete slices", [](auto* r) { r->insert(r->end() - 1, (*r)[0]); },
       grpc::StatusCode::INVALID_ARGUMENT,
       "expected a SliceChunk or End after the config, got a SessionConfig"},
      {"chunk offset far past the slice",
       [](auto* r) { (*r)[2].mutable_chunk()->set_offset(~uint64_t{0}); },
       grpc::StatusCode::INVALID_ARGUMENT, "chunk.offset = 18446744073709551615 is past the end"},
      {"huge declared slice_size",
       [](auto* r) { (*r)[1].mutable_chunk()->set_slice_size(~uint64_t{0}); },
       grpc::StatusCode::INVALID_ARGUMENT, "chunk.slice_size = 18446744073709551615"},
      {"huge declared grid",
       [](auto* r) {
         (*r)[0].mutable_config()->set_nx(int64_t{1} << 40);
         (*r)[0].mutable_config()->set_ny(int64_t{1} << 40);
       },
       grpc::StatusCode::RESOURCE_EXHAUSTED, "--max-voxels-per-slice"},
      {"grid whose voxel count overflows",
       [](auto* r) {
         (*r)[0].mutable_config()->set_nx(int64_t{1} << 62);
         (*r)[0].mutable_config()->set_ny(int64_t{1} << 62);
       },
       grpc::StatusCode::RESOURCE_EXHAUSTED, "--max-voxels-per-slice"},
      {"huge declared nz",
       [](auto* r) { (*r)[0].mutable_config()->set_nz(std::numeric_limits<int64_t>::max()); },
       grpc::StatusCode::RESOURCE_EXHAUSTED, "--max-slices"},
      {"negative slice index", [](auto* r) { (*r)[1].mutable_chunk()->set_slice(-1); },
       grpc::StatusCode::INVALID_ARGUMENT, "chunk.slice = -1"},
      {"unknown dtype",
       [](auto* r) { (*r)[0].mutable_config()->set_dtype(static_cast<v1::DType>(77)); },
       grpc::StatusCode::INVALID_ARGUMENT, "config.dtype"},
      {"End inside a slice", [](auto* r) { r->erase(r->end() - 2); },
       grpc::StatusCode::INVALID_ARGUMENT, "End arrived inside slice 11"},
      {"chunk after End", [](auto* r) { r->push_back((*r)[1]); },
       grpc::StatusCode::INVALID_ARGUMENT, "got a SliceChunk after End"},
      {"second End", [](auto* r) { r->push_back(r->back()); },
       grpc::StatusCode::INVALID_ARGUMENT, "got a second End after End"},
      {"config after End", [](auto* r) { r->push_back((*r)[0]); },
       grpc::StatusCode::INVALID_ARGUMENT, "got a SessionConfig after End"},
      {"chunk above the message size limit",
       [](auto* r) { (*r)[1].mutable_chunk()->mutable_data()->append(kMaxMessageBytes, '\0'); },
       grpc::StatusCode::RESOURCE_EXHAUSTED, "larger than max"},
  };
}

}  // namespace tandem::testing

#endif  // TANDEM_TESTS_SERVICE_BAD_INPUT_CASES_H_
