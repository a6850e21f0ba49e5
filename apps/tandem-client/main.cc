// tandem-client: command-line client of tandem-server.
//   tandem-client stream --server HOST:PORT --input VOLUME --iso C0 --error E0 --out MESH ...
//   tandem-client info   --server HOST:PORT
//   tandem-client health --server HOST:PORT
// Exit status (apps/common/cli_util.h): 0 success, 1 a failure while running (the message on
// stderr names the problem and, for a server error, its gRPC code), 2 a mistake in the
// command line, 3 stream --strict: the iso-value lies outside the data sent (a warning
// otherwise).
#include <unistd.h>
#if defined(__GLIBC__)
#include <malloc.h>  // mallopt
#endif

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <fstream>
#include <limits>
#include <memory>
#include <optional>
#include <string>

#include <grpcpp/grpcpp.h>

#include "absl/status/status.h"
#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "apps/common/cli_util.h"
#include "apps/common/extract_flags.h"
#include "apps/common/version.h"
#include "client/connection.h"
#include "apps/tandem-client/live_view.h"
#include "client/stream_client.h"
#include "codec/draco_codec.h"
#include "apps/common/flags.h"
#include "common/wire.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "tandem/follow.h"
#include "tandem/mesh_io.h"
#include "tandem/report.h"
#include "tandem/tandem.h"
#include "tandem/v1/tandem.grpc.pb.h"
#include "tandem/volume.h"

namespace {

using tandem::cli::FlagSet;

constexpr char kMainUsage[] =
    "usage: tandem-client <command> [flags]   (tandem-client <command> --help for its flags)\n"
    "commands:\n"
    "  stream   stream a volume to tandem-server and save the simplified iso-surface\n"
    "  watch    follow another stream's sealed-chunk session by its id and save its mesh\n"
    "  view     show a sealed-chunk session live in a browser (watch --view)\n"
    "  info     print the server's version, security, limits, live counters and sessions\n"
    "  health   query the standard gRPC health service (exit 0 when SERVING)\n"
    "  --version  print the version and git revision\n"
    "environment: TANDEM_SERVER, TANDEM_TLS_CA, TANDEM_TLS_SERVER_NAME, TANDEM_TOKEN_FILE (as\n"
    "the flags), TANDEM_TOKEN (the bearer token itself; --token-file wins; never a flag,\n"
    "since command lines are visible to every user of the machine); likewise the viewer's\n"
    "token TANDEM_VIEW_TOKEN (or --view-token-file) and stream's TANDEM_RESUME (or\n"
    "--resume-file), which as flags work but draw a warning";

// A failure here, with no server involved (a file that cannot be read or written): its
// message, without a gRPC code.
int Fail(const absl::Status& st) {
  absl::FPrintF(stderr, "tandem-client: error: %s\n", std::string(st.message()));
  return tandem::cli::kExitFailure;
}

// A call's failure: the server's (or the transport's) status code, its message, and a hint.
int RpcFail(const absl::Status& st, const std::string& hint = "") {
  if (tandem::client::IsLocalError(st)) return Fail(st);  // reading the volume mid-stream
  absl::FPrintF(stderr, "tandem-client: error: %s: %s%s\n", absl::StatusCodeToString(st.code()),
                std::string(st.message()), hint.empty() ? "" : absl::StrCat(" (", hint, ")"));
  return tandem::cli::kExitFailure;
}

// A mistake in the flags, found before anything was sent: exit status 2, no gRPC code.
int UsageError(const absl::Status& st) {
  absl::FPrintF(stderr, "tandem-client: %s\n", st.message());
  return tandem::cli::kExitUsage;
}

// --server and the TLS / token flags every command has (health: no token).
struct ConnectionFlags {
  tandem::client::ConnectionOptions options;
  std::string token_file;
  bool with_token = true;
  int64_t retries_flag = 4;

  ConnectionFlags() { options.server = tandem::wire::kDefaultServerAddress; }
  void Add(FlagSet& flags, bool token) {
    with_token = token;
    flags.AddString("server", &options.server, "HOST:PORT", "tandem-server address");
    flags.AddString("tls-ca", &options.tls_ca_file, "FILE",
                    "connect with TLS and verify the server against these PEM roots");
    flags.AddBool("tls", &options.tls, "connect with TLS, verified against the system's roots");
    flags.AddString("tls-server-name", &options.tls_server_name, "NAME",
                    "name the server's certificate must carry, when not the host of --server");
    flags.AddString("lb", &options.lb_policy, "pick_first|round_robin",
                    "how calls spread over the addresses --server resolves to (round_robin "
                    "with a DNS name of several replicas, or ipv4:HOST:PORT,HOST:PORT)");
    int64_t* retries = &retries_flag;
    flags.AddInt("retries", retries,
                 "send a stream again when the server refuses it at the door (RESOURCE_EXHAUSTED: "
                 "all session slots taken; UNAVAILABLE: going away or not there), up to N times "
                 "(0..4), backoff 0.5 s doubling to 5 s; no slice is read before the server "
                 "takes the stream, and limits it marks final are not retried");
    if (token) {
      flags.AddString("token-file", &token_file, "FILE",
                      "send the first token of FILE as `authorization: Bearer`; without it, "
                      "the token in $TANDEM_TOKEN (if set) is sent");
    }
  }
  // After parsing: loads the token. -1 to go on, else the exit status.
  int Finish() {
    options.retries = static_cast<int>(std::clamp<int64_t>(retries_flag, -1, 5));
    if (absl::StatusOr<std::string> config = tandem::client::ServiceConfigJson(options);
        !config.ok()) {
      absl::FPrintF(stderr, "tandem-client: %s\n", std::string(config.status().message()));
      return 2;
    }
    if (!with_token) return -1;
    absl::StatusOr<std::string> token = tandem::client::LoadToken(token_file);
    if (!token.ok()) return ::Fail(token.status());  // a file or the environment, read
    options.token = *std::move(token);
    return -1;
  }
  int Fail(const absl::Status& st) const {
    return RpcFail(st, tandem::client::ConnectionHint(options, st));
  }
};

// Parses flags; returns -1 to go on, else the exit status (help printed or usage error).
int ParseOrExit(FlagSet& flags, int argc, char** argv, ConnectionFlags* connection) {
  // TANDEM_SERVER etc., as in deploy/README.md (the token itself: TANDEM_TOKEN, no flag).
  flags.UseEnvironment("TANDEM_",
                       {"server", "tls-ca", "tls-server-name", "token-file", "lb", "retries"});
  if (absl::Status st = flags.Parse(argc, argv, 2); !st.ok()) {
    absl::FPrintF(stderr, "tandem-client: %s\n", std::string(st.message()));
    return 2;
  }
  if (flags.help_requested()) {
    absl::PrintF("%s", flags.Help());
    return 0;
  }
  if (!flags.positional().empty()) {
    absl::FPrintF(stderr, "tandem-client: unexpected argument '%s' (see --help)\n",
                  flags.positional().front());
    return 2;
  }
  return connection->Finish();
}

std::string Lower(std::string s) { return absl::AsciiStrToLower(s); }

absl::Status WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) return absl::UnavailableError(absl::StrCat(path, ": cannot write"));
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------
// Creates an output directory a flag names (--chunks, --partials).
absl::Status MakeOutputDir(const char* flag, const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return absl::UnavailableError(absl::StrCat(flag, " ", dir, ": ", ec.message()));
  return absl::OkStatus();
}

// The chunk callback of stream and watch: a line with --verbose; with `store` (watch
// --chunks; stream's are saved by StreamVolume) DIR/chunk_<index>.drc of session `session`,
// the first write error kept in *error.
std::function<void(const tandem::v1::SealedChunk&)> ChunkSaver(tandem::client::ChunkStore* store,
                                                               const std::string& session,
                                                               const bool& verbose,
                                                               absl::Status* error) {
  return [store, session, &verbose, error](const tandem::v1::SealedChunk& c) {
    if (verbose) {
      absl::FPrintF(stderr, "chunk index=%d slices=%d..%d triangles=%d vertices=%d bytes=%d\n",
                    c.index(), c.first_slice(), c.last_slice(), c.triangles(), c.vertices(),
                    c.draco().size());
    }
    if (store != nullptr && error->ok()) *error = store->Save(session, c);
  };
}

// Draco flags of stream and watch: false (after a message) when out of range.
bool DracoFlagsOk(int64_t bits, int64_t level) {
  if (bits >= 1 && bits <= 30 && level >= 0 && level <= 10) return true;
  absl::FPrintF(stderr, "tandem-client: need 1 <= --quantization-bits <= 30 and "
                        "0 <= --compression-level <= 10\n");
  return false;
}

// How stream and watch save what they received.
struct SaveOptions {
  bool seal = false;  // the mesh came as sealed chunks
  std::string out_pattern, metrics_path;
  tandem::codec::DracoOptions draco;  // .drc re-encoding of sealed chunks; --glb-draco
  bool glb_draco = false;
  std::string input, frame_text;  // for the report (the frame itself comes with the metrics)
  std::vector<tandem::cli::IsoValue> isos;  // as the user wrote them ({iso} names), or none
  const char* wall_label = "stream wall time";
  bool quiet = false;
};

// Saves one surface's final mesh of a stream or a watch to `out` (.drc: Draco bytes; sealed:
// the chunks welded), prints its summary on stdout and appends its metrics JSON to *json.
// 0 or the exit status of the failure.
int SaveSurface(const tandem::client::StreamResult& result, tandem::client::SurfaceResult& s,
                const SaveOptions& o, const std::string& out, std::vector<std::string>* json) {
  const bool seal = o.seal;
  const std::string ext = Lower(std::filesystem::path(out).extension().string());
  // Decode even for .drc: it checks the bytes and the counts the server announced. Sealed:
  // the chunks, welded (their counts were checked against the metrics), encoded for .drc.
  absl::StatusOr<tandem::IndexedMesh> mesh =
      seal ? tandem::WeldChunks(s.sealed) : tandem::codec::DecodeDraco(s.draco);
  if (!mesh.ok()) return Fail(mesh.status());
  if (seal && ext == ".drc") {
    absl::StatusOr<std::string> bytes = tandem::codec::EncodeDraco(*mesh, o.draco);
    if (!bytes.ok()) return Fail(bytes.status());
    s.draco = *std::move(bytes);
  }
  if (static_cast<int64_t>(mesh->num_triangles()) != s.triangles ||
      static_cast<int64_t>(mesh->num_vertices()) != s.vertices) {
    return Fail(absl::DataLossError(absl::StrCat(
        "the final mesh decodes to ", mesh->num_triangles(), " triangles and ",
        mesh->num_vertices(), " vertices; the server announced ", s.triangles, " and ",
        s.vertices)));
  }
  tandem::MeshWriteOptions write;
  if (o.glb_draco) write.glb_draco = tandem::codec::GlbCompressor(o.draco);
  // The frame the session ran in, as the server echoes it: the watcher of a session learns
  // it there too. An older server sends none: the grid's own frame.
  write.space = tandem::ParseSpace(s.metrics.frame()).value_or(tandem::Space::kGrid);
  absl::Status saved =
      ext == ".drc" ? WriteFile(out, s.draco) : tandem::WriteMesh(out, *mesh, write);
  if (!saved.ok()) return Fail(saved);

  tandem::MetricsReport report = tandem::wire::ReportFromProto(s.metrics);
  report.input = o.input;
  report.frame_text = o.frame_text;
  json->push_back(tandem::ReportToJson(report));
  if (o.quiet) return 0;
  if (result.num_surfaces() > 1) absl::PrintF("%s (iso %g)\n", out, s.metrics.iso());
  absl::PrintF("%s", tandem::ReportSummary(report));
  absl::PrintF("  %-22s %.3f s for %d slices (%.1f slices/s), %d previews\n", o.wall_label,
               result.seconds, result.slices_sent,
               result.seconds > 0 ? result.slices_sent / result.seconds : 0.0,
               s.metrics.previews_sent());
  if (seal) {
    absl::PrintF("  %-22s %d chunks, %d bytes received in all\n", "sealed", s.sealed.size(),
                 s.metrics.bytes_sent());
  }
  return 0;
}

// Every surface of a stream or a watch: to the names `out_pattern` gives (with {iso} when
// there are several), the metrics to `metrics_path` (one file per surface with {iso}, else
// one report, or a JSON array of them in surface order). 0 or the exit status of the failure.
int SaveResult(tandem::client::StreamResult& result, const SaveOptions& o) {
  const size_t n = result.num_surfaces();
  const std::string& metrics_path = o.metrics_path;
  std::vector<std::string> json;
  for (size_t i = 0; i < n; ++i) {
    tandem::client::SurfaceResult& s = result.surface(i);
    const tandem::cli::IsoValue iso = i < o.isos.size()
                                          ? o.isos[i]
                                          : tandem::cli::IsoValue{s.metrics.iso(),
                                                                  absl::StrCat(s.metrics.iso())};
    absl::StatusOr<std::string> out = tandem::cli::NameForIso("out", o.out_pattern, iso, n);
    if (!out.ok()) return Fail(out.status());
    if (int rc = SaveSurface(result, s, o, *out, &json); rc != 0) {
      return rc;
    }
    if (!metrics_path.empty() && metrics_path.find("{iso}") != std::string::npos) {
      absl::StatusOr<std::string> name = tandem::cli::NameForIso("metrics", metrics_path, iso, n);
      if (!name.ok()) return Fail(name.status());
      if (absl::Status st = WriteFile(*name, json.back()); !st.ok()) return Fail(st);
    }
  }
  if (!metrics_path.empty() && metrics_path.find("{iso}") == std::string::npos) {
    const std::string text =
        n == 1 ? json[0] : absl::StrCat("[\n", absl::StrJoin(json, ",\n"), "]\n");
    if (absl::Status st = WriteFile(metrics_path, text); !st.ok()) return Fail(st);
  }
  return 0;
}

int StreamCommand(int argc, char** argv) {
  ConnectionFlags connection;
  tandem::cli::ExtractFlags f;  // the flags `tandem extract` has too
  int64_t keepalive_ms = 30000;
  std::string partials, chunks_dir, resume;
  double rate = 0, timeout_s = 0;
  int64_t chunk_bytes = tandem::wire::kDefaultSliceChunkBytes;
  int64_t preview_every = 0, preview_ms = 0;
  bool verbose = false;
  FlagSet flags(
      "usage: tandem-client stream --input VOLUME --out MESH [flags]\n"
      "Streams VOLUME (.json+.raw, .nrrd/.nhdr, .nii/.nii.gz, .tif/.tiff, .mha/.mhd, a "
      "Zarr/OME-Zarr\n"
      "store X.zarr, X.zarr#LEVEL or X.zarr#ARRAY_PATH, or a folder holding a DICOM series\n"
      "or numbered single-slice TIFFs) slice by slice to\n"
      "tandem-server, prints the final metrics as a table on stdout, and saves the\n"
      "simplified iso-surface: .drc (the server's Draco bytes), or decoded: .ply or .obj (with "
      "vertex normals), .stl, .glb.");
  connection.Add(flags, /*token=*/true);
  f.Add(&flags, "final mesh: .drc (the server's Draco bytes), .ply or .obj (with vertex "
                "normals), .stl or .glb");
  flags.AddInt("keepalive-time-ms", &keepalive_ms,
               "while streaming, ping the server when the connection has been quiet this "
               "long, so that proxies and NATs keep it (0 = never; keep it at or above the "
               "server's minimum ping interval, see `tandem-client info`)");
  flags.AddDouble("rate", &rate, "send at most this many slices per second (0 = no pacing)");
  flags.AddInt("chunk-bytes", &chunk_bytes, "bytes of voxel data per message");
  flags.AddInt("preview-every", &preview_every,
               "ask for a preview mesh every N slices (0 = none; with --partials: about 20 over "
               "the volume; else with --view: every slice, at most one per 500 ms)");
  flags.AddInt("preview-ms", &preview_ms, "and at most one preview per this many milliseconds");
  flags.AddString("partials", &partials, "DIR", "save each preview as DIR/preview_<slice, 6 digits>.drc");
  flags.AddString("chunks", &chunks_dir, "DIR",
                  "--seal (implied): also save every sealed chunk as it arrives, "
                  "DIR/chunk_<index, 6 digits>.drc (Draco, vertex ids as a generic attribute), "
                  "listed in DIR/chunks.tsv; the server keeps each chunk until it is saved, and "
                  "--resume with the same DIR asks only for those not saved");
  flags.AddSecret("resume", &resume, "ID:TOKEN", "TANDEM_RESUME",
                  "continue the session ID, whose client was stopped or lost its connection "
                  "(the server keeps it for --resume-window-seconds): the same VOLUME is read "
                  "from its start and the slices the session has are skipped; ID:TOKEN is what "
                  "the first client printed (a client resumes by itself while it runs); a sealed "
                  "session needs the first run's --chunks DIR, unless it is small (tandem-server "
                  "--watch-retain-mb)");
  tandem::client::LiveView view;
  view.AddFlags(flags);
  flags.AddDouble("timeout", &timeout_s, "give up after this many seconds (0 = never)");
  flags.AddBool("verbose", &verbose,
                "print one line per progress, preview and chunk message on stderr, and one "
                "when the final mesh has arrived (before it is written)");
  if (int rc = ParseOrExit(flags, argc, argv, &connection); rc >= 0) return rc;
  if (absl::Status st = f.Check(flags); !st.ok()) return UsageError(st);
  const std::string input = f.InputPath();
  const std::string& out = f.out;
  const std::string& metrics_path = f.metrics;
  const bool follow = f.follow, strict = f.strict;
  bool& seal = f.seal;  // --chunks implies it, below

  const std::string ext = Lower(std::filesystem::path(out).extension().string());
  if (ext != ".drc" && !tandem::IsMeshOutputPath(out)) {
    absl::FPrintF(stderr, "tandem-client: --out %s: the extension must be .drc, %s\n", out,
                  tandem::kMeshExtensions);
    return 2;
  }
  // Fail before streaming, not after: the output's folder must exist.
  if (const std::filesystem::path parent = std::filesystem::path(out).parent_path();
      !parent.empty() && !std::filesystem::is_directory(parent)) {
    return Fail(absl::NotFoundError(
        absl::StrCat("--out ", out, ": folder ", parent.string(), " does not exist")));
  }
  if (chunk_bytes < 1 || rate < 0 || timeout_s < 0 || preview_every < 0 || preview_ms < 0 ||
      keepalive_ms < 0 || keepalive_ms > std::numeric_limits<int>::max()) {
    absl::FPrintF(stderr,
                  "tandem-client: --chunk-bytes must be >= 1; --rate, --timeout, --preview-every, "
                  "--preview-ms and --keepalive-time-ms must be >= 0\n");
    return 2;
  }
  const int64_t bits = f.quantization_bits, level = f.compression_level;
  if (!chunks_dir.empty()) {
    seal = true;
    if (absl::Status st = MakeOutputDir("--chunks", chunks_dir); !st.ok()) return Fail(st);
  }
  std::string resume_id, resume_token;
  if (!resume.empty()) {
    const size_t colon = resume.find(':');
    resume_id = resume.substr(0, colon);
    if (colon != std::string::npos) resume_token = resume.substr(colon + 1);
    if (resume_id.empty() || resume_token.empty()) {
      absl::FPrintF(stderr, "tandem-client: --resume: expected ID:TOKEN (as the first client "
                            "printed it), got no ':' or an empty side\n");
      return 2;
    }
  }
  if (!partials.empty()) {
    if (!flags.IsSet("preview-every")) preview_every = -1;  // set from the depth below
    if (absl::Status st = MakeOutputDir("--partials", partials); !st.ok()) return Fail(st);
  }
  if (view.on() && partials.empty() && !flags.IsSet("preview-every")) {
    // The page draws the growing mesh from the previews (unsealed: the whole partial mesh;
    // sealed: the band beside the chunks): one at every slice, time-bounded.
    preview_every = 1;
    if (!flags.IsSet("preview-ms")) preview_ms = tandem::client::kViewPreviewMs;
  }

  // One status line while following: slices complete on disk and sent.
  std::atomic<int64_t> on_disk{0};
  // What the readers set aside (a series, a file) or find odd, unless --quiet; a source
  // opened again for a resume has said it already.
  std::atomic<bool> reopened{false};
  std::atomic<bool> status_shown{false};  // a status line without its newline is on stderr
  auto note = [&](const std::string& line) {
    if (reopened || f.quiet) return;
    absl::FPrintF(stderr, "%standem-client: %s\n", status_shown.exchange(false) ? "\n" : "", line);
  };
  std::string spacing_warning;  // --spacing replacing the file's own
  bool geometry_refused = false;  // --spacing or --frame does not fit the volume: usage
  auto open = [&]() -> absl::StatusOr<std::unique_ptr<tandem::SliceSource>> {
    absl::StatusOr<std::unique_ptr<tandem::SliceSource>> src;
    if (!follow) {
      src = tandem::OpenVolume(input, f.Open(note));
    } else {
      tandem::FollowOptions fo = f.Follow(note);
      fo.progress = [&](int64_t seen, int64_t) { on_disk = seen; };
      src = tandem::FollowVolume(input, fo);
    }
    if (!src.ok()) return src;
    absl::StatusOr<std::string> warn = f.ApplyGeometry(&*src);
    geometry_refused = !warn.ok();
    if (!warn.ok()) return warn.status();
    spacing_warning = *warn;
    return src;
  };
  absl::StatusOr<std::unique_ptr<tandem::SliceSource>> source = open();
  if (!source.ok()) return geometry_refused ? UsageError(source.status()) : Fail(source.status());
  if (!spacing_warning.empty()) {
    std::fprintf(stderr, "tandem-client: warning: %s\n", spacing_warning.c_str());
  }
  // --iso and --error default as in `tandem extract`: the file's first suggested iso-value,
  // 0.2 x the smallest spacing.
  const tandem::VolumeInfo& info = (*source)->info();
  absl::StatusOr<std::vector<tandem::cli::IsoValue>> isos = f.Isos(flags, info);
  if (!isos.ok()) return UsageError(isos.status());
  // The session's options are checked by core's rules (--target-triangles with --seal or
  // --chunks too), as `tandem extract` checks them, before anything is sent.
  absl::StatusOr<tandem::SessionOptions> session = f.Options(flags, info);
  if (!session.ok()) return UsageError(session.status());
  if (preview_every < 0) {
    // --partials alone: about 20 previews over a known depth (each is the whole partial
    // mesh, encoded again), one every 16 slices when the depth is unknown.
    const int64_t depth = (*source)->info().nz;
    preview_every = depth > 0 ? std::max<int64_t>(1, depth / 20) : 16;
  }

  tandem::ValueRangeSource range(source->get());  // for the iso-outside-the-data warning
  std::optional<tandem::client::ChunkStore> chunk_store;
  if (!chunks_dir.empty()) chunk_store.emplace(chunks_dir);
  tandem::client::StreamOptions options;
  options.chunk_store = chunk_store ? &*chunk_store : nullptr;
  options.connection = connection.options;
  options.connection.keepalive_time_ms = keepalive_ms;
  options.rate = rate;
  options.chunk_bytes = static_cast<size_t>(chunk_bytes);
  options.timeout_s = timeout_s;
  options.rewind = [&]() -> absl::Status {  // a resume needs slices sent before a drop
    reopened = true;
    absl::StatusOr<std::unique_ptr<tandem::SliceSource>> again = open();
    if (!again.ok()) return again.status();
    range.Replace(*std::move(again));
    return absl::OkStatus();
  };
  options.resume_session_id = resume_id;
  options.resume_token = resume_token;
  tandem::v1::SessionConfig& c = options.config;
  c.set_iso(isos->front().value);
  for (size_t i = 1; i < isos->size(); ++i) c.add_extra_isos((*isos)[i].value);
  c.set_error(session->error);
  c.set_alpha(session->alpha);
  c.set_distance_guard(session->distance_guard);
  c.set_sag_correction(session->sag_correction);
  c.set_lockstep_error(session->lockstep_error);
  c.set_parts(session->parts);
  c.set_schedule(tandem::wire::ScheduleToProto(session->schedule));
  c.set_target_triangles(session->target_triangles);
  c.mutable_preview()->set_every_slices(static_cast<uint32_t>(preview_every));
  c.mutable_preview()->set_min_interval_ms(static_cast<uint32_t>(preview_ms));
  c.mutable_draco()->set_quantization_bits(static_cast<uint32_t>(bits));
  c.mutable_draco()->set_compression_level(static_cast<int32_t>(level));
  c.set_compute_distances(f.reference);
  c.set_sealed_chunks(seal);
  if (seal) c.set_seal_margin(session->seal_margin);
  c.set_description(std::filesystem::path(input).filename().string());
  c.set_frame(std::string(tandem::SpaceName(info.space)));

  const int64_t nz = (*source)->info().nz;
  const bool bar = isatty(STDERR_FILENO) != 0 && !verbose && !f.quiet;
  absl::Status partial_error;
  tandem::client::StreamCallbacks callbacks;
  // After the last slice, the server says what its finish is doing: one status line.
  tandem::cli::FinishingStatus finishing("tandem-client: ", f.quiet);
  callbacks.on_progress = [&](const tandem::v1::Progress& p, int64_t sent) {
    if (!p.finishing().empty()) {
      if (verbose) {
        absl::FPrintF(stderr, "progress finishing=\"%s\" share=%.3f seconds=%.1f\n",
                      p.finishing(), p.finishing_share(), p.finishing_seconds());
      } else {
        if (status_shown.exchange(false)) absl::FPrintF(stderr, "\n");
        finishing.Show({tandem::wire::FinishingFromProto(p)});
      }
      return;
    }
    if (f.quiet) {
      // no notes
    } else if (!p.session_id().empty()) {  // a stream's first
      // The variables, not --resume or --watch-key: a command line is readable by every user.
      if (!p.resume_token().empty()) {  // the session's first
        absl::FPrintF(stderr,
                      "tandem-client: session %s; to resume it after a crash, run the same "
                      "command with TANDEM_RESUME=%s:%s in its environment\n",
                      p.session_id(), p.session_id(), p.resume_token());
      } else {
        absl::FPrintF(stderr, "tandem-client: session %s resumed at slice %d\n", p.session_id(),
                      p.slices_consumed());
      }
      if (!p.watch_key().empty()) {  // the session is private to it (and to the token)
        absl::FPrintF(stderr, "tandem-client: %s: TANDEM_WATCH_KEY=%s tandem-client %s\n",
                      seal ? "to let others watch it, give them its watch key"
                           : "its watch key shows it in info",
                      p.watch_key(),
                      seal ? absl::StrCat("watch --session ", p.session_id()) : "info");
      }
    }
    if (verbose) {
      absl::FPrintF(stderr, "progress slices=%d triangles=%d peak=%d sent=%d\n",
                    p.slices_consumed(), p.triangles(), p.peak_triangles(), sent);
    } else if (bar && nz == 0) {
      absl::FPrintF(stderr, "\rfollowing: %d slices on disk, %d sent, %d meshed, %d triangles   ",
                    on_disk.load(), sent, p.slices_consumed(), p.triangles());
      status_shown = true;
    } else if (bar && nz > 0) {
      const int width = 30;
      const int filled = static_cast<int>(width * p.slices_consumed() / nz);
      absl::FPrintF(stderr, "\r[%s%s] %d/%d slices, %d triangles", std::string(filled, '#'),
                    std::string(width - filled, ' '), p.slices_consumed(), nz, p.triangles());
      status_shown = true;
    }
  };
  callbacks.on_retry = [&](const absl::Status& refusal, int retry, double seconds) {
    absl::FPrintF(stderr, "tandem-client: refused (%s: %s); retry %d of %d in %.1f s\n",
                  absl::StatusCodeToString(refusal.code()), std::string(refusal.message()),
                  retry, connection.options.retries, seconds);
  };
  callbacks.on_resume = [&](const absl::Status& cause, int64_t slice, int attempt,
                            double seconds) {
    absl::FPrintF(stderr, "%standem-client: the stream broke (%s: %s); resuming at slice %d, "
                  "attempt %d of %d in %.1f s\n",
                  bar ? "\n" : "", absl::StatusCodeToString(cause.code()),
                  std::string(cause.message()), slice, attempt, connection.options.retries,
                  seconds);
  };
  callbacks.on_preview = [&](const tandem::v1::Preview& p, int64_t sent) {
    if (verbose) {
      absl::FPrintF(stderr, "preview slice=%d triangles=%d vertices=%d bytes=%d sent=%d\n",
                    p.slice(), p.triangles(), p.vertices(), p.draco().size(), sent);
    }
    if (!partials.empty() && partial_error.ok()) {
      // Several surfaces: preview_<slice>_iso<C>.drc.
      const std::string iso_tag =
          isos->size() > 1 && p.surface() >= 0 && static_cast<size_t>(p.surface()) < isos->size()
              ? absl::StrCat("_iso", (*isos)[p.surface()].text)
              : "";
      partial_error = WriteFile((std::filesystem::path(partials) /
                                 absl::StrFormat("preview_%06d%s.drc", p.slice(), iso_tag))
                                    .string(),
                                p.draco());
    }
  };
  callbacks.on_chunk = ChunkSaver(nullptr, "", verbose, &partial_error);
  callbacks.on_chunks_kept = [&](int64_t kept) {
    if (!f.quiet) {
      absl::FPrintF(stderr,
                    "tandem-client: %d sealed chunks kept in %s; the server sends the rest\n",
                    kept, chunks_dir);
    }
  };
  if (absl::Status st = view.Start(c.description(), nz); !st.ok()) {
    return absl::IsInvalidArgument(st) ? UsageError(st) : Fail(st);  // --view's address
  }
  std::vector<std::string> iso_texts;
  for (const tandem::cli::IsoValue& v : *isos) iso_texts.push_back(v.text);
  view.SetIsos(iso_texts);
  if (follow) view.SetOnDisk(&on_disk);
  view.Wire(&callbacks);
  absl::StatusOr<tandem::client::StreamResult> result =
      tandem::client::StreamVolume(*view.Track(&range), options, callbacks);
  if (status_shown.exchange(false)) absl::FPrintF(stderr, "\n");
  finishing.Done();
  if (!result.ok()) {
    const int rc = connection.Fail(result.status());
    view.Finish(result);
    return rc;
  }
  if (!partial_error.ok()) return Fail(partial_error);
  if (verbose) {  // the mesh is here; writing it (a sealed .drc: encoded again) comes next
    absl::FPrintF(stderr, "received surfaces=%d triangles=%d seconds=%.3f\n",
                  result->num_surfaces(), result->triangles, result->seconds);
  }

  SaveOptions save;
  save.seal = result->sealed_session;
  save.out_pattern = out;
  save.metrics_path = metrics_path;
  save.draco.quantization_bits = static_cast<int>(bits);
  save.draco.compression_level = static_cast<int>(level);
  save.glb_draco = f.glb_draco;
  save.input = input;
  save.frame_text = info.frame;
  save.isos = *isos;
  save.quiet = f.quiet;
  if (int rc = SaveResult(*result, save);
      rc != 0) {
    return rc;
  }
  bool outside = false;
  for (const tandem::cli::IsoValue& v : *isos) {
    if (!range.Outside(v.value)) continue;
    outside = true;
    absl::FPrintF(stderr,
                  "tandem-client: warning: iso %g is outside the data's value range [%g, %g]: "
                  "the surface is empty (see tandem info)\n",
                  v.value, range.lo(), range.hi());
  }
  if (outside && strict) {
    view.Finish(result);
    return 3;
  }
  view.Finish(result);
  return 0;
}

// ---------------------------------------------------------------------------------------
void SetDeadline(grpc::ClientContext* context, double seconds) {
  context->set_deadline(std::chrono::system_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(seconds * 1000)));
}

int InfoCommand(int argc, char** argv) {
  ConnectionFlags connection;
  double timeout_s = 10;
  std::string watch_key;
  FlagSet flags(
      "usage: tandem-client info [--server HOST:PORT] [flags]\n"
      "Prints the server's version, security, limits, supported dtypes and live "
      "counters, and the sessions this call may see: those created with its bearer "
      "token, and the one of --watch-key.");
  connection.Add(flags, /*token=*/true);
  flags.AddDouble("timeout", &timeout_s, "seconds to wait for the answer");
  flags.AddSecret("watch-key", &watch_key, "KEY", "TANDEM_WATCH_KEY",
                  "also list the session of this watch key (its streaming client prints it)");
  if (int rc = ParseOrExit(flags, argc, argv, &connection); rc >= 0) return rc;
  absl::StatusOr<std::shared_ptr<grpc::Channel>> channel =
      tandem::client::MakeChannel(connection.options);
  if (!channel.ok()) return Fail(channel.status());
  auto stub = tandem::v1::Tandem::NewStub(*channel);
  grpc::ClientContext context;
  SetDeadline(&context, timeout_s);
  tandem::client::AddToken(connection.options, &context);
  tandem::v1::InfoResponse info;
  tandem::v1::InfoRequest request;
  if (!watch_key.empty()) request.add_watch_keys(watch_key);
  grpc::Status st = stub->GetInfo(&context, request, &info);
  if (!st.ok()) return connection.Fail(tandem::wire::FromGrpcStatus(st));
  std::string dtypes, schedules;
  for (int d : info.dtypes()) {
    absl::StrAppend(&dtypes, dtypes.empty() ? "" : ", ",
                    absl::AsciiStrToLower(tandem::v1::DType_Name(d).substr(6)));
  }
  for (int s : info.schedules()) {
    absl::StatusOr<tandem::Schedule> schedule = tandem::wire::ScheduleFromProto(s);
    if (schedule.ok()) {
      absl::StrAppend(&schedules, schedules.empty() ? "" : ", ",
                      std::string(tandem::ScheduleName(*schedule)));
    }
  }
  const auto& l = info.limits();
  const auto& c = info.counters();
  absl::PrintF("server                 %s (%s)\n", connection.options.server, info.version());
  absl::PrintF("security               %s, %s\n", info.tls() ? "TLS" : "plaintext",
               info.token_required() ? "bearer token required" : "no authentication");
  absl::PrintF("dtypes                 %s\n", dtypes);
  absl::PrintF("schedules              %s\n", schedules);
  absl::PrintF("max voxels per slice   %d\n", l.max_voxels_per_slice());
  absl::PrintF("max slices             %d\n", l.max_slices());
  absl::PrintF("max sessions           %d\n", l.max_sessions());
  absl::PrintF("max message bytes      %d\n", l.max_message_bytes());
  absl::PrintF("idle timeout           %g s\n", l.idle_timeout_seconds());
  absl::PrintF("session memory         %d MiB\n", l.session_memory_bytes() >> 20);
  absl::PrintF("max inflight bytes     %d\n", l.max_inflight_bytes());
  absl::PrintF("keepalive              time %d ms, timeout %d ms, min client ping interval %d ms, "
               "pings without calls %s\n",
               l.keepalive_time_ms(), l.keepalive_timeout_ms(), l.min_ping_interval_ms(),
               l.permit_keepalive_without_calls() ? "allowed" : "refused");
  absl::PrintF("min preview interval   %d ms (and at most %.0f%% of a stream's time)\n",
               l.min_preview_interval_ms(), 100 * l.max_preview_share());
  absl::PrintF("resume window          %g s\n", l.resume_window_seconds());
  absl::PrintF("compute threads        %d (shared by all sessions)\n", l.compute_threads());
  absl::PrintF("watch                  %d MiB kept per session, %g s after it ends\n",
               l.watch_retain_bytes() >> 20, l.watch_linger_seconds());
  absl::PrintF("active sessions        %d\n", c.active_sessions());
  absl::PrintF("sessions started       %d (finished %d, rejected %d)\n", c.sessions_started(),
               c.sessions_finished(), c.sessions_rejected());
  absl::PrintF("worker threads         %d\n", c.worker_threads());
  absl::PrintF("session bytes          %d\n", c.session_bytes());
  absl::PrintF("buffered bytes         %d\n", c.buffered_bytes());
  absl::PrintF("draining sessions      %d\n", c.sessions_draining());
  absl::PrintF("waiting for a resume   %d\n", c.sessions_waiting_for_resume());
  absl::PrintF("unauthenticated calls  %d\n", c.unauthenticated_calls());
  absl::PrintF(
      "sessions listed        %d (others' ids and descriptions are private: the bearer "
      "token that created a session, or its --watch-key, lists it)\n",
      info.sessions_size());
  for (const tandem::v1::SessionSummary& session : info.sessions()) {
    absl::PrintF("session                %s  %s, %d slices, %s%s, %.0f s\n", session.id(),
                 session.finished()             ? "finished"
                 : session.waiting_for_resume() ? "waiting for its client to resume"
                                                : "running",
                 session.slices_consumed(),
                 session.sealed_chunks() ? "sealed chunks (watchable)" : "no sealed chunks",
                 session.description().empty() ? "" : absl::StrCat(", ", session.description()),
                 session.age_seconds());
  }
  return 0;
}

// `watch`, and `view` (the same with the browser viewer on 127.0.0.1:8080 by default and
// --out optional).
int WatchCommand(int argc, char** argv, bool view_command) {
  ConnectionFlags connection;
  std::string session, watch_key, out, metrics_path, chunks_dir;
  double timeout_s = 0;
  int64_t bits = 16, level = 7;
  bool verbose = false, quiet = false, glb_draco = false;
  FlagSet flags(
      view_command
          ? "usage: tandem-client view --session ID [--listen HOST:PORT] [--out MESH] [flags]\n"
            "Shows a session another client is streaming with sealed chunks live in a browser\n"
            "(tandem-client stream --seal prints its id and watch key; give the key with\n"
            "--watch-key-file FILE or $TANDEM_WATCH_KEY): serves\n"
            "the viewer page on --listen (or --view; default 127.0.0.1:8080) and prints its\n"
            "address; the page draws every chunk so far, then the live ones and the band not\n"
            "sealed yet, then the final metrics. The same as tandem-client watch --view."
          : "usage: tandem-client watch --session ID --out MESH [flags]\n"
            "Follows a session another client is streaming with sealed chunks (tandem-client "
            "stream\n"
            "--seal prints its id and watch key; give the key with --watch-key-file FILE or\n"
            "$TANDEM_WATCH_KEY; a session is private to those who have it, and to the bearer\n"
            "token that created it): every chunk so far, then the\n"
            "live ones, then its final metrics. Saves the mesh (the chunks welded: .ply, .obj, "
            ".stl,\n"
            ".glb, or .drc re-encoded) and prints the metrics. A finished session stays watchable\n"
            "for tandem-server --watch-linger-seconds.");
  connection.Add(flags, /*token=*/true);
  flags.AddString("session", &session, "ID", "the session to watch", /*required=*/true);
  flags.AddSecret("watch-key", &watch_key, "KEY", "TANDEM_WATCH_KEY",
                  "the session's watch key, which its streaming client prints (not needed with "
                  "the bearer token that created the session)");
  flags.AddString("out", &out, "MESH",
                  view_command ? "also save the final mesh: .drc, .ply, .obj, .stl or .glb"
                               : "final mesh: .drc, .ply, .obj, .stl or .glb",
                  /*required=*/!view_command);
  flags.AddString("chunks", &chunks_dir, "DIR",
                  "also save every sealed chunk as it arrives, DIR/chunk_<index, 6 digits>.drc");
  flags.AddString("metrics", &metrics_path, "FILE.json", "write the final metrics as JSON");
  flags.AddInt("quantization-bits", &bits, ".drc output: Draco position quantization, 1..30");
  flags.AddInt("compression-level", &level, ".drc output: 0..10");
  flags.AddBool("glb-draco", &glb_draco,
                ".glb output: compress the mesh with Draco (glTF's KHR_draco_mesh_compression)");
  flags.AddDouble("timeout", &timeout_s, "give up after this many seconds (0 = never)");
  flags.AddBool("verbose", &verbose, "print one line per chunk, progress and preview message on stderr");
  flags.AddBool("quiet", &quiet, "no summary on stdout");
  tandem::client::LiveView view;
  view.AddFlags(flags, view_command ? "127.0.0.1:8080" : "");
  if (int rc = ParseOrExit(flags, argc, argv, &connection); rc >= 0) return rc;
  if (!out.empty() && !tandem::IsMeshOutputPath(out) &&
      Lower(std::filesystem::path(out).extension().string()) != ".drc") {
    absl::FPrintF(stderr, "tandem-client: --out %s: the extension must be .drc, %s\n", out,
                  tandem::kMeshExtensions);
    return 2;
  }
  if (!DracoFlagsOk(bits, level)) return 2;
  if (glb_draco && Lower(std::filesystem::path(out).extension().string()) != ".glb") {
    absl::FPrintF(stderr, "tandem-client: --glb-draco compresses a .glb output; --out is %s\n", out);
    return 2;
  }
  if (!chunks_dir.empty()) {
    if (absl::Status st = MakeOutputDir("--chunks", chunks_dir); !st.ok()) return Fail(st);
  }
  absl::Status chunk_error;
  std::optional<tandem::client::ChunkStore> chunk_store;
  if (!chunks_dir.empty()) chunk_store.emplace(chunks_dir);
  tandem::client::StreamCallbacks callbacks;
  callbacks.on_chunk =
      ChunkSaver(chunk_store ? &*chunk_store : nullptr, session, verbose, &chunk_error);
  callbacks.on_progress = [&](const tandem::v1::Progress& p, int64_t) {
    if (verbose) {
      absl::FPrintF(stderr, "progress slices=%d triangles=%d sealed=%d\n", p.slices_consumed(),
                    p.triangles(), p.sealed_triangles());
    }
  };
  callbacks.on_preview = [&](const tandem::v1::Preview& p, int64_t) {
    if (verbose) {
      absl::FPrintF(stderr, "preview slice=%d triangles=%d band_only=%d\n", p.slice(),
                    p.triangles(), p.band_only() ? 1 : 0);
    }
  };
  if (absl::Status st = view.Start(absl::StrCat("session ", session), 0); !st.ok()) {
    return absl::IsInvalidArgument(st) ? UsageError(st) : Fail(st);  // --view's address
  }
  view.Wire(&callbacks);
  absl::StatusOr<tandem::client::StreamResult> result =
      tandem::client::WatchSession(connection.options, session, watch_key, timeout_s, callbacks);
  if (!result.ok()) {
    const int rc = connection.Fail(result.status());
    view.Finish(result);
    return rc;
  }
  if (!chunk_error.ok()) return Fail(chunk_error);
  if (!out.empty()) {
    SaveOptions save;
    save.seal = true;
    save.out_pattern = out;
    save.metrics_path = metrics_path;
    save.draco.quantization_bits = static_cast<int>(bits);
    save.draco.compression_level = static_cast<int>(level);
    save.glb_draco = glb_draco;
    save.input = absl::StrCat("session ", session);
    save.wall_label = "watch wall time";
    save.quiet = quiet;
    if (int rc = SaveResult(*result, save);
        rc != 0) {
      return rc;
    }
  }
  view.Finish(result);
  return 0;
}

int HealthCommand(int argc, char** argv) {
  ConnectionFlags connection;
  std::string service;
  double timeout_s = 5;
  FlagSet flags("usage: tandem-client health [--server HOST:PORT] [flags]\n"
                "Asks grpc.health.v1.Health/Check; prints the status, exits 0 only if SERVING.\n"
                "The health service needs no token, even when the server requires one.");
  connection.Add(flags, /*token=*/false);
  flags.AddString("service", &service, "NAME", "service name to ask about (empty = the server)");
  flags.AddDouble("timeout", &timeout_s, "seconds to wait for the answer");
  if (int rc = ParseOrExit(flags, argc, argv, &connection); rc >= 0) return rc;
  absl::StatusOr<std::shared_ptr<grpc::Channel>> channel =
      tandem::client::MakeChannel(connection.options);
  if (!channel.ok()) return Fail(channel.status());
  auto stub = grpc::health::v1::Health::NewStub(*channel);
  grpc::ClientContext context;
  SetDeadline(&context, timeout_s);
  grpc::health::v1::HealthCheckRequest request;
  request.set_service(service);
  grpc::health::v1::HealthCheckResponse response;
  grpc::Status st = stub->Check(&context, request, &response);
  if (!st.ok()) return connection.Fail(tandem::wire::FromGrpcStatus(st));
  absl::PrintF("%s\n", grpc::health::v1::HealthCheckResponse::ServingStatus_Name(response.status()));
  return response.status() == grpc::health::v1::HealthCheckResponse::SERVING ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
#if defined(__GLIBC__)
  // Every message of a stream is a fresh buffer of about a chunk (1 MiB), serialized and
  // freed by gRPC. glibc hands freed memory at the top of a thread's heap back to the kernel
  // once it exceeds the trim threshold (a few MiB at most), so each buffer was faulted in
  // and zeroed anew: a quarter of a million page faults and two thirds of the client's CPU
  // time per GiB streamed. A short-lived client can keep its few MiB of buffers instead.
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
#endif
  const std::string command = argc > 1 ? argv[1] : "";
  if (command == "stream") return StreamCommand(argc, argv);
  if (command == "info") return InfoCommand(argc, argv);
  if (command == "watch") return WatchCommand(argc, argv, /*view_command=*/false);
  if (command == "view") return WatchCommand(argc, argv, /*view_command=*/true);
  if (command == "health") return HealthCommand(argc, argv);
  if (command == "--help" || command == "-h" || command == "help") {
    absl::PrintF("%s\n", kMainUsage);
    return 0;
  }
  if (command == "--version" || command == "version") {
    absl::PrintF("%s", TANDEM_VERSION_LINE("tandem-client"));
    return 0;
  }
  absl::FPrintF(stderr, "%s\n", kMainUsage);
  return 2;
}
