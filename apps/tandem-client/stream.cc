// tandem-client stream: a volume, slice by slice, to tandem-server; the simplified
// iso-surface and its metrics back (with previews, sealed chunks, resume and the live view).
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "apps/common/cli_util.h"
#include "apps/common/extract_flags.h"
#include "command.h"
#include "live_view.h"
#include "save.h"
#include "tandem/client/chunk_store.h"
#include "tandem/client/stream_client.h"
#include "tandem/common/wire.h"
#include "tandem/io/follow.h"
#include "tandem/io/labels_io.h"
#include "tandem/io/mesh_io.h"
#include "tandem/io/open_volume.h"
#include "tandem/status_macros.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"

namespace tandem::client_app {

int StreamCommand(int argc, char** argv) {
  ConnectionFlags connection;
  tandem::cli::ExtractFlags f;  // the flags `tandem extract` has too
  int64_t keepalive_ms = 30000;
  std::string partials, chunks_dir, resume;
  double rate = 0, timeout_s = 0;
  int64_t chunk_bytes = tandem::common::kDefaultSliceChunkBytes;
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
      "vertex normals), .stl, .glb.\nWith --labels (a label map): every label's surface, into "
      "--out DIR/ (a file per label and labels.glb) or one .glb, as `tandem extract --labels`.");
  connection.Add(flags, /*token=*/true);
  f.Add(&flags,
        "final mesh: .drc (the server's Draco bytes), .ply or .obj (with vertex "
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
  flags.AddString("partials", &partials, "DIR",
                  "save each preview as DIR/preview_<slice, 6 digits>.drc");
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
  // --labels' --out (a folder, or one .glb) is held to its rules by f.Check.
  if (!f.labels && ext != ".drc" && !tandem::io::IsMeshOutputPath(out)) {
    absl::FPrintF(stderr, "tandem-client: --out %s: the extension must be .drc, %s\n", out,
                  tandem::io::kMeshExtensions);
    return 2;
  }
  // Fail before streaming, not after: the output's folder must exist.
  // (A label folder is made when it is written, as `tandem extract --labels` makes it.)
  if (const std::filesystem::path parent = std::filesystem::path(out).parent_path();
      !(f.labels && f.LabelsToFolder()) && !parent.empty() &&
      !std::filesystem::is_directory(parent)) {
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
      absl::FPrintF(stderr,
                    "tandem-client: --resume: expected ID:TOKEN (as the first client "
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
  std::string spacing_warning;    // --spacing replacing the file's own
  bool geometry_refused = false;  // --spacing or --frame does not fit the volume: usage
  auto open = [&]() -> absl::StatusOr<std::unique_ptr<tandem::SliceSource>> {
    absl::StatusOr<std::unique_ptr<tandem::SliceSource>> src;
    if (!follow) {
      src = tandem::io::OpenVolume(input, f.Open(note));
    } else {
      tandem::io::FollowOptions fo = f.Follow(note);
      fo.progress = [&](int64_t seen, int64_t) { on_disk = seen; };
      src = tandem::io::FollowVolume(input, fo);
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
  // A label map has no iso-value: its surfaces lie between its labels.
  absl::StatusOr<std::vector<tandem::cli::IsoValue>> isos =
      f.labels ? std::vector<tandem::cli::IsoValue>{{0, "0"}} : f.Isos(flags, info);
  if (!isos.ok()) return UsageError(isos.status());
  tandem::io::LabelNames label_names;
  absl::StatusOr<tandem::LabelOptions> labels = f.Labels();
  if (!labels.ok()) return UsageError(labels.status());
  if (f.labels) {
    if (absl::Status st = f.CheckLabelInput(info); !st.ok()) return UsageError(st);
    if (!f.label_names.empty()) {
      absl::StatusOr<tandem::io::LabelNames> read = tandem::io::ReadLabelNames(f.label_names);
      if (!read.ok()) return Fail(read.status());
      label_names = *std::move(read);
    }
  }
  // The session's options are checked by core's rules (--target-triangles with --seal or
  // --chunks too), as `tandem extract` checks them, before anything is sent.
  absl::StatusOr<tandem::SessionOptions> session = f.Options(flags, info);
  if (!session.ok()) return UsageError(session.status());
  if (const std::string w = tandem::cli::OptionsWarning(*session, info); !w.empty()) {
    std::fprintf(stderr, "tandem-client: warning: %s\n", w.c_str());
  }
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
    TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<tandem::SliceSource> again, open());
    range.Replace(std::move(again));
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
  c.set_schedule(tandem::common::ScheduleToProto(session->schedule));
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
  if (labels->enabled) {
    tandem::v1::LabelConfig& l = *c.mutable_labels();
    l.set_enabled(true);
    l.set_background(labels->background);
    for (tandem::LabelId id : labels->only) l.add_only(id);
    l.set_close(labels->close);
  }

  const int64_t nz = (*source)->info().nz;
  const bool bar = isatty(STDERR_FILENO) != 0 && !verbose && !f.quiet;
  absl::Status partial_error;
  tandem::client::StreamCallbacks callbacks;
  // After the last slice, the server says what its finish is doing: one status line.
  tandem::cli::FinishingStatus finishing("tandem-client: ", f.quiet);
  callbacks.on_progress = [&](const tandem::v1::Progress& p, int64_t sent) {
    if (!p.finishing().empty()) {
      if (verbose) {
        absl::FPrintF(stderr, "progress finishing=\"%s\" share=%.3f seconds=%.1f\n", p.finishing(),
                      p.finishing_share(), p.finishing_seconds());
      } else {
        if (status_shown.exchange(false)) absl::FPrintF(stderr, "\n");
        finishing.Show({tandem::common::FinishingFromProto(p)});
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
                  absl::StatusCodeToString(refusal.code()), std::string(refusal.message()), retry,
                  connection.options.retries, seconds);
  };
  callbacks.on_resume = [&](const absl::Status& cause, int64_t slice, int attempt, double seconds) {
    absl::FPrintF(stderr,
                  "%standem-client: the stream broke (%s: %s); resuming at slice %d, "
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
                    "tandem-client: %d sealed chunks kept in %s; the server sends the rest\n", kept,
                    chunks_dir);
    }
  };
  if (absl::Status st = view.Start(c.description(), nz); !st.ok()) {
    return absl::IsInvalidArgument(st) ? UsageError(st) : Fail(st);  // --view's address
  }
  std::vector<std::string> iso_texts;
  for (const tandem::cli::IsoValue& v : *isos) iso_texts.push_back(v.text);
  if (f.labels) {
    view.SetLabels(f.label_names.empty() ? nullptr : &label_names);
  } else {
    view.SetIsos(iso_texts);
  }
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
  if (f.labels) {
    save.label_extension = f.LabelsToFolder() ? absl::StrCat(".", f.format) : "";
    save.label_names = f.label_names.empty() ? nullptr : &label_names;
    const int rc = SaveLabels(*result, save);
    view.Finish(result);
    return rc;
  }
  if (int rc = SaveResult(*result, save); rc != 0) {
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

}  // namespace tandem::client_app
