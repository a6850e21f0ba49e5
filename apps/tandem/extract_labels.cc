// tandem extract --labels: a label volume to one surface per label (sharing their
// interfaces), written one file per label and as one GLB with a node per label, with
// per-label figures.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "apps/common/cli_util.h"
#include "command.h"
#ifdef TANDEM_HAVE_DRACO
#include "neuroglancer_export.h"
#endif
#include "tandem/eval/label_metrics.h"
#include "tandem/eval/report.h"
#include "tandem/io/labels_io.h"
#include "tandem/io/run_session.h"
#include "tandem/labels.h"
#include "tandem/status_macros.h"

namespace tandem::app {

namespace {

// What a label session leaves: the run's report, its interface complex and the complex cut
// into one surface per label; with --neuroglancer, the complexes of the coarser sweeps
// (E0 * 2^k, k = 1..) too. Every session (and its label tables) is let go before the split.
struct LabelRun {
  eval::MetricsReport report;
  LabeledMesh complex;
  std::vector<std::pair<LabelId, IndexedMesh>> surfaces;
  std::vector<LabeledMesh> coarser;
};

// A template on the options' type, so that this builds with an engine that has no label mode
// (no SessionOptions::labels: refused) as well as with one.
template <typename Options>
absl::StatusOr<LabelRun> RunLabelSession(SliceSource& source, Options options,
                                         const LabelOptions& labels, int coarser,
                                         const std::function<void(int64_t, int64_t)>& progress) {
  if constexpr (requires { options.labels; }) {
    options.labels = labels;
    if (!options.labels.enabled) return absl::InvalidArgumentError("--labels is not set");
    std::vector<Options> all{options};
    for (int k = 1; k <= coarser; ++k) {  // read in the same pass as the finest
      Options o = options;
      o.error = std::ldexp(o.error, k);
      if (o.target_triangles > 0)
        o.target_triangles = std::max<int64_t>(4, o.target_triangles >> k);
      all.push_back(o);
    }
    // Sealed (--seal): each sweep's chunks, welded at the end into the same complex.
    std::vector<std::vector<SealedChunk>> chunks(all.size());
    std::function<absl::Status(size_t, SealedChunk)> on_chunk;
    if (options.seal) {
      on_chunk = [&chunks](size_t k, SealedChunk c) {
        chunks[k].push_back(std::move(c));
        return absl::OkStatus();
      };
    }
    TANDEM_ASSIGN_OR_RETURN(auto sessions, io::RunSessions(source, all, progress, on_chunk));
    auto complex = [&](size_t k) {
      LabeledMesh m = options.seal ? WeldLabeledChunks(chunks[k]) : sessions[k]->SnapshotLabeled();
      std::vector<SealedChunk>().swap(chunks[k]);
      return m;
    };
    LabelRun run;
    run.complex = complex(0);
    run.report = eval::MakeReport(*sessions[0], run.complex.mesh);
    sessions[0].reset();
    for (size_t k = 1; k < sessions.size(); ++k) {
      run.coarser.push_back(complex(k));
      sessions[k].reset();
    }
    // A session holds per label its pairs' tables and store: gone before the surfaces come.
    run.surfaces = SplitByLabel(run.complex, labels.background);
    return run;
  } else {
    (void)source;
    (void)coarser;
    (void)progress;
    return absl::UnimplementedError(
        "--labels: this build's engine has no label mode (SessionOptions::labels)");
  }
}

}  // namespace

int ExtractLabels(const cli::ExtractFlags& f, const cli::FlagSet& flags, SliceSource& source,
                  const io::MeshWriteOptions& write, const NeuroglancerRequest& neuroglancer) {
  const VolumeInfo info = source.info();
  const std::string input = f.InputPath();
  if (absl::Status st = f.CheckLabelInput(info); !st.ok()) return Usage(st);
  absl::StatusOr<LabelOptions> labels = f.Labels();
  if (!labels.ok()) return Usage(labels.status());
  io::LabelNames names;
  if (!f.label_names.empty()) {
    absl::StatusOr<io::LabelNames> read = io::ReadLabelNames(f.label_names);
    if (!read.ok()) return Fail(read.status());
    names = *std::move(read);
  }
  absl::StatusOr<SessionOptions> options = f.Options(flags, info);
  if (!options.ok()) return Usage(options.status());
  if (const std::string w = cli::OptionsWarning(*options, info); !w.empty()) {
    std::fprintf(stderr, "tandem extract: warning: %s\n", w.c_str());
  }
  cli::Progress progress("slices");
  absl::StatusOr<LabelRun> run = RunLabelSession(
      source, *options, *labels, neuroglancer.dir.empty() ? 0 : neuroglancer.lods - 1,
      [&](int64_t d, int64_t t) {
        if (!f.quiet) progress.Update(d, t);
      });
  progress.Done();
  if (!run.ok()) {
    return Fail(absl::Status(run.status().code(),
                             absl::StrCat(input, ": ", std::string(run.status().message()))));
  }
  const io::LabelNames* table = f.label_names.empty() ? nullptr : &names;
  // The figures first, so that the complex, unless the export needs it, goes before the
  // outputs are written: a label's memory is then its surfaces'.
  std::vector<eval::LabelMetrics> measured;
  for (const auto& [id, mesh] : run->surfaces) {
    eval::LabelMetrics m = eval::MeasureLabel(id, mesh);
    if (auto it = names.find(id); it != names.end()) m.name = it->second.name;
    measured.push_back(std::move(m));
  }
  eval::MetricsReport& report = run->report;
  if (neuroglancer.dir.empty()) run->complex = {};
  if (f.LabelsToFolder()) {
    absl::StatusOr<std::vector<io::LabelFile>> files =
        io::WriteLabelMeshes(f.out, absl::StrCat(".", f.format), run->surfaces, table, write);
    if (!files.ok()) return FailWriting(files.status());
  } else if (absl::Status st = io::WriteLabelsGlb(f.out, run->surfaces, table, write.space);
             !st.ok()) {
    return FailWriting(st);
  }
  run->surfaces = {};
#ifdef TANDEM_HAVE_DRACO
  if (!neuroglancer.dir.empty()) {
    std::vector<const LabeledMesh*> levels{&run->complex};
    for (const LabeledMesh& c : run->coarser) levels.push_back(&c);
    const double nm =
        neuroglancer.nm_per_unit > 0 ? neuroglancer.nm_per_unit : DefaultNmPerUnit(info);
    if (absl::Status st =
            WriteNeuroglancerLabels(neuroglancer.dir, info, levels, labels->background, nm,
                                    static_cast<int>(f.compression_level),
                                    {neuroglancer.chunk_voxels, neuroglancer.skirt_voxels});
        !st.ok()) {
      return FailWriting(st);
    }
  }
#endif

  report.input = input;
  report.peak_rss_bytes = eval::PeakRssBytes();
  if (!f.metrics.empty()) {
    if (absl::Status st = WriteText(f.metrics, eval::ReportWithLabelsToJson(report, measured));
        !st.ok()) {
      return Fail(st);
    }
  } else if (!f.quiet) {
    std::fprintf(stderr, "%s -> %s (%zu labels)\n%s  labels:\n%s", input.c_str(), f.out.c_str(),
                 measured.size(), eval::ReportSummary(report).c_str(),
                 eval::LabelMetricsSummary(measured).c_str());
  }
  if (measured.empty() && !f.quiet) {
    std::fprintf(stderr, "tandem extract: warning: %s holds no label but the background (%s)\n",
                 input.c_str(), f.background.c_str());
  }
  return 0;
}

}  // namespace tandem::app
