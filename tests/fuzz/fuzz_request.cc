// libFuzzer target: the server's request handling without gRPC. The input is one option
// byte, then a sequence of ExtractRequest messages, each prefixed by its length as a
// varint (protobuf's delimited format: google::protobuf::util::SerializeDelimitedTo*).
// They are fed, in order, to server::ExtractJob (which runs request_validation.h's checks,
// assembles slices and drives a real TandemSession) exactly as the server's worker thread
// does, under small limits. An unparsable record ends the input (the client half-closed).
//
// Checked (a violation aborts, so libFuzzer records it):
//   * an error status has a message and the code INVALID_ARGUMENT or RESOURCE_EXHAUSTED
//     (INTERNAL only for a failed final encoding, which must not happen either: aborts);
//   * the end of input is OK exactly when End was handled (done());
//   * progress counts never go back; the final messages come once, after End: FinalMesh
//     chunks 0..n-1 with one total size, then FinalMetrics, and the Draco bytes decode to
//     the announced triangle and vertex counts.
// Option byte: bit 0 = tiny memory budget (256 KiB, to reach the budget checks), bit 1 =
// max message 4 KiB (bigger chunks are refused as gRPC would, before the job sees them).
//
// SessionConfig.compute_distances is cleared (seconds of Metro sampling per input).
// Seeds: run with TANDEM_FUZZ_WRITE_SEEDS=DIR to write valid streams (every dtype, chunked
// and whole slices, unknown nz, previews, each schedule, a target) into DIR and exit.
// TANDEM_FUZZ_VERBOSE=1 prints how each input ended.
#include <google/protobuf/io/coded_stream.h>
#include <google/protobuf/io/zero_copy_stream_impl_lite.h>
#include <google/protobuf/util/delimited_message_util.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include "tandem/codec/draco_codec.h"
#include "tandem/eval/synthetic.h"
#include "tandem/server/extract_job.h"
#include "tandem/server/request_validation.h"
#include "tandem/v1/tandem.pb.h"

namespace {

using tandem::v1::ExtractRequest;
using tandem::v1::ExtractResponse;

[[noreturn]] void Violation(const std::string& what) {
  std::fprintf(stderr, "fuzz_request: %s\n", what.c_str());
  std::fflush(stderr);
  std::abort();
}

class CheckingSink : public tandem::server::JobSink {
 public:
  void PostProgress(tandem::v1::Progress p) override {
    if (p.slices_consumed() < last_slices_) Violation("progress went back");
    last_slices_ = p.slices_consumed();
  }
  void PostPreview(tandem::v1::Preview p) override {
    if (p.draco().empty()) Violation("empty preview");
  }
  void PostChunk(tandem::v1::SealedChunk c) override {
    if (finals_ > 0) Violation("a sealed chunk after the final messages");
    if (c.index() != chunks_++) Violation("sealed chunks out of order");
    if (c.draco().empty() || c.triangles() <= 0) Violation("empty sealed chunk");
  }
  void PostFinal(std::vector<ExtractResponse> messages) override {
    if (finals_++ > 0) Violation("final messages posted twice");
    if (messages.size() == 1 && messages[0].has_final_metrics() &&
        messages[0].final_metrics().sealed_chunks() == chunks_) {
      return;  // sealed chunks: the mesh went out in them
    }
    if (messages.size() < 2 || !messages.back().has_final_metrics()) {
      Violation("the final messages do not end with FinalMetrics");
    }
    std::string draco;
    for (size_t i = 0; i + 1 < messages.size(); ++i) {
      const tandem::v1::FinalMesh& m = messages[i].final_mesh();
      if (!messages[i].has_final_mesh() || m.chunk_index() != i ||
          m.chunk_count() != messages.size() - 1) {
        Violation("FinalMesh chunks out of order");
      }
      draco += m.draco();
    }
    const tandem::v1::FinalMesh& last = messages[messages.size() - 2].final_mesh();
    if (draco.size() != last.total_bytes()) Violation("FinalMesh total_bytes is wrong");
    absl::StatusOr<tandem::IndexedMesh> mesh = tandem::codec::DecodeDraco(draco);
    if (!mesh.ok())
      Violation("the final mesh does not decode: " + std::string(mesh.status().message()));
    if (static_cast<int64_t>(mesh->num_triangles()) != last.triangles() ||
        static_cast<int64_t>(mesh->num_vertices()) != last.vertices()) {
      Violation("the final mesh's counts differ from the announced ones");
    }
  }
  int finals() const { return finals_; }

 private:
  int64_t last_slices_ = 0;
  int finals_ = 0;
  int64_t chunks_ = 0;
};

void CheckError(const absl::Status& st) {
  if (st.message().empty()) Violation("error status without a message");
  if (!absl::IsInvalidArgument(st) && !absl::IsResourceExhausted(st)) {
    Violation("unexpected code: " + st.ToString());
  }
}

// Valid streams for the corpus.
void WriteSeeds(const std::string& dir) {
  using tandem::eval::Shape;
  struct Seed {
    const char* name;
    Shape shape;
    int64_t n, nz;
    tandem::v1::DType dtype;
    size_t chunk;
    bool unknown_nz;
    void (*edit)(tandem::v1::SessionConfig*);
  };
  const Seed seeds[] = {
      {"sphere_float32_chunked", Shape::kSphere, 12, 12, tandem::v1::DTYPE_FLOAT32, 200, false,
       [](auto* c) { c->set_error(0.5); }},
      {"link_float32_whole_previews", Shape::kLink, 16, 16, tandem::v1::DTYPE_FLOAT32, 1 << 20,
       false,
       [](auto* c) {
         c->set_error(0.3);
         c->mutable_preview()->set_every_slices(3);
       }},
      {"sphere_uint8_unknown_nz", Shape::kSphere, 10, 10, tandem::v1::DTYPE_UINT8, 1 << 20, true,
       [](auto* c) {
         c->set_error(0.5);
         c->set_iso(128);
         c->set_schedule(tandem::v1::SCHEDULE_CLASSICAL);
       }},
      {"sphere_int16_tandem", Shape::kSphere, 10, 10, tandem::v1::DTYPE_INT16, 64, false,
       [](auto* c) {
         c->set_error(0.5);
         c->set_schedule(tandem::v1::SCHEDULE_TANDEM);
       }},
      {"gyroid_uint16_none", Shape::kGyroid, 12, 12, tandem::v1::DTYPE_UINT16, 100, false,
       [](auto* c) {
         c->set_iso(32768);
         c->set_schedule(tandem::v1::SCHEDULE_NONE);
         c->mutable_draco()->set_compression_level(0);
       }},
      {"pillowbox_target", Shape::kPillowBox, 12, 12, tandem::v1::DTYPE_FLOAT32, 1 << 20, false,
       [](auto* c) {
         c->set_error(0.2);
         c->set_target_triangles(40);
         c->set_alpha(0.5);
       }},
  };
  for (const Seed& s : seeds) {
    auto source = tandem::eval::MakeSyntheticSource(s.shape, s.n, s.n, s.nz);
    const tandem::VolumeInfo& info = source->info();
    std::vector<ExtractRequest> requests;
    tandem::v1::SessionConfig* c = requests.emplace_back().mutable_config();
    c->set_nx(info.nx);
    c->set_ny(info.ny);
    c->set_nz(s.unknown_nz ? 0 : info.nz);
    c->set_dtype(s.dtype);
    s.edit(c);
    std::vector<uint8_t> bytes;
    std::vector<float> values;
    for (int64_t z = 0; z < info.nz; ++z) {
      if (!source->ReadSlice(&bytes).ok()) Violation("seed source failed");
      values.assign(reinterpret_cast<const float*>(bytes.data()),
                    reinterpret_cast<const float*>(bytes.data()) + info.slice_voxels());
      std::string slice;
      for (float v : values) {  // the field is a signed distance; map it into each dtype
        switch (s.dtype) {
          case tandem::v1::DTYPE_UINT8:
            slice.push_back(
                static_cast<char>(static_cast<uint8_t>(std::clamp(128 + 40 * v, 0.f, 255.f))));
            break;
          case tandem::v1::DTYPE_INT16: {
            const int16_t x = static_cast<int16_t>(std::clamp(100 * v, -32768.f, 32767.f));
            slice.append(reinterpret_cast<const char*>(&x), 2);
            break;
          }
          case tandem::v1::DTYPE_UINT16: {
            const uint16_t x = static_cast<uint16_t>(std::clamp(32768 + 1000 * v, 0.f, 65535.f));
            slice.append(reinterpret_cast<const char*>(&x), 2);
            break;
          }
          default:
            slice.append(reinterpret_cast<const char*>(&v), 4);
        }
      }
      for (size_t off = 0; off < slice.size(); off += s.chunk) {
        tandem::v1::SliceChunk* chunk = requests.emplace_back().mutable_chunk();
        chunk->set_slice(z);
        chunk->set_offset(off);
        chunk->set_data(slice.substr(off, s.chunk));
        if (off == 0) chunk->set_slice_size(slice.size());
      }
    }
    requests.emplace_back().mutable_end()->set_slices(info.nz);
    std::ofstream out(dir + "/seed_" + s.name, std::ios::binary);
    out.put('\0');
    for (const ExtractRequest& r : requests) {
      google::protobuf::util::SerializeDelimitedToOstream(r, &out);
    }
    if (!out) Violation(std::string("cannot write seed ") + s.name);
  }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  if (const char* dir = std::getenv("TANDEM_FUZZ_WRITE_SEEDS"); dir != nullptr) {
    WriteSeeds(dir);
    std::fprintf(stderr, "fuzz_request: seeds written to %s\n", dir);
    std::exit(0);
  }
  return 0;
}

// TANDEM_FUZZ_VERBOSE=1: print how each input ended (corpus triage).
void Report(const char* how, const absl::Status& st) {
  static const bool verbose = std::getenv("TANDEM_FUZZ_VERBOSE") != nullptr;
  if (verbose) std::fprintf(stderr, "fuzz_request: %s: %s\n", how, st.ToString().c_str());
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const uint8_t options = data[0];
  tandem::server::ServerLimits limits;
  limits.max_voxels_per_slice = 64 * 64;
  limits.max_slices = 64;
  limits.max_message_bytes = (options & 2) ? 4096 : 1 << 20;
  limits.session_memory_bytes = (options & 1) ? 256 << 10 : 16 << 20;

  CheckingSink sink;
  tandem::server::ExtractJob job(limits, &sink);
  google::protobuf::io::ArrayInputStream array(data + 1, static_cast<int>(size - 1));
  google::protobuf::io::CodedInputStream coded(&array);
  coded.SetTotalBytesLimit(static_cast<int>(size));
  ExtractRequest request;
  while (!coded.ExpectAtEnd()) {
    request.Clear();
    if (!google::protobuf::util::ParseDelimitedFromCodedStream(&request, &coded, nullptr)) {
      break;  // garbage: the stream ends here
    }
    // Metro distances sample the surfaces for seconds per input under ASan, and are not
    // request handling (core's metrics tests cover them): keep them off.
    if (request.has_config()) request.mutable_config()->set_compute_distances(false);
    if (static_cast<int64_t>(request.ByteSizeLong()) > limits.max_message_bytes) {
      Report("message over the limit", absl::OkStatus());
      return 0;  // gRPC refuses it (RESOURCE_EXHAUSTED) before the job sees it
    }
    const bool was_done = job.done();
    const absl::Status st = job.Handle(request);
    if (!st.ok()) {
      CheckError(st);
      if (sink.finals() > 0 && !was_done) Violation("an error after the final messages");
      Report("refused", st);
      return 0;  // the stream ends with this status
    }
    if (was_done) Violation("a message after End was accepted");
  }
  const absl::Status end = job.HandleEndOfInput();
  if (end.ok() != job.done()) Violation("end of input: " + end.ToString());
  if (!end.ok()) CheckError(end);
  if (job.done() != (sink.finals() == 1)) Violation("done() without final messages");
  Report(job.done() ? "done" : "end of input", end);
  return 0;
}
