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
//   * progress counts never go back; the final messages come once, after End: per surface
//     FinalMesh chunks 0..n-1 with one total size (none when sealed), then its FinalMetrics,
//     and the Draco bytes decode to the announced triangle and vertex counts; a label
//     session's surfaces carry their labels in order, then the session's FinalMetrics
//     counts them.
// Option byte: bit 0 = tiny memory budget (256 KiB, to reach the budget checks), bit 1 =
// max message 4 KiB (bigger chunks are refused as gRPC would, before the job sees them).
//
// SessionConfig.compute_distances is cleared (seconds of Metro sampling per input).
// Seeds: run with TANDEM_FUZZ_WRITE_SEEDS=DIR to write valid streams (every dtype, chunked
// and whole slices, unknown nz, previews, each schedule, a target, label maps whole and
// sealed) into DIR and exit.
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
#include "tandem/common/wire.h"
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

// A surface's whole Draco bytes against what its last FinalMesh chunk announced.
void CheckMesh(const std::string& draco, const tandem::v1::FinalMesh& last) {
  if (draco.size() != last.total_bytes()) Violation("FinalMesh total_bytes is wrong");
  absl::StatusOr<tandem::IndexedMesh> mesh = tandem::codec::DecodeDraco(draco);
  if (!mesh.ok()) {
    Violation("the final mesh does not decode: " + std::string(mesh.status().message()));
  }
  if (static_cast<int64_t>(mesh->num_triangles()) != last.triangles() ||
      static_cast<int64_t>(mesh->num_vertices()) != last.vertices()) {
    Violation("the final mesh's counts differ from the announced ones");
  }
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
    tandem::SealedChunk pairs;
    tandem::LabelId background = 0;
    if (c.has_label_pairs() &&
        !tandem::common::LabelPairsFromProto(c.label_pairs(), static_cast<size_t>(c.triangles()),
                                             &pairs, &background)
             .ok()) {
      Violation("a label chunk's pairs do not cover its triangles");
    }
  }
  void PostFinal(std::vector<ExtractResponse> messages) override {
    if (finals_++ > 0) Violation("final messages posted twice");
    if (messages.empty() || !messages.back().has_final_metrics() ||
        messages.back().final_metrics().has_label()) {
      Violation("the final messages do not end with the session's FinalMetrics");
    }
    const tandem::v1::FinalMetrics& session = messages.back().final_metrics();
    // Sealed chunks: the mesh went out in them (an unsealed session has sent none either).
    const bool sealed = session.sealed_chunks() == chunks_;
    int64_t labels = 0;
    for (size_t i = 0; i < messages.size(); ++i) {  // a surface: its FinalMesh chunks, metrics
      const size_t first = i;
      std::string draco;
      for (; i < messages.size() && messages[i].has_final_mesh(); ++i) {
        const tandem::v1::FinalMesh& m = messages[i].final_mesh();
        if (m.chunk_index() != i - first ||
            m.chunk_count() != messages[first].final_mesh().chunk_count()) {
          Violation("FinalMesh chunks out of order");
        }
        draco += m.draco();
      }
      if (i == messages.size() || !messages[i].has_final_metrics()) {
        Violation("FinalMesh chunks not followed by their FinalMetrics");
      }
      const tandem::v1::FinalMetrics& metrics = messages[i].final_metrics();
      if (i > first) {
        const tandem::v1::FinalMesh& last = messages[i - 1].final_mesh();
        if (last.chunk_count() != i - first) Violation("FinalMesh chunks missing");
        CheckMesh(draco, last);
        if (last.has_label() != metrics.has_label() || last.label() != metrics.label()) {
          Violation("a FinalMesh and its FinalMetrics name different labels");
        }
      } else if (!sealed) {
        Violation("a surface without its FinalMesh in an unsealed session");
      }
      if (metrics.has_label() && metrics.surface() != labels++) {
        Violation("label surfaces out of order");
      }
    }
    if (labels != session.labels()) {
      Violation("the session's label count differs from the labels' FinalMetrics");
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

// A slice's bytes as SliceChunk requests of at most `chunk` bytes.
void AppendSlice(int64_t z, const std::string& slice, size_t chunk,
                 std::vector<ExtractRequest>* requests) {
  for (size_t off = 0; off < slice.size(); off += chunk) {
    tandem::v1::SliceChunk* c = requests->emplace_back().mutable_chunk();
    c->set_slice(z);
    c->set_offset(off);
    c->set_data(slice.substr(off, chunk));
    if (off == 0) c->set_slice_size(slice.size());
  }
}

// DIR/seed_NAME: the option byte 0, then the requests, length-delimited.
void WriteSeed(const std::string& dir, const std::string& name,
               const std::vector<ExtractRequest>& requests) {
  std::ofstream out(dir + "/seed_" + name, std::ios::binary);
  out.put('\0');
  for (const ExtractRequest& r : requests) {
    google::protobuf::util::SerializeDelimitedToOstream(r, &out);
  }
  if (!out) Violation("cannot write seed " + name);
}

// Label maps (SessionConfig.labels), whole and sealed: five Voronoi cells with ids
// `first` + 7 k in each integer width, a ball of background (0) in the middle.
void WriteLabelSeeds(const std::string& dir) {
  struct LabelSeed {
    const char* name;
    tandem::v1::DType dtype;
    int bytes;
    uint64_t first;
    size_t chunk;
    void (*edit)(tandem::v1::SessionConfig*);
  };
  const LabelSeed seeds[] = {
      {"labels_uint8_previews", tandem::v1::DTYPE_UINT8, 1, 1, 1 << 20,
       [](auto* c) { c->mutable_preview()->set_every_slices(3); }},
      {"labels_uint16_sealed_close", tandem::v1::DTYPE_UINT16, 2, 1000, 100,
       [](auto* c) {
         c->set_sealed_chunks(true);
         c->mutable_labels()->set_close(true);
         c->mutable_preview()->set_every_slices(4);
       }},
      {"labels_uint32_background_only", tandem::v1::DTYPE_UINT32, 4, 3000000000u, 1 << 20,
       [](auto* c) {  // the first cell is what surrounds; two of the others are meshed
         c->mutable_labels()->set_background(3000000000u);
         c->mutable_labels()->add_only(3000000007u);
         c->mutable_labels()->add_only(3000000014u);
       }},
      {"labels_uint64_sealed", tandem::v1::DTYPE_UINT64, 8, uint64_t{1} << 40, 64,
       [](auto* c) { c->set_sealed_chunks(true); }},
  };
  constexpr int64_t kN = 12;
  const double cells[5][3] = {{2, 3, 2}, {9, 2, 4}, {3, 9, 8}, {10, 10, 10}, {6, 5, 11}};
  for (const LabelSeed& s : seeds) {
    std::vector<ExtractRequest> requests;
    tandem::v1::SessionConfig* c = requests.emplace_back().mutable_config();
    c->set_nx(kN);
    c->set_ny(kN);
    c->set_nz(kN);
    c->set_dtype(s.dtype);
    c->set_error(0.5);
    c->mutable_labels()->set_enabled(true);
    s.edit(c);
    for (int64_t z = 0; z < kN; ++z) {
      std::string slice;
      for (int64_t y = 0; y < kN; ++y) {
        for (int64_t x = 0; x < kN; ++x) {
          uint64_t id = 0;
          const double dx = x - 5.5, dy = y - 5.5, dz = static_cast<double>(z) - 5.5;
          if (dx * dx + dy * dy + dz * dz > 6) {
            double best = 1e30;
            for (int k = 0; k < 5; ++k) {
              const double ex = x - cells[k][0], ey = y - cells[k][1], ez = z - cells[k][2];
              const double d = ex * ex + ey * ey + ez * ez;
              if (d < best) {
                best = d;
                id = s.first + 7 * static_cast<uint64_t>(k);
              }
            }
          }
          for (int b = 0; b < s.bytes; ++b) slice.push_back(static_cast<char>(id >> (8 * b)));
        }
      }
      AppendSlice(z, slice, s.chunk, &requests);
    }
    requests.emplace_back().mutable_end()->set_slices(kN);
    WriteSeed(dir, s.name, requests);
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
      AppendSlice(z, slice, s.chunk, &requests);
    }
    requests.emplace_back().mutable_end()->set_slices(info.nz);
    WriteSeed(dir, s.name, requests);
  }
  WriteLabelSeeds(dir);
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
