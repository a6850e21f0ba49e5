#include "tandem/client/stream_client.h"

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <optional>
#include <thread>
#include <vector>

#include "absl/random/distributions.h"
#include "absl/random/random.h"
#include "absl/strings/cord.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/common/wire.h"
#include "tandem/labels.h"
#include "tandem/status_macros.h"
#include "tandem/v1/tandem.grpc.pb.h"

namespace tandem::client {
namespace {

constexpr char kLocalPayload[] = "type.googleapis.com/tandem.client.LocalError";

using Stream = grpc::ClientReaderWriter<v1::ExtractRequest, v1::ExtractResponse>;

// What the server's messages say, in order: callbacks, the final mesh's chunks and their
// checks (an Extract stream's or a watcher's).
class Collector {
 public:
  // `sealed`: the mesh is expected as sealed chunks (the messages decide in the end);
  // `surfaces`: 1 + config.extra_isos, or 0 to learn them from the messages (a watcher, which
  // also learns whether it is a label session). `labels`: a label session (config.labels),
  // whose surfaces are its labels, as many as the session's own metrics say.
  Collector(const StreamCallbacks& callbacks, StreamResult* result, bool sealed, size_t surfaces,
            bool labels = false)
      : callbacks_(callbacks),
        result_(*result),
        state_(std::max<size_t>(surfaces, 1)),
        learn_surfaces_(surfaces == 0 || labels),
        learn_labels_(surfaces == 0),
        labels_(labels) {
    result_.sealed_session = sealed;
    result_.labels = labels;
    result_.extra_surfaces.resize(state_.size() - 1);
  }

  void Handle(const v1::ExtractResponse& response, int64_t slices_sent) {
    StreamResult& result = result_;
    if (learn_labels_ && !labels_ && Labeled(response)) {
      labels_ = true;
      result.labels = true;
    }
    switch (response.kind_case()) {
      case v1::ExtractResponse::kProgress:
        if (callbacks_.on_progress) callbacks_.on_progress(response.progress(), slices_sent);
        break;
      case v1::ExtractResponse::kPreview:
        if (callbacks_.on_preview) callbacks_.on_preview(response.preview(), slices_sent);
        break;
      case v1::ExtractResponse::kFinalMesh: {
        result.sealed_session = false;
        const v1::FinalMesh& m = response.final_mesh();
        SurfaceResult* out = Surface(m.surface(), "final mesh");
        if (out == nullptr) break;
        State& st = state_[m.surface()];
        if (m.chunk_index() != st.next_chunk ||
            (st.next_chunk > 0 && m.chunk_count() != st.chunk_count) || m.chunk_count() == 0) {
          malformed_ = absl::StrCat("final mesh chunk ", m.chunk_index(), " of ", m.chunk_count(),
                                    " arrived, expected chunk ", st.next_chunk);
        }
        st.chunk_count = m.chunk_count();
        ++st.next_chunk;
        out->draco += m.draco();
        out->triangles = m.triangles();
        out->vertices = m.vertices();
        if (m.chunk_index() + 1 == m.chunk_count() && out->draco.size() != m.total_bytes()) {
          malformed_ = absl::StrCat("final mesh has ", out->draco.size(),
                                    " bytes, the server said ", m.total_bytes());
        }
        break;
      }
      case v1::ExtractResponse::kSealedChunk: {
        const v1::SealedChunk& c = response.sealed_chunk();
        result.sealed_session = true;
        if (callbacks_.on_chunk) callbacks_.on_chunk(c);
        if (!malformed_.empty()) break;
        // A label session's chunk holds label pairs (each label takes its part), or is one
        // label's: the labels' places are known at End.
        const bool by_pairs = labels_ && c.has_label_pairs();
        SurfaceResult* out = nullptr;
        if (!by_pairs) {
          out = labels_ && c.has_label() ? &label_chunks_[c.label()]
                                         : Surface(c.surface(), "sealed chunk");
          if (out == nullptr) break;
        }
        LabelId background = 0;
        std::optional<SealedChunk> chunk = DecodeChunk(c, by_pairs ? &background : nullptr);
        if (!chunk.has_value()) break;
        if (!by_pairs) {
          out->sealed.push_back(*std::move(chunk));
          break;
        }
        for (auto& [label, part] : SplitLabeledChunk(*chunk, background)) {
          label_chunks_[label].sealed.push_back(std::move(part));
        }
        break;
      }
      case v1::ExtractResponse::kFinalMetrics: {
        const v1::FinalMetrics& m = response.final_metrics();
        if (labels_ && !m.has_label()) {  // the session's own, the last message
          result.session_metrics = m;
          have_session_metrics_ = true;
          break;
        }
        SurfaceResult* out = Surface(m.surface(), "final metrics");
        if (out == nullptr) break;
        out->metrics = m;
        state_[m.surface()].have_metrics = true;
        break;
      }
      default:
        break;  // a newer server's message: ignore
    }
  }

  // After an OK status: what is missing or inconsistent ("" when the reply is whole).
  std::string Check() {
    StreamResult& result = result_;
    size_t surfaces = state_.size();
    if (labels_ && malformed_.empty()) {
      surfaces = static_cast<size_t>(std::max<int64_t>(0, result.session_metrics.labels()));
      if (!have_session_metrics_) {
        malformed_ = "the label stream ended without the session's final metrics";
      } else if (surfaces != learned_) {
        malformed_ =
            absl::StrCat("the label stream sent ", learned_, " labels; its metrics say ", surfaces);
      }
      if (surfaces == 0) result.extra_surfaces.clear();
    }
    for (size_t i = 0; i < surfaces && malformed_.empty(); ++i) {
      SurfaceResult& out = result.surface(i);
      const State& st = state_[i];
      const std::string which = state_.size() > 1 ? absl::StrCat(" of surface ", i) : "";
      if (result.sealed_session) {
        if (labels_ && st.have_metrics) {
          auto it = label_chunks_.find(out.metrics.label());
          if (it != label_chunks_.end()) {
            out.sealed = std::move(it->second.sealed);
            label_chunks_.erase(it);
          }
        }
        if (st.have_metrics) {
          // The union of the chunks is the final mesh: it must have the final counts.
          const IndexedMesh mesh = WeldChunks(out.sealed);
          out.triangles = static_cast<int64_t>(mesh.num_triangles());
          out.vertices = static_cast<int64_t>(mesh.num_vertices());
          if (out.triangles != out.metrics.triangles_final() ||
              out.vertices != out.metrics.vertices_final()) {
            malformed_ = absl::StrCat("the sealed chunks", which, " weld into ", out.triangles,
                                      " triangles and ", out.vertices, " vertices; the metrics say ",
                                      out.metrics.triangles_final(), " and ",
                                      out.metrics.vertices_final());
          }
        }
      } else if (st.chunk_count == 0 || st.next_chunk != st.chunk_count) {
        malformed_ = absl::StrCat("the stream ended after ", st.next_chunk, " of ", st.chunk_count,
                                  " final mesh chunks", which);
      }
      if (malformed_.empty() && !st.have_metrics) {
        malformed_ = absl::StrCat("the stream ended without final metrics", which);
      }
    }
    if (malformed_.empty() && !label_chunks_.empty()) {
      malformed_ = absl::StrCat("sealed chunks of label ", label_chunks_.begin()->first,
                                " arrived, but no final metrics for it");
    }
    return malformed_;
  }

 private:
  // Whether a message says it is a label session's (a watcher learns it so).
  static bool Labeled(const v1::ExtractResponse& r) {
    switch (r.kind_case()) {
      case v1::ExtractResponse::kProgress:
        return r.progress().labels();
      case v1::ExtractResponse::kPreview:
        return r.preview().labels_size() > 0;
      case v1::ExtractResponse::kSealedChunk:
        return r.sealed_chunk().has_label() || r.sealed_chunk().has_label_pairs();
      case v1::ExtractResponse::kFinalMesh:
        return r.final_mesh().has_label();
      case v1::ExtractResponse::kFinalMetrics:
        return r.final_metrics().has_label();
      default:
        return false;
    }
  }
  // A sealed chunk decoded, with its label pairs when `background` is given (which gets
  // theirs), or nullopt with the stream malformed.
  std::optional<SealedChunk> DecodeChunk(const v1::SealedChunk& c, LabelId* background) {
    SealedChunk chunk;
    absl::StatusOr<IndexedMesh> mesh = codec::DecodeDraco(c.draco(), &chunk.ids);
    absl::Status pairs = mesh.status();
    if (mesh.ok() && background != nullptr) {
      pairs =
          common::LabelPairsFromProto(c.label_pairs(), mesh->num_triangles(), &chunk, background);
    }
    if (c.index() != chunks_) {
      malformed_ = absl::StrCat("sealed chunk ", c.index(), " arrived, expected chunk ", chunks_);
    } else if (!pairs.ok()) {
      malformed_ = absl::StrCat("sealed chunk ", c.index(), ": ", pairs.ToString());
    } else if (static_cast<int64_t>(mesh->num_triangles()) != c.triangles() ||
               static_cast<int64_t>(mesh->num_vertices()) < c.vertices()) {  // splits
      malformed_ = absl::StrCat("sealed chunk ", c.index(), " decodes to ", mesh->num_triangles(),
                                " triangles, announced ", c.triangles());
    }
    if (!malformed_.empty()) return std::nullopt;
    ++chunks_;
    chunk.index = c.index();
    chunk.first_slice = c.first_slice();
    chunk.last_slice = c.last_slice();
    chunk.positions = std::move(mesh->positions);
    chunk.indices = std::move(mesh->indices);
    return chunk;
  }
  // A sealed label session: the chunks of each label, until its metrics give its place.
  std::map<uint64_t, SurfaceResult> label_chunks_;
  struct State {
    uint32_t next_chunk = 0, chunk_count = 0;
    bool have_metrics = false;
  };
  // The result for a message's surface, or nullptr (and malformed) for one not asked for.
  SurfaceResult* Surface(int32_t surface, const char* what) {
    if (labels_ && surface >= 0) {
      // A label's surfaces come in turn: only the next one may begin.
      const auto s = static_cast<size_t>(surface);
      if (s + 1 == learned_ || s == learned_) {
        learned_ = s + 1;
        if (s >= state_.size()) {
          state_.resize(s + 1);
          result_.extra_surfaces.resize(s);
        }
        return &result_.surface(s);
      }
      if (malformed_.empty()) {
        malformed_ = absl::StrCat(what, " for label surface ", surface, " arrived after surface ",
                                  learned_ == 0 ? -1 : static_cast<int64_t>(learned_) - 1);
      }
      return nullptr;
    }
    if (learn_surfaces_ && surface > 0 && surface < kMaxSurfaces &&
        static_cast<size_t>(surface) >= state_.size()) {
      state_.resize(static_cast<size_t>(surface) + 1);
      result_.extra_surfaces.resize(state_.size() - 1);
    }
    if (surface < 0 || static_cast<size_t>(surface) >= state_.size()) {
      if (malformed_.empty()) {
        malformed_ = absl::StrCat(what, " for surface ", surface, " arrived; the stream has ",
                                  state_.size());
      }
      return nullptr;
    }
    return &result_.surface(static_cast<size_t>(surface));
  }

  const StreamCallbacks& callbacks_;
  StreamResult& result_;
  std::string malformed_;
  static constexpr int32_t kMaxSurfaces = 8;  // tandem.proto: SessionConfig.extra_isos
  std::vector<State> state_;  // per surface
  const bool learn_surfaces_;
  const bool learn_labels_;
  bool labels_;
  size_t learned_ = 0;  // labels: the surfaces begun so far
  bool have_session_metrics_ = false;
  int64_t& chunks_ = result_.chunks_received;  // all surfaces together
};

// The sending half, on its own thread: config, chunks of every slice (paced by `rate`),
// End. Write() blocks while the server is not reading (its flow control), which is what
// keeps both sides' memory bounded. Returns a local error (reading the volume); a failed
// Write just stops, since the server's status explains why.
class Sender {
 public:
  // Sends `config`, then the slices from `first_slice` on, read from the source (which
  // must not be past it; slices before it are skipped).
  Sender(SliceSource& source, const StreamOptions& options, const v1::SessionConfig& config,
         int64_t first_slice, Stream* stream)
      : source_(source),
        options_(options),
        config_(config),
        first_slice_(first_slice),
        stream_(stream),
        slices_sent_(first_slice) {}

  absl::Status Run();
  // Wakes a paced sender and makes it stop (the response stream ended).
  void Stop() {
    absl::MutexLock lock(&mu_);
    stop_ = true;
  }
  // The server answered (its first message says it took the session): slices may flow.
  // Until then nothing is read from the volume, so a refused stream can be sent again.
  void Accept() {
    absl::MutexLock lock(&mu_);
    accepted_ = true;
  }
  // The client keeps sealed chunks 0 .. count-1: a ChunksReceived goes out before the next
  // slice (or at once, while paced), until End.
  void Acknowledge(int64_t count) {
    absl::MutexLock lock(&mu_);
    ack_wanted_ = std::max(ack_wanted_, count);
  }
  int64_t slices_sent() const {
    absl::MutexLock lock(&mu_);
    return slices_sent_;
  }

 private:
  // The next slice from the source: *data points into `bytes` or into a mapped file;
  // OutOfRange at the end of the volume.
  absl::Status FromSource(std::vector<uint8_t>* bytes, const uint8_t** data, size_t* size);
  // Writes a ChunksReceived if one is due; false when the stream is broken.
  bool SendAcknowledgement();
  bool AckDueLocked() const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return ack_wanted_ > ack_sent_; }

  SliceSource& source_;
  const StreamOptions& options_;
  const v1::SessionConfig& config_;
  const int64_t first_slice_;
  Stream* stream_;
  mutable absl::Mutex mu_;
  bool stop_ ABSL_GUARDED_BY(mu_) = false;
  bool accepted_ ABSL_GUARDED_BY(mu_) = false;
  int64_t slices_sent_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t ack_wanted_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t ack_sent_ ABSL_GUARDED_BY(mu_) = 0;
};

bool Sender::SendAcknowledgement() {
  v1::ExtractRequest ack;
  {
    absl::MutexLock lock(&mu_);
    if (!AckDueLocked()) return true;
    ack_sent_ = ack_wanted_;
    ack.mutable_chunks_received()->set_count(ack_sent_);
  }
  return stream_->Write(ack);
}

absl::Status Sender::FromSource(std::vector<uint8_t>* bytes, const uint8_t** data,
                                size_t* size) {
  // A mapped file offers its slices in place (SliceSource::ViewSlice): sent from there, they
  // are not first copied out of the page cache into `bytes`.
  const uint8_t* view = nullptr;
  TANDEM_RETURN_IF_ERROR(source_.ViewSlice(&view));
  if (view != nullptr) {
    *data = view;
    *size = source_.info().slice_bytes();
    return absl::OkStatus();
  }
  TANDEM_RETURN_IF_ERROR(source_.ReadSlice(bytes));
  *data = bytes->data();
  *size = bytes->size();
  return absl::OkStatus();
}

absl::Status Sender::Run() {
  const VolumeInfo& info = source_.info();
  v1::ExtractRequest request;
  *request.mutable_config() = config_;
  if (!stream_->Write(request)) return absl::OkStatus();
  {
    absl::MutexLock lock(&mu_);
    mu_.Await(absl::Condition(
        +[](Sender* s) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s->mu_) { return s->accepted_ || s->stop_; },
        this));
    if (stop_) return absl::OkStatus();
  }
  std::vector<uint8_t> bytes;
  const absl::Time start = absl::Now();
  int64_t z = first_slice_;
  for (; info.nz == 0 || z < info.nz; ++z) {
    const uint8_t* data = nullptr;
    size_t size = 0;
    if (z < source_.next_slice()) {
      return absl::InternalError(absl::StrCat("slice ", z, " was already read from the volume"));
    }
    absl::Status st;
    do {  // a resumed stream skips what the session already has
      st = FromSource(&bytes, &data, &size);
    } while (st.ok() && source_.next_slice() <= z);
    if (absl::IsOutOfRange(st)) break;
    if (!st.ok()) return st;
    if (options_.rate > 0) {
      // Pace like a scanner: slice z leaves at start + (z - first) / rate. Acknowledgements
      // go out meanwhile.
      const absl::Time due =
          start + absl::Seconds(static_cast<double>(z - first_slice_) / options_.rate);
      auto stop_or_ack = [this]()
                             ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return stop_ || AckDueLocked(); };
      while (true) {
        {
          absl::MutexLock lock(&mu_);
          mu_.AwaitWithDeadline(absl::Condition(&stop_or_ack), due);
          if (stop_) return absl::OkStatus();
        }
        if (!SendAcknowledgement()) return absl::OkStatus();
        if (absl::Now() >= due) break;
      }
    }
    {
      absl::MutexLock lock(&mu_);
      if (stop_) return absl::OkStatus();
    }
    if (!SendAcknowledgement()) return absl::OkStatus();
    for (size_t offset = 0; offset < size; offset += options_.chunk_bytes) {
      request.Clear();
      v1::SliceChunk* chunk = request.mutable_chunk();
      chunk->set_slice(z);
      chunk->set_offset(offset);
      chunk->set_data(data + offset, std::min(options_.chunk_bytes, size - offset));
      if (offset == 0) {
        chunk->set_slice_size(size);
        chunk->set_dtype(common::DTypeToProto(info.dtype));
      }
      if (!stream_->Write(request)) return absl::OkStatus();
    }
    absl::MutexLock lock(&mu_);
    slices_sent_ = z + 1;
  }
  if (!SendAcknowledgement()) return absl::OkStatus();
  request.Clear();
  request.mutable_end()->set_slices(z);
  if (stream_->Write(request)) stream_->WritesDone();
  return absl::OkStatus();
}

// A local failure (not the server's): `what` says which part of the client failed.
absl::Status Local(absl::Status status, const char* what) {
  status.SetPayload(kLocalPayload, absl::Cord(what));
  return status;
}

// What StreamVolume carries from one attempt to the next.
struct Resumption {
  std::string id, token;  // of the session, once its first Progress came
  int64_t consumed = 0;   // slices the server said it consumed
};

// How an attempt ended, besides its status.
struct Attempt {
  bool answered = false;       // the server took the stream (its first message came)
  bool refused = false;        // refused at the door: the same attempt may be sent again
  int64_t expected_slice = -1;  // a resume's FAILED_PRECONDITION: the slice it needs
};


// One attempt: the config (with Resume once the session has an id), then slices from
// `first_slice`. Messages go to `collector`; `resumption` learns the id and the slices
// consumed.
absl::Status StreamOnce(SliceSource& source, const StreamOptions& opts, int64_t first_slice,
                        Collector& collector, StreamResult& result,
                        Resumption& resumption, v1::Tandem::Stub& stub,
                        const std::chrono::system_clock::time_point* deadline, Attempt* attempt) {
  grpc::ClientContext context;
  AddToken(opts.connection, &context);
  if (deadline != nullptr) context.set_deadline(*deadline);
  std::unique_ptr<Stream> stream = stub.Extract(&context);

  v1::SessionConfig config = opts.config;
  if (!resumption.id.empty()) {
    v1::Resume* r = config.mutable_resume();
    r->set_session_id(resumption.id);
    r->set_token(resumption.token);
    r->set_next_slice(first_slice);
    r->set_chunks_received(result.chunks_received);
  }
  Sender sender(source, opts, config, first_slice, stream.get());
  absl::Status send_status;
  std::thread send_thread([&] {
    send_status = sender.Run();
    if (!send_status.ok()) context.TryCancel();  // the server's stream is of no use now
  });

  v1::ExtractResponse response;
  bool acks = false;  // the server takes ChunksReceived on this stream
  absl::Status save_status;
  while (stream->Read(&response)) {
    if (!attempt->answered) {
      attempt->answered = true;
      sender.Accept();
    }
    if (response.has_progress()) {
      const v1::Progress& p = response.progress();
      if (!p.session_id().empty()) {
        resumption.id = result.session_id = p.session_id();
        if (!p.resume_token().empty()) resumption.token = p.resume_token();
        acks = p.chunk_acks();
      }
      resumption.consumed = std::max(resumption.consumed, p.slices_consumed());
    }
    if (response.has_sealed_chunk() && opts.chunk_store != nullptr) {
      // Kept before the callbacks see it, and acknowledged once kept.
      save_status = opts.chunk_store->Save(resumption.id, response.sealed_chunk());
      if (!save_status.ok()) {
        context.TryCancel();
        break;
      }
      if (acks) sender.Acknowledge(opts.chunk_store->saved());
    }
    collector.Handle(response, sender.slices_sent());
  }
  sender.Stop();
  send_thread.join();
  const grpc::Status status = stream->Finish();
  result.slices_sent = std::max(result.slices_sent, sender.slices_sent());
  if (!send_status.ok()) return Local(send_status, "reading the volume");
  if (!save_status.ok()) return Local(save_status, "saving the sealed chunks");
  if (!status.ok()) {
    // Retryable: nothing came back, and the server did not mark the refusal as final
    // (it does, with grpc-retry-pushback-ms: -1, for its limits: the same scan would fail
    // again).
    const auto& trailers = context.GetServerTrailingMetadata();
    const auto pushback = trailers.find("grpc-retry-pushback-ms");
    attempt->refused = !attempt->answered &&
                       (status.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED ||
                        status.error_code() == grpc::StatusCode::UNAVAILABLE) &&
                       (pushback == trailers.end() || pushback->second != "-1");
    const auto expected = trailers.find("tandem-expected-slice");
    int64_t slice = -1;
    if (status.error_code() == grpc::StatusCode::FAILED_PRECONDITION &&
        expected != trailers.end() &&
        absl::SimpleAtoi(absl::string_view(expected->second.data(), expected->second.size()),
                         &slice)) {
      attempt->expected_slice = slice;
    }
    return common::FromGrpcStatus(status);
  }
  return absl::OkStatus();
}

// The error of a stream that broke (`broke`, OK if it did not) and ended with `last`.
absl::Status Unresumed(const absl::Status& broke, const absl::Status& last) {
  if (broke.ok() || broke == last) return last;
  return absl::Status(last.code(), absl::StrCat("the stream broke (", broke.ToString(),
                                                ") and could not be resumed: ", last.message()));
}

}  // namespace

bool IsLocalError(const absl::Status& status) {
  return status.GetPayload(kLocalPayload).has_value();
}

absl::StatusOr<StreamResult> StreamVolume(SliceSource& source, const StreamOptions& options,
                                          const StreamCallbacks& callbacks) {
  if (options.chunk_bytes == 0) return absl::InvalidArgumentError("chunk size must be > 0");
  StreamOptions opts = options;
  const VolumeInfo& info = source.info();
  v1::SessionConfig& c = opts.config;
  c.set_nx(info.nx);
  c.set_ny(info.ny);
  c.set_nz(info.nz);
  c.set_dtype(common::DTypeToProto(info.dtype));
  c.clear_spacing();
  c.clear_origin();
  for (int a = 0; a < 3; ++a) {
    c.add_spacing(info.spacing[a]);
    c.add_origin(info.origin[a]);
  }
  c.clear_directions();
  if (!info.axis_aligned()) {
    for (const auto& d : info.directions) {
      for (double v : d) c.add_directions(v);
    }
  }

  if (opts.chunk_store != nullptr && c.sealed_chunks()) c.set_chunk_acks(true);
  if (opts.connection.max_receive_bytes == 0) {
    opts.connection.max_receive_bytes = common::kClientMaxReceiveBytes;
  }
  TANDEM_ASSIGN_OR_RETURN(std::shared_ptr<grpc::Channel> channel, MakeChannel(opts.connection));
  std::unique_ptr<v1::Tandem::Stub> stub = v1::Tandem::NewStub(channel);
  const absl::Time start = absl::Now();
  const auto deadline = std::chrono::system_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(opts.timeout_s * 1000));
  StreamResult result;
  Collector collector(callbacks, &result, opts.config.sealed_chunks(),
                      1 + static_cast<size_t>(opts.config.extra_isos_size()),
                      opts.config.labels().enabled());
  Resumption resumption{opts.resume_session_id, opts.resume_token, 0};
  if (opts.chunk_store != nullptr && !resumption.id.empty()) {
    // A restarted client holds the chunks it kept: the server sends the others.
    absl::StatusOr<std::vector<v1::SealedChunk>> kept = opts.chunk_store->Load(resumption.id);
    if (!kept.ok()) return Local(kept.status(), "reading the sealed chunks kept");
    if (callbacks.on_chunks_kept) callbacks.on_chunks_kept(static_cast<int64_t>(kept->size()));
    v1::ExtractResponse r;
    for (v1::SealedChunk& chunk : *kept) {
      *r.mutable_sealed_chunk() = std::move(chunk);
      collector.Handle(r, 0);
    }
  }
  absl::Status broke;  // the drop being resumed, if any
  int64_t first_slice = 0;
  absl::BitGen jitter;
  for (int attempt = 0;;) {
    Attempt a;
    absl::Status st;
    if (first_slice < source.next_slice()) {
      // Slices sent before the connection broke, not consumed: read the volume again.
      absl::Status again = opts.rewind ? opts.rewind()
                                       : absl::FailedPreconditionError("the volume cannot be read again");
      if (!again.ok()) {
        return Unresumed(broke, absl::Status(again.code(), absl::StrCat("resuming at slice ",
                                                                        first_slice, ": ",
                                                                        again.message())));
      }
    }
    st = StreamOnce(source, opts, first_slice, collector, result, resumption, *stub,
                    opts.timeout_s > 0 ? &deadline : nullptr, &a);
    result.seconds = absl::ToDoubleSeconds(absl::Now() - start);
    if (st.ok()) {
      const std::string malformed = collector.Check();
      if (!malformed.empty()) {
        return absl::DataLossError(
            absl::StrCat("malformed reply from ", opts.connection.server, ": ", malformed));
      }
      return result;
    }
    if (a.answered) attempt = 0;  // it got through: the budget is for this drop
    const bool resuming = !resumption.token.empty();
    if (!broke.ok() && !resuming) return st;
    const bool round_robin = opts.connection.lb_policy == "round_robin";
    if (resuming && !a.answered && absl::IsNotFound(st) &&
        (!round_robin || attempt >= opts.connection.retries)) {
      // Sessions live in the server's memory: no replica has this one (any more).
      return absl::NotFoundError(absl::StrCat(
          broke.ok() ? "" : absl::StrCat("the stream broke (", broke.ToString(), ") and "),
          "the server no longer has session ", resumption.id,
          " (it restarted or the session expired); send the scan again",
          opts.resume_session_id.empty() ? "" : " without --resume"));
    }
    // What to do next, and after how long.
    double backoff = std::min(5.0, 0.5 * std::pow(2.0, attempt)) * absl::Uniform(jitter, 0.8, 1.2);
    if (resuming && a.expected_slice >= 0 && a.expected_slice != first_slice) {
      first_slice = a.expected_slice;  // the server consumed more (or less) than it said
      backoff = 0;
      attempt = 0;  // the replica holding the session answered: the budget starts again
    } else if (resuming && a.answered && absl::IsUnavailable(st)) {
      broke = st;  // the connection broke mid-stream: resume where the server is
      first_slice = resumption.consumed;
    } else if (resuming && !a.answered && absl::IsNotFound(st) && round_robin) {
      // Another replica took the resume: the next stream goes to the next one. A short pause,
      // so that a replica still connecting is among those the balancer picks from.
      backoff = 0.1;
    } else if (!a.refused) {
      return Unresumed(broke, st);
    }
    if (attempt >= opts.connection.retries) return Unresumed(broke, st);
    ++attempt;
    if (resuming) {
      ++result.resumes;
      if (callbacks.on_resume) callbacks.on_resume(broke.ok() ? st : broke, first_slice, attempt, backoff);
    } else if (callbacks.on_retry) {
      // Refused at the door (all session slots taken, or the server going away), before a
      // single slice was read: send it again after a backoff, 0.5 s doubling to 5 s, +-20 %.
      callbacks.on_retry(st, attempt, backoff);
    }
    absl::SleepFor(absl::Seconds(backoff));
  }
}

absl::StatusOr<StreamResult> WatchSession(const ConnectionOptions& connection,
                                          const std::string& session_id,
                                          const std::string& watch_key, double timeout_s,
                                          const StreamCallbacks& callbacks) {
  ConnectionOptions options = connection;
  if (options.max_receive_bytes == 0) options.max_receive_bytes = common::kClientMaxReceiveBytes;
  TANDEM_ASSIGN_OR_RETURN(std::shared_ptr<grpc::Channel> channel, MakeChannel(options));
  std::unique_ptr<v1::Tandem::Stub> stub = v1::Tandem::NewStub(channel);
  grpc::ClientContext context;
  AddToken(options, &context);
  if (timeout_s > 0) {
    context.set_deadline(std::chrono::system_clock::now() +
                         std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000)));
  }
  const absl::Time start = absl::Now();
  v1::WatchRequest request;
  request.set_session_id(session_id);
  request.set_watch_key(watch_key);
  std::unique_ptr<grpc::ClientReader<v1::ExtractResponse>> reader = stub->Watch(&context, request);
  StreamResult result;
  Collector collector(callbacks, &result, /*sealed=*/true, /*surfaces=*/0);
  v1::ExtractResponse response;
  while (reader->Read(&response)) collector.Handle(response, 0);
  const grpc::Status status = reader->Finish();
  result.seconds = absl::ToDoubleSeconds(absl::Now() - start);
  if (!status.ok()) return common::FromGrpcStatus(status);
  const std::string malformed = collector.Check();
  if (!malformed.empty()) {
    return absl::DataLossError(
        absl::StrCat("malformed reply from ", options.server, ": ", malformed));
  }
  result.slices_sent = (result.labels ? result.session_metrics : result.metrics).slices();
  return result;
}

}  // namespace tandem::client
