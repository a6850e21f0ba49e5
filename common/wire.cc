#include "common/wire.h"

#include "absl/strings/str_cat.h"

namespace tandem::wire {

std::string ServiceVersion() { return "tandem " TANDEM_VERSION_STRING; }

absl::StatusOr<DType> DTypeFromProto(int value, const std::string& field) {
  switch (value) {
    case v1::DTYPE_UINT8: return DType::kUInt8;
    case v1::DTYPE_UINT16: return DType::kUInt16;
    case v1::DTYPE_INT16: return DType::kInt16;
    case v1::DTYPE_FLOAT32: return DType::kFloat32;
    case v1::DTYPE_UNSPECIFIED:
      return absl::InvalidArgumentError(
          absl::StrCat(field, " is unset: say DTYPE_UINT8, DTYPE_UINT16, DTYPE_INT16 or DTYPE_FLOAT32"));
    default:
      return absl::InvalidArgumentError(absl::StrCat(field, " has unknown value ", value));
  }
}

v1::DType DTypeToProto(DType dtype) {
  switch (dtype) {
    case DType::kUInt8: return v1::DTYPE_UINT8;
    case DType::kUInt16: return v1::DTYPE_UINT16;
    case DType::kInt16: return v1::DTYPE_INT16;
    case DType::kFloat32: return v1::DTYPE_FLOAT32;
  }
  return v1::DTYPE_UNSPECIFIED;
}

absl::StatusOr<Schedule> ScheduleFromProto(int value) {
  switch (value) {
    case v1::SCHEDULE_UNSPECIFIED:
    case v1::SCHEDULE_TANDEM_LAG: return Schedule::kTandemLag;
    case v1::SCHEDULE_NONE: return Schedule::kNone;
    case v1::SCHEDULE_CLASSICAL: return Schedule::kClassical;
    case v1::SCHEDULE_TANDEM: return Schedule::kTandem;
    default:
      return absl::InvalidArgumentError(absl::StrCat("config.schedule has unknown value ", value));
  }
}

v1::Schedule ScheduleToProto(Schedule schedule) {
  switch (schedule) {
    case Schedule::kNone: return v1::SCHEDULE_NONE;
    case Schedule::kClassical: return v1::SCHEDULE_CLASSICAL;
    case Schedule::kTandem: return v1::SCHEDULE_TANDEM;
    case Schedule::kTandemLag: return v1::SCHEDULE_TANDEM_LAG;
  }
  return v1::SCHEDULE_UNSPECIFIED;
}

namespace {
void DirectedToProto(const DirectedDistance& d, v1::DirectedDistance* out) {
  out->set_l1(d.l1);
  out->set_l2(d.l2);
  out->set_linf(d.linf);
  out->set_samples(d.samples);
}
DirectedDistance DirectedFromProto(const v1::DirectedDistance& d) {
  DirectedDistance out;
  out.l1 = d.l1();
  out.l2 = d.l2();
  out.linf = d.linf();
  out.samples = d.samples();
  return out;
}
}  // namespace

void ReportToProto(const MetricsReport& r, v1::FinalMetrics* out) {
  out->set_schedule(std::string(ScheduleName(r.options.schedule)));
  out->set_iso(r.options.iso);
  out->set_error_threshold(r.options.error);
  out->set_alpha(r.options.alpha);
  out->set_distance_guard(r.options.distance_guard);
  out->set_sag_correction(r.options.sag_correction);
  out->set_sag_corrected(r.stats.sag_corrected);
  out->set_target_triangles(r.options.target_triangles);
  out->set_nx(r.nx);
  out->set_ny(r.ny);
  out->set_nz(r.nz);
  out->set_slices(r.stats.slices);
  out->set_crossed_cubes(r.stats.crossed_cubes);
  out->set_triangles_extracted(r.stats.triangles_extracted);
  out->set_triangles_final(r.triangles_final);
  out->set_vertices_final(r.vertices_final);
  out->set_peak_triangles(r.stats.peak_triangles);
  out->set_error_max(r.error_max);
  out->set_anisotropy(r.anisotropy);
  out->set_directional_bias(r.directional_bias);
  out->set_time_extract_s(r.stats.time.extract_s);
  out->set_time_simplify_s(r.stats.time.simplify_s);
  out->set_time_total_s(r.stats.time.total_s);
  out->set_peak_rss_bytes(r.peak_rss_bytes);
  out->mutable_trace()->Assign(r.stats.trace.begin(), r.stats.trace.end());
  v1::Refusals* f = out->mutable_refusals();
  f->set_link(r.stats.refusals.link);
  f->set_flip(r.stats.refusals.flip);
  f->set_degenerate(r.stats.refusals.degenerate);
  f->set_box(r.stats.refusals.box);
  f->set_error(r.stats.refusals.error);
  f->set_distance(r.stats.refusals.distance);
  out->set_contractions(r.stats.contractions);
  if (r.distance) {
    v1::Distances* d = out->mutable_distance();
    DirectedToProto(r.distance->forward, d->mutable_forward());
    DirectedToProto(r.distance->backward, d->mutable_backward());
    d->set_l1_max(r.distance->l1_max);
    d->set_l2_max(r.distance->l2_max);
    d->set_linf_max(r.distance->linf_max);
  } else {
    out->clear_distance();
  }
  out->set_bytes_received(r.bytes_received);
  out->set_bytes_sent(r.bytes_sent);
  out->set_peak_session_bytes(r.peak_session_bytes);
}

MetricsReport ReportFromProto(const v1::FinalMetrics& m) {
  MetricsReport r;
  // A name this build does not know (a newer server's) leaves the default.
  if (absl::StatusOr<Schedule> s = ParseSchedule(m.schedule()); s.ok()) r.options.schedule = *s;
  r.options.iso = m.iso();
  r.options.error = m.error_threshold();
  r.options.alpha = m.alpha();
  r.options.distance_guard = m.distance_guard();
  r.options.sag_correction = m.sag_correction();
  r.stats.sag_corrected = m.sag_corrected();
  r.options.target_triangles = m.target_triangles();
  r.nx = m.nx();
  r.ny = m.ny();
  r.nz = m.nz();
  r.stats.slices = m.slices();
  r.stats.crossed_cubes = m.crossed_cubes();
  r.stats.triangles_extracted = m.triangles_extracted();
  r.triangles_final = m.triangles_final();
  r.vertices_final = m.vertices_final();
  r.stats.peak_triangles = m.peak_triangles();
  r.error_max = m.error_max();
  r.anisotropy = m.anisotropy();
  r.directional_bias = m.directional_bias();
  r.stats.time.extract_s = m.time_extract_s();
  r.stats.time.simplify_s = m.time_simplify_s();
  r.stats.time.total_s = m.time_total_s();
  r.peak_rss_bytes = m.peak_rss_bytes();
  r.stats.trace.assign(m.trace().begin(), m.trace().end());
  r.stats.refusals.link = m.refusals().link();
  r.stats.refusals.flip = m.refusals().flip();
  r.stats.refusals.degenerate = m.refusals().degenerate();
  r.stats.refusals.box = m.refusals().box();
  r.stats.refusals.error = m.refusals().error();
  r.stats.refusals.distance = m.refusals().distance();
  r.stats.contractions = m.contractions();
  if (m.has_distance()) {
    Distances d;
    d.forward = DirectedFromProto(m.distance().forward());
    d.backward = DirectedFromProto(m.distance().backward());
    d.l1_max = m.distance().l1_max();
    d.l2_max = m.distance().l2_max();
    d.linf_max = m.distance().linf_max();
    r.distance = d;
  }
  r.bytes_received = m.bytes_received();
  r.bytes_sent = m.bytes_sent();
  r.peak_session_bytes = m.peak_session_bytes();
  return r;
}

grpc::Status ToGrpcStatus(const absl::Status& status) {
  if (status.ok()) return grpc::Status::OK;
  return grpc::Status(static_cast<grpc::StatusCode>(status.code()),
                      std::string(status.message()));
}

absl::Status FromGrpcStatus(const grpc::Status& status) {
  if (status.ok()) return absl::OkStatus();
  return absl::Status(static_cast<absl::StatusCode>(status.error_code()), status.error_message());
}

}  // namespace tandem::wire
