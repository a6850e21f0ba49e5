// tandem-client watch and view: follow another stream's sealed-chunk session by its id, save
// its mesh (a label session: its labels' files) and metrics, or show it live in the browser
// viewer.
#include <filesystem>
#include <optional>
#include <string>
#include <system_error>

#include "absl/status/status.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "apps/common/extract_flags.h"
#include "command.h"
#include "live_view.h"
#include "save.h"
#include "tandem/client/chunk_store.h"
#include "tandem/client/stream_client.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/io/mesh_io.h"

namespace tandem::client_app {

int WatchCommand(int argc, char** argv, bool view_command) {
  ConnectionFlags connection;
  std::string session, watch_key, out, metrics_path, chunks_dir, label_names_path, format = "ply";
  double timeout_s = 0;
  int64_t bits = codec::kDefaultQuantizationBits, level = codec::kDefaultCompressionLevel;
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
            "for tandem-server --watch-linger-seconds. A label session (stream --labels --seal)\n"
            "writes what its streaming client writes: --out DIR/ (a file per label and\n"
            "labels.glb) or one .glb.");
  connection.Add(flags, /*token=*/true);
  flags.AddString("session", &session, "ID", "the session to watch", /*required=*/true);
  flags.AddSecret("watch-key", &watch_key, "KEY", "TANDEM_WATCH_KEY",
                  "the session's watch key, which its streaming client prints (not needed with "
                  "the bearer token that created the session)");
  flags.AddString("out", &out, "MESH",
                  view_command ? "also save the final mesh: .drc, .ply, .obj, .stl or .glb "
                                 "(a label session: a folder DIR/ or one .glb)"
                               : "final mesh: .drc, .ply, .obj, .stl or .glb (a label session: "
                                 "a folder DIR/, a file per label and labels.glb, or one .glb)",
                  /*required=*/!view_command);
  flags.AddString("chunks", &chunks_dir, "DIR",
                  "also save every sealed chunk as it arrives, DIR/chunk_<index, 6 digits>.drc");
  flags.AddString("metrics", &metrics_path, "FILE.json", "write the final metrics as JSON");
  flags.AddInt("quantization-bits", &bits, ".drc output: Draco position quantization, 1..30");
  flags.AddInt("compression-level", &level, ".drc output: 0..10");
  flags.AddBool("glb-draco", &glb_draco,
                ".glb output: compress the mesh with Draco (glTF's KHR_draco_mesh_compression)");
  flags.AddString("format", &format, "ply|obj|stl|glb",
                  "a label session's --out DIR/: the format of the per-label files");
  flags.AddString("label-names", &label_names_path, "FILE",
                  "a label session: names (and colours) of its labels, as tandem-client stream "
                  "--label-names takes them");
  flags.AddDouble("timeout", &timeout_s, "give up after this many seconds (0 = never)");
  flags.AddBool("verbose", &verbose,
                "print one line per chunk, progress and preview message on stderr");
  flags.AddBool("quiet", &quiet, "no summary on stdout");
  tandem::client::LiveView view;
  view.AddFlags(flags, view_command ? "127.0.0.1:8080" : "");
  if (int rc = ParseOrExit(flags, argc, argv, &connection); rc >= 0) return rc;
  std::error_code ec;
  // A label session's files go to a folder (or one .glb); whether it is one, its messages say.
  const bool out_folder =
      !out.empty() && (absl::EndsWith(out, "/") || std::filesystem::is_directory(out, ec));
  if (!out.empty() && !out_folder && !tandem::io::IsMeshOutputPath(out) &&
      Lower(std::filesystem::path(out).extension().string()) != ".drc") {
    absl::FPrintF(stderr,
                  "tandem-client: --out %s: the extension must be .drc, %s (or a folder DIR/ "
                  "for a label session)\n",
                  out, tandem::io::kMeshExtensions);
    return 2;
  }
  if (format != "ply" && format != "obj" && format != "stl" && format != "glb") {
    absl::FPrintF(stderr, "tandem-client: --format %s: expected ply, obj, stl or glb\n", format);
    return 2;
  }
  tandem::io::LabelNames label_names;
  if (!label_names_path.empty()) {
    absl::StatusOr<tandem::io::LabelNames> read = tandem::io::ReadLabelNames(label_names_path);
    if (!read.ok()) return Fail(read.status());
    label_names = *std::move(read);
  }
  if (absl::Status st = cli::CheckDracoFlags(bits, level); !st.ok()) return UsageError(st);
  if (glb_draco && Lower(std::filesystem::path(out).extension().string()) != ".glb") {
    absl::FPrintF(stderr, "tandem-client: --glb-draco compresses a .glb output; --out is %s\n",
                  out);
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
  if (!label_names_path.empty()) view.SetLabelNames(&label_names);
  view.Wire(&callbacks);
  absl::StatusOr<tandem::client::StreamResult> result =
      tandem::client::WatchSession(connection.options, session, watch_key, timeout_s, callbacks);
  if (!result.ok()) {
    const int rc = connection.Fail(result.status());
    view.Finish(result);
    return rc;
  }
  if (!chunk_error.ok()) return Fail(chunk_error);
  const bool out_glb = Lower(std::filesystem::path(out).extension().string()) == ".glb";
  if (!out.empty() && (result->labels ? !(out_folder || out_glb) : out_folder)) {
    const std::string why =
        result->labels ? absl::StrCat("session ", session,
                                      " is a label session: --out must be a folder (end it with "
                                      "/) or one .glb (a node per label); it is ",
                                      out)
                       : absl::StrCat("session ", session,
                                      " is not a label session: --out must name one mesh file, "
                                      "not the folder ",
                                      out);
    absl::FPrintF(stderr, "tandem-client: %s\n", why);
    view.Finish(result);
    return 2;
  }
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
    if (result->labels) {
      save.label_extension = out_folder ? absl::StrCat(".", format) : "";
      save.label_names = label_names_path.empty() ? nullptr : &label_names;
      const int rc = SaveLabels(*result, save);
      view.Finish(result);
      return rc;
    }
    if (int rc = SaveResult(*result, save); rc != 0) {
      return rc;
    }
  }
  view.Finish(result);
  return 0;
}

}  // namespace tandem::client_app
