// request_validation (proto → core options or a Status) and ExtractJob driven directly,
// without gRPC: codes, messages a person can act on, cadence, and the final mesh being
// exactly the local session's.
#include "tandem/server/request_validation.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/resource.h>

#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <type_traits>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/common/wire.h"
#include "tandem/eval/distance.h"
#include "tandem/eval/metrics.h"
#include "tandem/eval/report.h"
#include "tandem/eval/synthetic.h"
#include "tandem/geometry.h"
#include "tandem/io/run_session.h"
#include "tandem/labels.h"
#include "tandem/mesh.h"
#include "tandem/server/auth.h"
#include "tandem/server/extract_job.h"
#include "tandem/server/resume.h"
#include "tandem/server/watch.h"
#include "tandem/tandem.h"
#include "testutil/testutil.h"

namespace tandem::server {
namespace {

using ::testing::HasSubstr;

v1::SessionConfig GoodConfig() {
  v1::SessionConfig c;
  c.set_nx(16);
  c.set_ny(12);
  c.set_nz(10);
  c.set_dtype(v1::DTYPE_INT16);
  c.set_iso(100);
  c.set_error(0.5);
  c.set_alpha(0.25);
  return c;
}

void ExpectError(const absl::Status& st, absl::StatusCode code, const std::string& text) {
  EXPECT_EQ(st.code(), code) << st;
  EXPECT_THAT(std::string(st.message()), HasSubstr(text));
}

TEST(ValidateConfig, AcceptsAGoodConfigAndAppliesDefaults) {
  auto cfg = ValidateConfig(GoodConfig(), ServerLimits{});
  ASSERT_TRUE(cfg.ok()) << cfg.status();
  EXPECT_EQ(cfg->grid.nx, 16);
  EXPECT_EQ(cfg->grid.dtype, DType::kInt16);
  EXPECT_EQ(cfg->grid.spacing[2], 1.0);
  EXPECT_EQ(cfg->options.schedule, Schedule::kTandemLag);
  EXPECT_EQ(cfg->options.alpha, 0.25);
  EXPECT_EQ(cfg->options.distance_guard, 2.0);  // unset: the core default
  EXPECT_EQ(cfg->options.sag_correction, 0.3);
  EXPECT_EQ(cfg->options.lockstep_error, 0.5);  // unset: the core default
  EXPECT_EQ(cfg->options.parts, 0);  // unset: automatic
  EXPECT_EQ(cfg->draco.quantization_bits, 16);
  EXPECT_EQ(cfg->draco.compression_level, 7);
  EXPECT_EQ(cfg->preview_every_slices, 0);
}

TEST(ValidateConfig, ReadsSpacingOriginAndDraco) {
  v1::SessionConfig c = GoodConfig();
  for (double s : {3.2, 3.2, 1.5}) c.add_spacing(s);
  for (double o : {-1.0, 2.0, 3.0}) c.add_origin(o);
  c.mutable_draco()->set_quantization_bits(12);
  c.mutable_draco()->set_compression_level(0);
  c.mutable_preview()->set_every_slices(4);
  c.mutable_preview()->set_min_interval_ms(250);
  c.set_parts(3);
  auto cfg = ValidateConfig(c, ServerLimits{});
  ASSERT_TRUE(cfg.ok()) << cfg.status();
  EXPECT_EQ(cfg->grid.spacing[2], 1.5);
  EXPECT_EQ(cfg->grid.origin[0], -1.0);
  EXPECT_EQ(cfg->draco.quantization_bits, 12);
  EXPECT_EQ(cfg->draco.compression_level, 0);
  EXPECT_EQ(cfg->preview_every_slices, 4);
  EXPECT_EQ(cfg->preview_min_interval_ms, 250);
  EXPECT_EQ(cfg->options.parts, 3);
}

TEST(ValidateConfig, RejectsEachBadFieldWithItsName) {
  const ServerLimits limits;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  struct Case {
    std::function<void(v1::SessionConfig*)> edit;
    absl::StatusCode code;
    std::string text;
  };
  const std::vector<Case> cases = {
      {[](auto* c) { c->set_nx(1); }, absl::StatusCode::kInvalidArgument,
       "config: invalid dimensions: nx = 1 (need at least 2 samples per axis)"},
      {[](auto* c) { c->set_ny(-5); }, absl::StatusCode::kInvalidArgument,
       "config: invalid dimensions: ny = -5"},
      {[](auto* c) {  // negative factors whose product would overflow
         c->set_nx(-(int64_t{1} << 62));
         c->set_ny(-(int64_t{1} << 62));
       },
       absl::StatusCode::kInvalidArgument, "config: invalid dimensions: nx = -4611686018427387904"},
      {[](auto* c) { c->set_nz(1); }, absl::StatusCode::kInvalidArgument,
       "config: invalid dimensions: nz = 1 (need at least 2 slices, or 0 if the count is unknown)"},
      {[](auto* c) { c->set_nz(-3); }, absl::StatusCode::kInvalidArgument,
       "config: invalid dimensions: nz = -3"},
      {[](auto* c) { c->set_dtype(v1::DTYPE_UNSPECIFIED); }, absl::StatusCode::kInvalidArgument,
       "config.dtype is unset"},
      {[](auto* c) { c->set_dtype(static_cast<v1::DType>(42)); },
       absl::StatusCode::kInvalidArgument, "unknown value 42"},
      {[](auto* c) { c->add_spacing(1); }, absl::StatusCode::kInvalidArgument, "give 3"},
      {[](auto* c) {
         for (double s : {1.0, 0.0, 1.0}) c->add_spacing(s);
       },
       absl::StatusCode::kInvalidArgument,
       "config: invalid spacing 0 on axis 1 (must be finite and > 0)"},
      {[nan](auto* c) {
         for (double o : {0.0, 0.0, nan}) c->add_origin(o);
       },
       absl::StatusCode::kInvalidArgument, "config: invalid origin nan on axis 2 (must be finite)"},
      {[nan](auto* c) { c->set_iso(nan); }, absl::StatusCode::kInvalidArgument, "config.iso"},
      {[](auto* c) { c->set_error(0); }, absl::StatusCode::kInvalidArgument, "config.error (E0)"},
      {[](auto* c) { c->set_error(-1); }, absl::StatusCode::kInvalidArgument, "config.error (E0)"},
      {[](auto* c) { c->set_alpha(1.5); }, absl::StatusCode::kInvalidArgument, "config.alpha"},
      {[](auto* c) { c->set_alpha(-0.1); }, absl::StatusCode::kInvalidArgument, "[0, 1]"},
      {[](auto* c) { c->set_distance_guard(-1); }, absl::StatusCode::kInvalidArgument,
       "config.distance_guard"},
      {[](auto* c) { c->set_distance_guard(std::numeric_limits<double>::quiet_NaN()); },
       absl::StatusCode::kInvalidArgument, "config.distance_guard"},
      {[](auto* c) { c->set_sag_correction(-0.5); }, absl::StatusCode::kInvalidArgument,
       "config.sag_correction"},
      {[](auto* c) { c->set_lockstep_error(0); }, absl::StatusCode::kInvalidArgument,
       "config.lockstep_error"},
      {[](auto* c) {
         c->set_sealed_chunks(true);
         c->set_target_triangles(100);
       },
       absl::StatusCode::kInvalidArgument, "config.target_triangles"},
      {[](auto* c) { c->set_seal_margin(-1); }, absl::StatusCode::kInvalidArgument,
       "config.seal_margin"},
      {[](auto* c) { c->set_seal_margin(std::numeric_limits<double>::infinity()); },
       absl::StatusCode::kInvalidArgument, "config.seal_margin"},
      {[](auto* c) { c->set_sag_correction(std::numeric_limits<double>::quiet_NaN()); },
       absl::StatusCode::kInvalidArgument, "config.sag_correction"},
      {[](auto* c) { c->set_target_triangles(-3); }, absl::StatusCode::kInvalidArgument,
       "config.target_triangles"},
      {[](auto* c) { c->set_parts(-1); }, absl::StatusCode::kInvalidArgument, "config.parts"},
      {[](auto* c) { c->set_parts(65); }, absl::StatusCode::kInvalidArgument, "config.parts = 65"},
      {[](auto* c) { c->set_schedule(static_cast<v1::Schedule>(9)); },
       absl::StatusCode::kInvalidArgument, "config.schedule"},
      {[](auto* c) { c->mutable_draco()->set_quantization_bits(31); },
       absl::StatusCode::kInvalidArgument, "config.draco.quantization_bits"},
      {[](auto* c) { c->mutable_draco()->set_compression_level(11); },
       absl::StatusCode::kInvalidArgument, "config.draco.compression_level"},
      {[](auto* c) {
         c->set_nx(5000);
         c->set_ny(5000);
       },
       absl::StatusCode::kResourceExhausted, "--max-voxels-per-slice"},
      {[](auto* c) {
         c->set_nx(int64_t{1} << 40);
         c->set_ny(int64_t{1} << 40);
       },
       absl::StatusCode::kResourceExhausted, "--max-voxels-per-slice"},
      {[](auto* c) { c->set_nz(100000); }, absl::StatusCode::kResourceExhausted, "--max-slices"},
      {[nan](auto* c) { c->add_extra_isos(nan); }, absl::StatusCode::kInvalidArgument,
       "config.iso and config.extra_isos: iso-value nan is not a finite number"},
      {[](auto* c) { c->add_extra_isos(c->iso()); }, absl::StatusCode::kInvalidArgument,
       "config.iso and config.extra_isos: iso-value 100 is given twice"},
      {[](auto* c) {
         c->add_extra_isos(7);
         c->add_extra_isos(7);
       },
       absl::StatusCode::kInvalidArgument, "config.extra_isos: iso-value 7 is given twice"},
      {[](auto* c) {
         for (int i = 1; i <= 8; ++i) c->add_extra_isos(c->iso() + i);
       },
       absl::StatusCode::kInvalidArgument,
       "config.extra_isos: at most 8 iso-values in one pass, got 9"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    v1::SessionConfig c = GoodConfig();
    cases[i].edit(&c);
    SCOPED_TRACE(::testing::Message() << "case " << i << ": " << c.ShortDebugString());
    ExpectError(ValidateConfig(c, limits).status(), cases[i].code, cases[i].text);
  }
}

TEST(ValidateConfig, ScheduleNoneNeedsNoErrorThreshold) {
  v1::SessionConfig c = GoodConfig();
  c.set_schedule(v1::SCHEDULE_NONE);
  c.set_error(0);
  EXPECT_TRUE(ValidateConfig(c, ServerLimits{}).ok());
}

TEST(ValidateChunk, ChecksIndexOffsetSizeAndDtype) {
  auto cfg = ValidateConfig(GoodConfig(), ServerLimits{});  // 16 x 12 int16: 384 bytes
  ASSERT_TRUE(cfg.ok());
  const ServerLimits limits;
  auto chunk = [](int64_t z, uint64_t offset, size_t size) {
    v1::SliceChunk c;
    c.set_slice(z);
    c.set_offset(offset);
    c.set_data(std::string(size, '\0'));
    return c;
  };
  EXPECT_TRUE(ValidateChunk(chunk(0, 0, 384), *cfg, {0, 0}, limits).ok());
  EXPECT_TRUE(ValidateChunk(chunk(3, 100, 284), *cfg, {3, 100}, limits).ok());
  ExpectError(ValidateChunk(chunk(2, 0, 384), *cfg, {3, 0}, limits),
              absl::StatusCode::kInvalidArgument, "slice 2 repeated");
  ExpectError(ValidateChunk(chunk(-1, 0, 384), *cfg, {0, 0}, limits),
              absl::StatusCode::kInvalidArgument, "chunk.slice = -1: slice indices start at 0");
  ExpectError(ValidateChunk(chunk(0, ~uint64_t{0}, 10), *cfg, {0, 0}, limits),
              absl::StatusCode::kInvalidArgument, "past the end of the slice");
  ExpectError(ValidateChunk(chunk(5, 0, 384), *cfg, {3, 0}, limits),
              absl::StatusCode::kInvalidArgument, "out of order: expected slice 3");
  ExpectError(ValidateChunk(chunk(4, 0, 384), *cfg, {3, 100}, limits),
              absl::StatusCode::kInvalidArgument, "before slice 3 was complete");
  ExpectError(ValidateChunk(chunk(3, 500, 10), *cfg, {3, 100}, limits),
              absl::StatusCode::kInvalidArgument, "past the end of the slice");
  ExpectError(ValidateChunk(chunk(3, 50, 10), *cfg, {3, 100}, limits),
              absl::StatusCode::kInvalidArgument, "expected 100");
  ExpectError(ValidateChunk(chunk(3, 100, 300), *cfg, {3, 100}, limits),
              absl::StatusCode::kInvalidArgument, "wrong slice size");
  ExpectError(ValidateChunk(chunk(10, 0, 384), *cfg, {10, 0}, limits),
              absl::StatusCode::kInvalidArgument, "past the declared config.nz = 10");
  v1::SliceChunk typed = chunk(0, 0, 384);
  typed.set_dtype(v1::DTYPE_FLOAT32);
  ExpectError(ValidateChunk(typed, *cfg, {0, 0}, limits), absl::StatusCode::kInvalidArgument,
              "does not match config.dtype DTYPE_INT16");
  v1::SliceChunk sized = chunk(0, 0, 384);
  sized.set_slice_size(768);
  ExpectError(ValidateChunk(sized, *cfg, {0, 0}, limits), absl::StatusCode::kInvalidArgument,
              "16 x 12 x int16 = 384 bytes");
  ServerLimits few;
  few.max_slices = 3;
  cfg->grid.nz = 0;
  ExpectError(ValidateChunk(chunk(3, 0, 384), *cfg, {3, 0}, few),
              absl::StatusCode::kResourceExhausted, "--max-slices");
}

TEST(ValidateEnd, NeedsCompleteSlicesMatchingCounts) {
  auto cfg = ValidateConfig(GoodConfig(), ServerLimits{});
  ASSERT_TRUE(cfg.ok());
  v1::End end;
  EXPECT_TRUE(ValidateEnd(end, *cfg, {10, 0}).ok());
  ExpectError(ValidateEnd(end, *cfg, {9, 20}), absl::StatusCode::kInvalidArgument,
              "inside slice 9");
  ExpectError(ValidateEnd(end, *cfg, {9, 0}), absl::StatusCode::kInvalidArgument,
              "config.nz = 10");
  end.set_slices(11);
  ExpectError(ValidateEnd(end, *cfg, {10, 0}), absl::StatusCode::kInvalidArgument,
              "End.slices = 11");
  cfg->grid.nz = 0;
  end.set_slices(0);
  ExpectError(ValidateEnd(end, *cfg, {1, 0}), absl::StatusCode::kInvalidArgument,
              "at least 2");
}

// ---------------------------------------------------------------------------------------
// ExtractJob without gRPC.

struct RecordingSink : JobSink {
  std::vector<v1::Progress> progress;
  std::vector<v1::Preview> previews;
  std::vector<v1::ExtractResponse> final;
  void PostProgress(v1::Progress p) override { progress.push_back(std::move(p)); }
  void PostPreview(v1::Preview p) override { previews.push_back(std::move(p)); }
  void PostFinal(std::vector<v1::ExtractResponse> m) override { final = std::move(m); }
  std::vector<v1::SealedChunk> chunks;
  void PostChunk(v1::SealedChunk c) override { chunks.push_back(std::move(c)); }
};

// The messages of a synthetic float32 volume, each slice split in `pieces` chunks.
// A float32 source's stream: the config, each slice in `pieces` chunks, the end.
std::vector<v1::ExtractRequest> SourceRequests(const v1::SessionConfig& options,
                                               SliceSource* source, int pieces) {
  const VolumeInfo& info = source->info();
  std::vector<v1::ExtractRequest> out;
  v1::SessionConfig* c = out.emplace_back().mutable_config();
  *c = options;
  c->set_nx(info.nx);
  c->set_ny(info.ny);
  c->set_nz(info.nz);
  c->set_dtype(v1::DTYPE_FLOAT32);
  std::vector<uint8_t> bytes;
  for (int64_t z = 0; z < info.nz; ++z) {
    EXPECT_TRUE(source->ReadSlice(&bytes).ok());
    const size_t piece = (bytes.size() + pieces - 1) / pieces;
    for (size_t off = 0; off < bytes.size(); off += piece) {
      v1::SliceChunk* chunk = out.emplace_back().mutable_chunk();
      chunk->set_slice(z);
      chunk->set_offset(off);
      chunk->set_data(bytes.data() + off, std::min(piece, bytes.size() - off));
    }
  }
  out.emplace_back().mutable_end();
  return out;
}
std::vector<v1::ExtractRequest> SyntheticRequests(const v1::SessionConfig& options,
                                                  eval::Shape shape, int64_t nx, int64_t ny,
                                                  int64_t nz, int pieces) {
  return SourceRequests(options, eval::MakeSyntheticSource(shape, nx, ny, nz).get(), pieces);
}
std::vector<v1::ExtractRequest> SphereRequests(const v1::SessionConfig& options, int64_t n,
                                               int pieces) {
  return SyntheticRequests(options, eval::Shape::kSphere, n, n, n, pieces);
}

// After every message the job checks its budget, posts progress, and the server's worker
// reads its memory and triangles. A split session runs its slabs' steps behind AddSlice:
// waiting for them there drained that pipeline every message and made the worker compute
// beside the executor's threads (a dense stream took longer through the server than the CLI;
// docs/decisions.md 33). With an executor of no threads a queued step
// runs only when someone waits: three slices in (the ring holds four), none has, yet the
// mesh at the end is the local session's.
TEST(ExtractJob, BetweenSlicesTheJobDoesNotWaitForTheSessionsSteps) {
  const std::unique_ptr<Executor> none = NewThreadPool(0);
  v1::SessionConfig options;
  options.set_error(0.3);
  RecordingSink sink;
  ExtractJob job(ServerLimits{}, &sink, none.get());
  std::vector<v1::ExtractRequest> requests =
      SyntheticRequests(options, eval::Shape::kGyroid, 160, 40, 12, 2);
  ASSERT_EQ(requests.size(), 1u + 12 * 2 + 1);
  for (size_t i = 0; i < requests.size(); ++i) {
    ASSERT_TRUE(job.Handle(requests[i]).ok()) << i;
    (void)job.MemoryBytes();
    if (i <= 6) {  // the config and three slices
      EXPECT_EQ(job.triangles(), 0) << i;
      EXPECT_EQ(sink.progress.back().triangles(), 0) << i;
    }
  }
  ASSERT_TRUE(job.done());
  auto source = eval::MakeSyntheticSource(eval::Shape::kGyroid, 160, 40, 12);
  SessionOptions local;
  local.error = 0.3;
  auto session = io::RunSession(*source, local);
  ASSERT_TRUE(session.ok()) << session.status();
  ASSERT_FALSE(sink.final.empty());
  ASSERT_TRUE(sink.final[0].has_final_mesh());
  EXPECT_EQ(sink.final[0].final_mesh().triangles(), (*session)->num_triangles());
  EXPECT_GT((*session)->num_triangles(), 0);
}

// The mesh a local sealed session with E0 = `error` makes of `source`: its chunks welded.
IndexedMesh LocalSealedMesh(SliceSource* source, double error) {
  SessionOptions options;
  options.error = error;
  options.seal = true;
  std::vector<SealedChunk> chunks;
  auto local = io::RunSession(*source, options, nullptr, [&](SealedChunk c) {
    chunks.push_back(std::move(c));
    return absl::OkStatus();
  });
  EXPECT_TRUE(local.ok()) << local.status();
  return WeldChunks(chunks);
}

// The chunks a job posted, numbered 0, 1, ..., decoded and welded by id, are `expected` (the
// same vertices in id order, within `step` of its coordinates, and the same triangles).
void ExpectChunksWeldTo(const std::vector<v1::SealedChunk>& chunks, const IndexedMesh& expected,
                        double step) {
  std::vector<SealedChunk> got;
  for (size_t i = 0; i < chunks.size(); ++i) {
    EXPECT_EQ(chunks[i].index(), static_cast<int64_t>(i));
    SealedChunk c;
    auto mesh = codec::DecodeDraco(chunks[i].draco(), &c.ids);
    ASSERT_TRUE(mesh.ok()) << mesh.status();
    EXPECT_EQ(static_cast<int64_t>(mesh->num_triangles()), chunks[i].triangles());
    c.positions = mesh->positions;
    c.indices = mesh->indices;
    got.push_back(std::move(c));
  }
  const IndexedMesh welded = WeldChunks(got);
  ASSERT_EQ(welded.num_vertices(), expected.num_vertices());
  ASSERT_EQ(welded.num_triangles(), expected.num_triangles());
  for (size_t i = 0; i < expected.num_vertices(); ++i) {
    for (int c = 0; c < 3; ++c) {
      ASSERT_NEAR(welded.positions[i][c], expected.positions[i][c], step) << i;
    }
  }
}

// Sealed: the job's chunks are the local sealed session's (same ids, coordinates within the
// grid's step), no FinalMesh comes, and the metrics measure their union.
TEST(ExtractJob, SealedChunksAreTheLocalSessionsChunks) {
  v1::SessionConfig options;
  options.set_error(0.1);
  options.set_sealed_chunks(true);
  options.mutable_preview()->set_every_slices(4);
  RecordingSink sink;
  ServerLimits limits;
  limits.min_preview_interval_ms = 0;
  limits.max_preview_share = 0;  // every preview asked for
  limits.max_band_bytes_share = 0;
  ExtractJob job(limits, &sink);
  const int64_t n = 40;
  for (v1::ExtractRequest& r : SphereRequests(options, n, 1)) ASSERT_TRUE(job.Handle(r).ok());
  ASSERT_TRUE(job.done());

  const IndexedMesh expected =
      LocalSealedMesh(eval::MakeSyntheticSource(eval::Shape::kSphere, n, n, n).get(), 0.1);

  ASSERT_EQ(sink.final.size(), 1u);  // FinalMetrics only
  ASSERT_GE(sink.chunks.size(), 2u);  // the previews take what is sealed before each
  ExpectChunksWeldTo(sink.chunks, expected, 1.5 * (n - 1) / ((1 << 16) - 1));
  const v1::FinalMetrics& m = sink.final[0].final_metrics();
  EXPECT_EQ(m.triangles_final(), static_cast<int64_t>(expected.num_triangles()));
  EXPECT_EQ(m.vertices_final(), static_cast<int64_t>(expected.num_vertices()));
  EXPECT_EQ(m.sealed_chunks(), static_cast<int64_t>(sink.chunks.size()));
  EXPECT_NEAR(m.anisotropy(), eval::Anisotropy(expected), 1e-9);
  EXPECT_NEAR(m.directional_bias(), eval::DirectionalBias(expected), 1e-9);
  ASSERT_FALSE(sink.previews.empty());
  for (const v1::Preview& p : sink.previews) EXPECT_TRUE(p.band_only());
  EXPECT_GT(sink.progress.back().sealed_triangles(), 0);
}

// The stream's last chunk (the time lag's band and the seams, sealed at once) goes out in
// parts of at most 16,384 triangles, encoded side by side (one a compute thread), and every
// chunk before it too (one at a time): runs of its triangles, each with the vertices it uses,
// that weld to the local session's mesh. The encoder's buffers stay bounded by the parts'
// size, however many triangles the chunk holds.
TEST(ExtractJob, ALargeLastChunkGoesOutInPartsEncodedSideBySide) {
  const int64_t nx = 300, ny = 300, nz = 6;
  constexpr int64_t kPart = 16384;
  const IndexedMesh expected =
      LocalSealedMesh(::tandem::testing::BoxCutGyroid(nx, ny, nz).get(), 0.05);
  for (int threads : {2, 0}) {
    const std::string what = std::to_string(threads) + " compute threads";
    v1::SessionConfig options;
    options.set_error(0.05);
    options.set_sealed_chunks(true);
    RecordingSink sink;
    const std::unique_ptr<Executor> compute = NewThreadPool(threads);
    ExtractJob job(ServerLimits{}, &sink, compute.get());
    // A gyroid of period 14 voxels filling the box: surface in every slice.
    for (v1::ExtractRequest& r :
         SourceRequests(options, ::tandem::testing::BoxCutGyroid(nx, ny, nz).get(), 1)) {
      ASSERT_TRUE(job.Handle(r).ok()) << what;
    }
    ASSERT_TRUE(job.done()) << what;
    ExpectChunksWeldTo(sink.chunks, expected, 1.5 * (nx - 1) / ((1 << 16) - 1));
    for (const v1::SealedChunk& c : sink.chunks) EXPECT_LE(c.triangles(), kPart) << what;
    // The last chunk's parts: the chunks through the last slice from its first slice, in
    // runs of nearly equal length.
    const int64_t first = sink.chunks.back().first_slice();
    size_t parts = 0;
    int64_t last = 0;
    for (auto c = sink.chunks.rbegin();
         c != sink.chunks.rend() && c->first_slice() == first && c->last_slice() == nz - 1; ++c) {
      ++parts;
      last += c->triangles();
    }
    EXPECT_GE(last, 2 * kPart) << what;
    EXPECT_EQ(static_cast<int64_t>(parts), (last + kPart - 1) / kPart) << what;
    for (size_t p = 0; p < parts; ++p) {
      const int64_t n = static_cast<int64_t>(parts);
      const int64_t i = static_cast<int64_t>(p);
      EXPECT_EQ(sink.chunks[sink.chunks.size() - parts + p].triangles(),
                last * (i + 1) / n - last * i / n)
          << what << ", part " << p;
    }
    ASSERT_EQ(sink.final.size(), 1u) << what;
    const v1::FinalMetrics& m = sink.final[0].final_metrics();
    EXPECT_EQ(m.sealed_chunks(), static_cast<int64_t>(sink.chunks.size())) << what;
    EXPECT_EQ(m.triangles_final(), static_cast<int64_t>(expected.num_triangles())) << what;
    EXPECT_NEAR(m.anisotropy(), eval::Anisotropy(expected), 1e-9) << what;
  }
}

// On a coarse grid (8 bits over the padded box: a step of 0.84 voxel) thin triangles of a
// sealed stream would fall onto lines of the grid. A chunk's encoder moves a corner that no
// earlier chunk sent by one grid step instead, and a later chunk sends that vertex again
// where it was sent: every id decodes to one position in every chunk that has it, and the
// welded mesh has a triangle without area only where an earlier chunk sent all three of its
// corners (those may not move). Compute threads split the last chunk: a vertex two parts
// share may not move either.
TEST(ExtractJob, SealedChunksKeepTheirTrianglesAreasOnTheGrid) {
  const int64_t nx = 96, ny = 96, nz = 24;
  v1::SessionConfig options;
  options.set_error(0.05);
  options.set_sealed_chunks(true);
  options.mutable_draco()->set_quantization_bits(8);
  options.mutable_preview()->set_every_slices(2);  // a preview takes what is sealed: a chunk
  ServerLimits limits;
  limits.min_preview_interval_ms = 0;
  limits.max_preview_share = 0;  // every preview asked for
  limits.max_band_bytes_share = 0;
  RecordingSink sink;
  const std::unique_ptr<Executor> compute = NewThreadPool(2);
  ExtractJob job(limits, &sink, compute.get());
  for (v1::ExtractRequest& r :
       SourceRequests(options, ::tandem::testing::BoxCutGyroid(nx, ny, nz).get(), 1)) {
    ASSERT_TRUE(job.Handle(r).ok());
  }
  ASSERT_TRUE(job.done());
  ASSERT_GE(sink.chunks.size(), 3u);
  std::map<uint32_t, std::pair<Vec3, size_t>> first;  // id: position, first chunk
  size_t triangles = 0, without_area = 0, excused = 0;
  for (size_t k = 0; k < sink.chunks.size(); ++k) {
    std::vector<uint32_t> ids;
    auto mesh = codec::DecodeDraco(sink.chunks[k].draco(), &ids);
    ASSERT_TRUE(mesh.ok()) << mesh.status();
    for (size_t v = 0; v < ids.size(); ++v) {
      auto [it, fresh] = first.emplace(ids[v], std::make_pair(mesh->positions[v], k));
      if (!fresh) {
        EXPECT_EQ(it->second.first, mesh->positions[v]) << "id " << ids[v];
      }
    }
    for (size_t t = 0; t < mesh->num_triangles(); ++t, ++triangles) {
      const uint32_t* v = &mesh->indices[3 * t];
      if (!AreaAtMost(4e-12, TwiceAreaVector(mesh->positions[v[0]], mesh->positions[v[1]],
                                              mesh->positions[v[2]]),
                      SumSquaredEdges(mesh->positions[v[0]], mesh->positions[v[1]],
                                      mesh->positions[v[2]]))) {
        continue;
      }
      ++without_area;
      bool all_earlier = true;
      for (int c = 0; c < 3; ++c) all_earlier = all_earlier && first[ids[v[c]]].second < k;
      excused += all_earlier;
      EXPECT_TRUE(all_earlier) << "chunk " << k << " triangle " << t;
    }
  }
  EXPECT_GT(triangles, 10000u);
  EXPECT_LE(without_area, triangles / 1000);
  std::printf("%zu triangles, %zu without an area on the grid (%zu with every corner sent by an "
              "earlier chunk)\n", triangles, without_area, excused);
}

// A preview every slice of a small volume: a share bound of 5% skips most of them, and
// without it every one goes. (At the default 20% the skipped share depends on how costly
// encoding is next to the session: under ASan the session is instrumented and Debian's
// Draco is not, and 41 of 48 previews went.)
TEST(ExtractJob, PreviewsTakeAtMostTheirShareOfTheTime) {
  v1::SessionConfig options;
  options.set_error(0.4);
  options.mutable_preview()->set_every_slices(1);
  size_t counts[2] = {0, 0};
  for (int bounded = 0; bounded < 2; ++bounded) {
    RecordingSink sink;
    ServerLimits limits;
    limits.min_preview_interval_ms = 0;
    limits.max_preview_share = bounded ? 0.05 : 0;
    ExtractJob job(limits, &sink);
    for (v1::ExtractRequest& r : SphereRequests(options, 48, 1)) ASSERT_TRUE(job.Handle(r).ok());
    counts[bounded] = sink.previews.size();
  }
  EXPECT_EQ(counts[0], 48u);
  EXPECT_GE(counts[1], 1u);
  EXPECT_LT(counts[1], counts[0] * 3 / 4) << "encoding previews costs more than the session here";
}

// Sealed, with a preview asked for every slice: the band previews' bytes stay within their
// share of the chunks' bytes (plus the one that crossed it).
TEST(ExtractJob, BandPreviewBytesStayUnderTheirShareOfTheChunks) {
  v1::SessionConfig options;
  options.set_error(0.1);
  options.set_sealed_chunks(true);
  options.mutable_preview()->set_every_slices(1);
  RecordingSink sink;
  ServerLimits limits;
  limits.min_preview_interval_ms = 0;
  limits.max_preview_share = 0;
  ExtractJob job(limits, &sink);
  for (v1::ExtractRequest& r : SphereRequests(options, 64, 1)) ASSERT_TRUE(job.Handle(r).ok());
  int64_t chunks = 0, previews = 0, largest = 0;
  for (const v1::SealedChunk& c : sink.chunks) chunks += static_cast<int64_t>(c.draco().size());
  for (const v1::Preview& p : sink.previews) {
    previews += static_cast<int64_t>(p.draco().size());
    largest = std::max(largest, static_cast<int64_t>(p.draco().size()));
  }
  ASSERT_GE(sink.previews.size(), 1u);  // the first always goes
  EXPECT_LT(sink.previews.size(), 64u / 2) << "most were skipped (a preview a slice otherwise)";
  EXPECT_LE(previews, limits.max_band_bytes_share * static_cast<double>(chunks) + largest);
}

TEST(ExtractJob, FinalMeshIsTheLocalSessionsSnapshot) {
  v1::SessionConfig options;
  options.set_error(0.4);
  options.set_alpha(0.1);
  options.mutable_draco()->set_compression_level(0);  // keeps order: compare index by index
  options.mutable_preview()->set_every_slices(5);
  RecordingSink sink;
  ServerLimits limits;
  limits.min_preview_interval_ms = 0;  // every preview asked for (the sink sends at once)
  limits.max_preview_share = 0;
  ExtractJob job(limits, &sink);
  const int64_t n = 24;
  for (v1::ExtractRequest& r : SphereRequests(options, n, 3)) {
    ASSERT_FALSE(job.done());
    ASSERT_TRUE(job.Handle(r).ok());
  }
  ASSERT_TRUE(job.done());
  EXPECT_EQ(job.slices(), n);

  auto source = eval::MakeSyntheticSource(eval::Shape::kSphere, n, n, n);
  SessionOptions local_options;
  local_options.error = 0.4;
  local_options.alpha = 0.1;
  auto local = io::RunSession(*source, local_options);
  ASSERT_TRUE(local.ok());
  const IndexedMesh expected = (*local)->Snapshot();
  const SessionStats& stats = (*local)->stats();

  ASSERT_EQ(sink.final.size(), 2u);  // one mesh chunk + metrics
  const v1::FinalMesh& fm = sink.final[0].final_mesh();
  EXPECT_EQ(fm.chunk_count(), 1u);
  auto mesh = codec::DecodeDraco(fm.draco());
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_EQ(mesh->indices, expected.indices);
  ASSERT_EQ(mesh->num_vertices(), expected.num_vertices());
  const double tol = codec::PositionTolerance(expected, 16);
  for (size_t i = 0; i < expected.num_vertices(); ++i) {
    for (int c = 0; c < 3; ++c) {
      ASSERT_NEAR(mesh->positions[i][c], expected.positions[i][c], tol) << i;
    }
  }
  const v1::FinalMetrics& m = sink.final[1].final_metrics();
  EXPECT_EQ(m.triangles_final(), static_cast<int64_t>(expected.num_triangles()));
  EXPECT_EQ(m.triangles_extracted(), stats.triangles_extracted);
  EXPECT_EQ(std::vector<int64_t>(m.trace().begin(), m.trace().end()), stats.trace);
  EXPECT_DOUBLE_EQ(m.error_max(), (*local)->MaxShapeError());

  // Progress when the config is taken (0 slices: the client's go-ahead), after every slice
  // and at the end; a preview every 5 slices showing the mesh as the session holds it after
  // slice k: one of slice k's two trace entries (after its EXTRACT or its SIMPLIFY,
  // depending on whether core defers that SIMPLIFY to the next slice).
  ASSERT_EQ(sink.progress.size(), static_cast<size_t>(n) + 2);
  EXPECT_EQ(sink.progress.front().slices_consumed(), 0);
  ASSERT_EQ(sink.previews.size(), static_cast<size_t>(n / 5));
  for (size_t i = 0; i < sink.previews.size(); ++i) {
    const v1::Preview& p = sink.previews[i];
    EXPECT_EQ(p.slice(), static_cast<int64_t>(5 * i + 4));
    EXPECT_TRUE(p.triangles() == stats.trace[2 * p.slice()] ||
                p.triangles() == stats.trace[2 * p.slice() + 1])
        << "preview after slice " << p.slice() << ": " << p.triangles();
    auto decoded = codec::DecodeDraco(p.draco());
    ASSERT_TRUE(decoded.ok());
    EXPECT_EQ(static_cast<int64_t>(decoded->num_triangles()), p.triangles());
  }
}

// Every MetricsReport field survives the wire (a field added to core but not to the proto
// shows up here as a JSON difference).
TEST(Wire, MetricsReportRoundTrip) {
  auto source = eval::MakeSyntheticSource(eval::Shape::kSphere, 16, 16, 16);
  SessionOptions options;
  options.error = 0.5;
  options.alpha = 0.2;
  options.distance_guard = 1.5;
  options.sag_correction = 0.25;
  options.target_triangles = 100;
  auto session = io::RunSession(*source, options);
  ASSERT_TRUE(session.ok());
  const IndexedMesh mesh = (*session)->Snapshot();
  eval::MetricsReport report = eval::MakeReport(**session, mesh);
  report.stats.sag_corrected = 37;  // here 0: past E0, toward the target, no vertex may move
  report.distance = eval::MeasureDistances(mesh, mesh, eval::DistanceOptions{1000, 1, 1});
  report.peak_rss_bytes = 12345;
  report.bytes_received = 678;
  report.bytes_sent = 910;
  v1::FinalMetrics proto;
  common::ReportToProto(report, &proto);
  eval::MetricsReport back = common::ReportFromProto(proto);
  back.input = report.input;  // not on the wire: the client knows its file name
  back.frame_text = report.frame_text;  // nor the frame's description (the frame travels)
  EXPECT_EQ(eval::ReportToJson(back), eval::ReportToJson(report));
}

TEST(ExtractJob, OrderOfMessagesIsEnforced) {
  RecordingSink sink;
  ExtractJob job(ServerLimits{}, &sink);
  v1::ExtractRequest end;
  end.mutable_end();
  ExpectError(job.Handle(end), absl::StatusCode::kInvalidArgument,
              "the first message must be a SessionConfig, got an End");
  ExtractJob job2(ServerLimits{}, &sink);
  ExpectError(job2.HandleEndOfInput(), absl::StatusCode::kInvalidArgument, "before a SessionConfig");
  auto requests = SphereRequests(v1::SessionConfig(), 8, 1);
  requests[0].mutable_config()->set_error(1);
  ASSERT_TRUE(job2.Handle(requests[0]).ok());
  ExpectError(job2.Handle(requests[0]), absl::StatusCode::kInvalidArgument, "got a SessionConfig");
  ASSERT_TRUE(job2.Handle(requests[1]).ok());
  ExpectError(job2.HandleEndOfInput(), absl::StatusCode::kInvalidArgument, "without an End marker");
}

TEST(ExtractJob, ComputesDistancesWhenAsked) {
  v1::SessionConfig options;
  options.set_error(0.5);
  options.set_compute_distances(true);
  RecordingSink sink;
  ExtractJob job(ServerLimits{}, &sink);
  for (v1::ExtractRequest& r : SphereRequests(options, 16, 1)) ASSERT_TRUE(job.Handle(r).ok());
  ASSERT_FALSE(sink.final.empty());
  const v1::FinalMetrics& m = sink.final.back().final_metrics();
  ASSERT_TRUE(m.has_distance());
  EXPECT_GT(m.distance().forward().samples(), 0u);
  EXPECT_GT(m.distance().linf_max(), 0);
  // E0 bounds the distance to each vertex's planes, not the Hausdorff distance: on this
  // 16³ sphere it is 0.96-1.01 as rounding decides ties (the sphere has many).
  EXPECT_LE(m.distance().linf_max(), 3 * 0.5) << "Hausdorff distance near E0";
}

// The proto conversion follows the report's field table (VisitReportFields) through
// reflection: every wire name there must be a FinalMetrics field of its member's type, and a
// report whose every field has its own value must come back from FinalMetrics with each of
// them.
std::string Text(const std::string& v) { return v; }
std::string Text(Schedule v) { return std::string(ScheduleName(v)); }
std::string Text(double v) { return absl::StrCat(v); }
std::string Text(int64_t v) { return absl::StrCat(v); }
std::string Text(const std::vector<int64_t>& v) { return absl::StrJoin(v, ","); }
std::string Text(const std::optional<eval::Distances>& d) {
  if (!d) return "none";
  std::string s;
  for (const eval::DirectedDistance& x : {d->forward, d->backward}) {
    absl::StrAppend(&s, x.l1, ",", x.l2, ",", x.linf, ",", x.samples, ";");
  }
  return absl::StrCat(s, d->l1_max, ",", d->l2_max, ",", d->linf_max);
}

// Every field its own non-default value (k counts the fields).
eval::MetricsReport ReportWithDistinctFields() {
  eval::MetricsReport r;
  int k = 0;
  auto set = [&k](const char*, const char*, auto& v, eval::Written) {
    using T = std::remove_cvref_t<decltype(v)>;
    ++k;
    if constexpr (std::is_same_v<T, std::string>) {
      v = absl::StrCat("text", k);
    } else if constexpr (std::is_same_v<T, Schedule>) {
      v = Schedule::kClassical;  // the default is kTandemLag
    } else if constexpr (std::is_same_v<T, std::vector<int64_t>>) {
      v = {k, k + 1, k + 2};
    } else if constexpr (std::is_same_v<T, std::optional<eval::Distances>>) {
      eval::Distances d;
      d.forward = {k + 0.25, k + 0.5, k + 0.75, static_cast<size_t>(k + 1)};
      d.backward = {k + 1.25, k + 1.5, k + 1.75, static_cast<size_t>(k + 2)};
      d.l1_max = k + 2.25;
      d.l2_max = k + 2.5;
      d.linf_max = k + 2.75;
      v = d;
    } else if constexpr (std::is_floating_point_v<T>) {
      v = k + 0.5;
    } else {
      v = 1000 + k;
    }
  };
  eval::VisitReportFields(r, set);
  return r;
}

// key → value text, through the table.
std::map<std::string, std::string> Fields(const eval::MetricsReport& r) {
  std::map<std::string, std::string> out;
  eval::VisitReportFields(
      r, [&](const char* key, const char*, const auto& v, eval::Written) { out[key] = Text(v); });
  return out;
}

// A label chunk's pairs go as runs over its triangles and come back as they were (a run past
// the pairs: no label's); runs that do not cover the triangles are refused naming the field;
// each label's part holds its triangles, reversed where it is outside, with the vertices' ids.
TEST(WireLabelPairs, RoundTripAndEachLabelsPart) {
  const std::vector<LabelPair> pairs = {{5, 9}, {9, 0}};
  const std::vector<uint32_t> patch = {0, 0, 1, 1, 1, 0, 7};
  v1::LabelPairs wire;
  common::LabelPairsToProto(patch, pairs, 0, &wire);
  EXPECT_THAT(wire.runs(), ::testing::ElementsAre(0, 2, 1, 3, 0, 1, 2, 1));
  SealedChunk back;
  LabelId background = 3;
  ASSERT_TRUE(common::LabelPairsFromProto(wire, patch.size(), &back, &background).ok());
  EXPECT_EQ(background, 0u);
  EXPECT_EQ(back.pairs, pairs);
  EXPECT_THAT(back.patch, ::testing::ElementsAre(0, 0, 1, 1, 1, 0, 2));
  EXPECT_EQ(common::LabelPairsFromProto(wire, patch.size() + 1, &back, &background).message(),
            "label_pairs.runs cover 7 triangles of 8");
  wire.add_inside(4);
  EXPECT_EQ(common::LabelPairsFromProto(wire, patch.size(), &back, &background).message(),
            "label_pairs: 3 inside labels, 2 outside");

  // Two triangles: (5 | 9) and (9 | background).
  SealedChunk chunk;
  chunk.index = 4;
  chunk.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
  chunk.ids = {40, 41, 42, 43};
  chunk.indices = {0, 1, 2, 1, 3, 2};
  chunk.pairs = pairs;
  chunk.patch = {0, 1};
  const auto parts = SplitLabeledChunk(chunk, 0);
  ASSERT_EQ(parts.size(), 2u);
  EXPECT_EQ(parts[0].first, 5u);
  EXPECT_THAT(parts[0].second.ids, ::testing::ElementsAre(40, 41, 42));
  EXPECT_THAT(parts[0].second.indices, ::testing::ElementsAre(0, 1, 2));
  EXPECT_EQ(parts[1].first, 9u);
  EXPECT_EQ(parts[1].second.index, 4);
  EXPECT_THAT(parts[1].second.ids, ::testing::ElementsAre(40, 42, 41, 43));  // reversed first
  EXPECT_THAT(parts[1].second.indices, ::testing::ElementsAre(0, 1, 2, 2, 3, 1));
}

TEST(WireReport, TableNamesFinalMetricsFields) {
  const absl::Status table = common::CheckReportFields();
  EXPECT_TRUE(table.ok()) << table;
  // Only the input's name and the frame's description stay off the wire: the client knows
  // them itself (the frame itself travels: a watcher writes it into its mesh files).
  std::set<std::string> local_only;
  const eval::MetricsReport r;
  eval::VisitReportFields(r, [&](const char* key, const char* wire, const auto&, eval::Written) {
    if (wire == nullptr) local_only.insert(key);
  });
  EXPECT_EQ(local_only, (std::set<std::string>{"/input", "/frame_text"}));

  // The check refuses a name FinalMetrics lacks, and a field of another type than the member.
  const int64_t count = 0;
  const double value = 0;
  const std::vector<int64_t> counts;
  EXPECT_TRUE(common::CheckWireField("nx", count).ok());
  EXPECT_TRUE(common::CheckWireField("refusals.link", count).ok());
  EXPECT_TRUE(common::CheckWireField("trace", counts).ok());
  EXPECT_TRUE(common::CheckWireField("distance", std::optional<eval::Distances>()).ok());
  EXPECT_TRUE(common::CheckWireField("schedule", Schedule::kTandem).ok());
  for (const std::string name : {"grid_x", "refusals.shape", "nx.low"}) {
    ExpectError(common::CheckWireField(name.c_str(), count), absl::StatusCode::kNotFound,
                "tandem.v1.FinalMetrics has no field " + name);
  }
  ExpectError(common::CheckWireField("nx", value), absl::StatusCode::kInvalidArgument,
              "tandem.v1.FinalMetrics.nx is of type int64,");
  ExpectError(common::CheckWireField("trace", count), absl::StatusCode::kInvalidArgument,
              "trace is of type repeated int64,");
  ExpectError(common::CheckWireField("contractions", counts), absl::StatusCode::kInvalidArgument,
              "contractions is of type int64,");
  ExpectError(common::CheckWireField("iso", Schedule::kTandem), absl::StatusCode::kInvalidArgument,
              "iso is of type double,");
  ExpectError(common::CheckWireField("refusals", count), absl::StatusCode::kInvalidArgument,
              "refusals is of type tandem.v1.Refusals,");
  ExpectError(common::CheckWireField("distance.forward", std::optional<eval::Distances>()),
              absl::StatusCode::kInvalidArgument,
              "distance.forward is of type tandem.v1.DirectedDistance,");
}

TEST(WireReport, CarriesEveryFieldOfTheReportTable) {
  const eval::MetricsReport want = ReportWithDistinctFields();
  v1::FinalMetrics m;
  common::ReportToProto(want, &m);
  const std::map<std::string, std::string> got = Fields(common::ReportFromProto(m));
  for (const auto& [key, value] : Fields(want)) {
    if (key == "/input" || key == "/frame_text") {
      EXPECT_EQ(got.at(key), "") << key << " is not on the wire";
    } else {
      EXPECT_EQ(got.at(key), value) << key << " is not carried by FinalMetrics";
    }
  }
  // Into FinalMetrics' own fields, as the generated code (and the Python client) reads them,
  // where the JSON key and the wire name differ.
  EXPECT_EQ(m.nx(), want.nx);
  EXPECT_EQ(m.ny(), want.ny);
  EXPECT_EQ(m.nz(), want.nz);
  EXPECT_EQ(m.error_threshold(), want.options.error);
  EXPECT_EQ(m.time_extract_s(), want.stats.time.extract_s);
  EXPECT_EQ(m.time_simplify_s(), want.stats.time.simplify_s);
  EXPECT_EQ(m.time_total_s(), want.stats.time.total_s);
  EXPECT_EQ(m.refusals().link(), want.stats.refusals.link);
  EXPECT_EQ(m.refusals().distance(), want.stats.refusals.distance);
  EXPECT_EQ(m.schedule(), "classical");
  EXPECT_EQ(m.distance().backward().samples(), want.distance->backward.samples);
  EXPECT_THAT(m.trace(), ::testing::ElementsAreArray(want.stats.trace));

  // Without distances the message has none, and a report read back has none either.
  eval::MetricsReport plain = want;
  plain.distance.reset();
  common::ReportToProto(plain, &m);  // over the message that had them
  EXPECT_FALSE(m.has_distance());
  EXPECT_FALSE(common::ReportFromProto(m).distance.has_value());
}

TEST(WireReport, JsonCarriesEveryFieldOfTheReportTable) {
  eval::MetricsReport want = ReportWithDistinctFields();
  want.distance->forward.samples = want.distance->backward.samples = 0;  // not in the JSON
  auto back = eval::ReportFromJson(eval::ReportToJson(want));
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(Fields(*back), Fields(want));
}

// --max-sessions slots: a session counts once on its way from its stream to the resume
// table. The stream's slot becomes the parked session's when ParkAndWait takes it, not
// when gRPC is done with the stream (which can come later: a new stream was refused as
// busy in that moment).
TEST(ResumeTable, AParkedSessionHoldsItsStreamsSlotAndGivesItToANewStream) {
  ResumeTable table(absl::Seconds(30));
  ASSERT_TRUE(table.AdmitStream(1));
  EXPECT_FALSE(table.AdmitStream(1));  // the one slot is the stream's
  ParkedSession parked;
  parked.feed = std::make_shared<SessionFeed>("s1", "k1", TokenAuthenticator::kNoIdentity, 1 << 20);
  std::optional<ParkedSession> left;
  std::thread waiter([&] { left = table.ParkAndWait(std::move(parked)); });
  for (int i = 0; i < 500 && table.parked() == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_EQ(table.parked(), 1);
  // The parked session holds the slot (no StreamEnded for its stream): a new stream ends
  // its wait and takes the slot; the next one is refused.
  EXPECT_TRUE(table.AdmitStream(1));
  waiter.join();
  ASSERT_TRUE(left.has_value());  // evicted: handed back to be ended
  EXPECT_EQ(left->feed->id(), "s1");
  EXPECT_EQ(table.parked(), 0);
  EXPECT_FALSE(table.AdmitStream(1));
  table.StreamEnded();
  EXPECT_TRUE(table.AdmitStream(1));
  // With two slots, a stream and a parked session both fit.
  ResumeTable two(absl::Seconds(30));
  ASSERT_TRUE(two.AdmitStream(2));
  ParkedSession p2;
  p2.feed = std::make_shared<SessionFeed>("s2", "k2", TokenAuthenticator::kNoIdentity, 1 << 20);
  std::thread waiter2([&] { left = two.ParkAndWait(std::move(p2)); });
  for (int i = 0; i < 500 && two.parked() == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_EQ(two.parked(), 1);
  EXPECT_TRUE(two.AdmitStream(2));
  EXPECT_EQ(two.parked(), 1);  // not evicted: there was a free slot
  EXPECT_TRUE(two.AdmitStream(2));  // the third evicts it
  waiter2.join();
  EXPECT_FALSE(two.AdmitStream(2));
}

// Privacy: a session is read with its watch key or by its creator's bearer token; to every
// other call it does not exist, the same as an unknown id, and GetInfo does not list it.
TEST(SessionFeed, OnlyItsWatchKeyOrItsCreatorsTokenReadsIt) {
  const std::string key = NewSecret();
  ASSERT_EQ(key.size(), 32u);
  SessionFeed feed("s", key, /*owner=*/2, 1 << 20);
  EXPECT_TRUE(feed.MayRead(key, TokenAuthenticator::kNoIdentity));
  EXPECT_TRUE(feed.MayRead("", 2));
  EXPECT_FALSE(feed.MayRead("", TokenAuthenticator::kNoIdentity));
  EXPECT_FALSE(feed.MayRead("", 3));
  EXPECT_FALSE(feed.MayRead(NewSecret(), 3));
  EXPECT_FALSE(feed.MayRead(key.substr(0, 31), TokenAuthenticator::kNoIdentity));
  EXPECT_FALSE(feed.MayRead(key + key + key, TokenAuthenticator::kNoIdentity));
  // Without authentication nobody has an identity: the key alone reads it.
  SessionFeed open("o", key, TokenAuthenticator::kNoIdentity, 1 << 20);
  EXPECT_FALSE(open.MayRead("", TokenAuthenticator::kNoIdentity));

  FeedRegistry registry(absl::Seconds(60), 1 << 20);
  std::shared_ptr<SessionFeed> mine = registry.Create(key, 0);
  std::shared_ptr<SessionFeed> other = registry.Create(NewSecret(), 1);
  EXPECT_EQ(registry.FindReadable(mine->id(), key, TokenAuthenticator::kNoIdentity), mine);
  EXPECT_EQ(registry.FindReadable(mine->id(), "", 0), mine);
  EXPECT_EQ(registry.FindReadable(mine->id(), "", 1), nullptr);
  EXPECT_EQ(registry.FindReadable(mine->id(), other->watch_key(), 1), nullptr);
  EXPECT_EQ(registry.FindReadable("0123456789abcdef0123456789abcdef", key, 0), nullptr);
  auto ids = [](const std::vector<v1::SessionSummary>& list) {
    std::vector<std::string> out;
    for (const v1::SessionSummary& s : list) out.push_back(s.id());
    std::sort(out.begin(), out.end());
    return out;
  };
  EXPECT_TRUE(registry.Summaries({}, TokenAuthenticator::kNoIdentity).empty());
  EXPECT_EQ(ids(registry.Summaries({}, 1)), std::vector<std::string>{other->id()});
  EXPECT_EQ(ids(registry.Summaries({key}, TokenAuthenticator::kNoIdentity)),
            std::vector<std::string>{mine->id()});
  std::vector<std::string> both = {mine->id(), other->id()};
  std::sort(both.begin(), both.end());
  EXPECT_EQ(ids(registry.Summaries({key}, 1)), both);
}

// A sealed chunk of `bytes` bytes (its index and surface set).
v1::SealedChunk ChunkOfBytes(int64_t index, size_t bytes) {
  v1::SealedChunk c;
  c.set_index(index);
  c.set_draco(std::string(bytes, static_cast<char>('a' + index % 26)));
  return c;
}

// Resume from a client's kept chunks: once the chunks outgrow the watchers' retention, the
// feed keeps (for the session's own client) every chunk the client has not acknowledged,
// counted in the session's budget, and forgets each as it is acknowledged; without
// acknowledgements it keeps only the newest. The session's end gives the memory back.
TEST(SessionFeed, ChunksTheClientHasNotAcknowledgedOutliveTheWatchRetention) {
  constexpr int64_t kRetain = 4000;
  auto budget = std::make_shared<MemoryBudget>();
  SessionFeed feed("s", NewSecret(), TokenAuthenticator::kNoIdentity, kRetain);
  feed.SetSealed(true, "");
  feed.KeepUnacknowledged(budget);
  SessionFeed plain("p", NewSecret(), TokenAuthenticator::kNoIdentity, kRetain);
  plain.SetSealed(true, "");
  for (int64_t i = 0; i < 40; ++i) {
    feed.Chunk(ChunkOfBytes(i, 500));
    plain.Chunk(ChunkOfBytes(i, 500));
  }
  std::vector<v1::SealedChunk> replay;
  ASSERT_TRUE(feed.ChunksFrom(0, &replay).ok());
  ASSERT_EQ(replay.size(), 40u);
  for (int64_t i = 0; i < 40; ++i) {
    ASSERT_EQ(replay[static_cast<size_t>(i)].index(), i);
    ASSERT_EQ(replay[static_cast<size_t>(i)].draco(), ChunkOfBytes(i, 500).draco());
  }
  const absl::Status dropped = plain.ChunksFrom(0, &replay);
  EXPECT_EQ(dropped.code(), absl::StatusCode::kFailedPrecondition) << dropped;
  EXPECT_NE(dropped.message().find("--chunks DIR"), std::string::npos) << dropped;
  // What only the client's resume needs is in the budget; the newest kRetain are the
  // watchers' as before.
  const int64_t held = feed.unacknowledged_bytes();
  EXPECT_GT(held, 30 * 500);
  EXPECT_EQ(budget->held(), held);
  EXPECT_EQ(plain.unacknowledged_bytes(), 0);

  ASSERT_TRUE(feed.Acknowledge(25).ok());
  EXPECT_FALSE(feed.ChunksFrom(24, &replay).ok());
  ASSERT_TRUE(feed.ChunksFrom(25, &replay).ok());
  EXPECT_EQ(replay.size(), 15u);
  EXPECT_EQ(replay.front().index(), 25);
  EXPECT_LT(feed.unacknowledged_bytes(), held);
  EXPECT_EQ(budget->held(), feed.unacknowledged_bytes());
  ASSERT_TRUE(feed.Acknowledge(10).ok()) << "a lower count changes nothing";
  ASSERT_TRUE(feed.ChunksFrom(25, &replay).ok());
  const absl::Status too_many = feed.Acknowledge(41);
  EXPECT_EQ(too_many.code(), absl::StatusCode::kInvalidArgument) << too_many;
  EXPECT_NE(too_many.message().find("has sent 40 sealed chunks"), std::string::npos);
  // Acknowledged, a chunk is the watchers' rule's again: the next ones drop the old ones.
  ASSERT_TRUE(feed.Acknowledge(40).ok());
  EXPECT_EQ(feed.unacknowledged_bytes(), 0);
  feed.Chunk(ChunkOfBytes(40, 500));
  EXPECT_FALSE(feed.ChunksFrom(30, &replay).ok());
  ASSERT_TRUE(feed.ChunksFrom(40, &replay).ok());
  for (int64_t i = 41; i < 50; ++i) feed.Chunk(ChunkOfBytes(i, 500));  // 40, 41 not acknowledged
  EXPECT_EQ(feed.unacknowledged_bytes(), budget->held());
  EXPECT_GT(budget->held(), 0);
  ASSERT_TRUE(feed.ChunksFrom(40, &replay).ok());
  feed.Finish({}, grpc::Status::OK);  // no resume after the end
  EXPECT_EQ(feed.unacknowledged_bytes(), 0);
  EXPECT_EQ(budget->held(), 0);
}

// With a spill directory a feed keeps its chunks' bytes in an unlinked file, none in memory,
// and reads them back as they were posted: a watcher from the first chunk and a resume from
// the middle get byte-identical chunks. Dropped chunks leave the counts, and so does the feed.
TEST(SessionFeed, KeptChunksGoToTheSpillFileAndComeBackAsPosted) {
  const std::string dir = testing::MakeTempDir();
  for (const int64_t retain : {int64_t{1} << 20, int64_t{5000}}) {
    auto retention = std::make_shared<ChunkRetention>(retain, dir);
    {
      SessionFeed feed("s", NewSecret(), TokenAuthenticator::kNoIdentity, retention);
      feed.SetSealed(true, "");
      int64_t posted = 0;
      for (int64_t i = 0; i < 30; ++i) {
        feed.Chunk(ChunkOfBytes(i, 1000 + i));
        posted += static_cast<int64_t>(ChunkOfBytes(i, 1000 + i).ByteSizeLong());
      }
      EXPECT_EQ(retention->memory_bytes.load(), 0);
      EXPECT_TRUE(std::filesystem::is_empty(dir)) << "the spill file is unlinked";
      std::vector<v1::SealedChunk> replay;
      if (retain < posted) {
        // Past the retention, with nobody watching, only the newest stay, on disk too.
        EXPECT_LE(retention->spilled_bytes.load(), retain + 1100);
        EXPECT_FALSE(feed.ChunksFrom(17, &replay).ok());
        continue;
      }
      EXPECT_EQ(retention->spilled_bytes.load(), posted);
      ASSERT_TRUE(feed.ChunksFrom(17, &replay).ok());
      ASSERT_EQ(replay.size(), 13u);
      for (int64_t i = 17; i < 30; ++i) {
        EXPECT_EQ(replay[static_cast<size_t>(i - 17)].SerializeAsString(),
                  ChunkOfBytes(i, 1000 + i).SerializeAsString());
      }
      SessionFeed::Cursor cursor;
      std::optional<grpc::Status> done;
      for (int64_t i = 0; i < 30; ++i) {
        std::optional<v1::ExtractResponse> r = feed.Next(&cursor, &done);
        ASSERT_TRUE(r.has_value() && r->has_sealed_chunk()) << i;
        EXPECT_EQ(r->sealed_chunk().SerializeAsString(),
                  ChunkOfBytes(i, 1000 + i).SerializeAsString());
      }
    }
    EXPECT_EQ(retention->spilled_bytes.load(), 0) << "a feed gone gives its bytes back";
  }
}

// A spill directory that cannot be written keeps the chunks in memory, as without one.
TEST(SessionFeed, AnUnwritableSpillDirectoryKeepsTheChunksInMemory) {
  const std::string file = testing::MakeTempDir() + "/file";
  std::FILE* f = std::fopen(file.c_str(), "w");
  ASSERT_NE(f, nullptr);
  std::fclose(f);
  auto retention = std::make_shared<ChunkRetention>(int64_t{1} << 20, file + "/sub");
  SessionFeed feed("s", NewSecret(), TokenAuthenticator::kNoIdentity, retention);
  feed.SetSealed(true, "");
  int64_t posted = 0;
  for (int64_t i = 0; i < 5; ++i) {
    feed.Chunk(ChunkOfBytes(i, 700));
    posted += static_cast<int64_t>(ChunkOfBytes(i, 700).ByteSizeLong());
  }
  EXPECT_EQ(retention->spilled_bytes.load(), 0);
  EXPECT_EQ(retention->memory_bytes.load(), posted);
  std::vector<v1::SealedChunk> replay;
  ASSERT_TRUE(feed.ChunksFrom(2, &replay).ok());
  ASSERT_EQ(replay.size(), 3u);
  EXPECT_EQ(replay[0].SerializeAsString(), ChunkOfBytes(2, 700).SerializeAsString());
}

// A write the disk refuses (here the file size limit, as a full disk would) keeps that chunk
// in memory; the chunks before it stay on disk, and all of them come back as posted.
TEST(SessionFeed, AChunkTheSpillFileCannotTakeStaysInMemory) {
  auto retention = std::make_shared<ChunkRetention>(int64_t{1} << 20, testing::MakeTempDir());
  SessionFeed feed("s", NewSecret(), TokenAuthenticator::kNoIdentity, retention);
  feed.SetSealed(true, "");
  feed.Chunk(ChunkOfBytes(0, 3000));
  feed.Chunk(ChunkOfBytes(1, 3000));
  const int64_t on_disk = retention->spilled_bytes.load();
  rlimit old{};
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old), 0);
  rlimit small = old;
  small.rlim_cur = 8000;  // the third chunk would end past it
  void (*old_handler)(int) = std::signal(SIGXFSZ, SIG_IGN);
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);
  feed.Chunk(ChunkOfBytes(2, 3000));
  setrlimit(RLIMIT_FSIZE, &old);
  std::signal(SIGXFSZ, old_handler);
  feed.Chunk(ChunkOfBytes(3, 3000));
  const int64_t third = static_cast<int64_t>(ChunkOfBytes(2, 3000).ByteSizeLong());
  EXPECT_EQ(retention->memory_bytes.load(), third);
  EXPECT_EQ(retention->spilled_bytes.load(),
            on_disk + static_cast<int64_t>(ChunkOfBytes(3, 3000).ByteSizeLong()));
  std::vector<v1::SealedChunk> replay;
  ASSERT_TRUE(feed.ChunksFrom(0, &replay).ok());
  ASSERT_EQ(replay.size(), 4u);
  for (int64_t i = 0; i < 4; ++i) {
    EXPECT_EQ(replay[static_cast<size_t>(i)].SerializeAsString(),
              ChunkOfBytes(i, 3000).SerializeAsString());
  }
}

}  // namespace
}  // namespace tandem::server
