#include "tandem/common/wire.h"

#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>
#include <google/protobuf/reflection.h>

#include <algorithm>
#include <optional>
#include <set>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"

namespace tandem::common {

std::string ServiceVersion() { return "tandem " TANDEM_VERSION_STRING; }

namespace {
// The wire's DType of each of tandem's, both ways.
constexpr std::pair<v1::DType, DType> kWireDTypes[] = {
    {v1::DTYPE_UINT8, DType::kUInt8},    {v1::DTYPE_INT8, DType::kInt8},
    {v1::DTYPE_UINT16, DType::kUInt16},  {v1::DTYPE_INT16, DType::kInt16},
    {v1::DTYPE_UINT32, DType::kUInt32},  {v1::DTYPE_INT32, DType::kInt32},
    {v1::DTYPE_UINT64, DType::kUInt64},  {v1::DTYPE_INT64, DType::kInt64},
    {v1::DTYPE_FLOAT32, DType::kFloat32}};
}  // namespace

absl::StatusOr<DType> DTypeFromProto(int value, const std::string& field) {
  for (const auto& [wire, dtype] : kWireDTypes) {
    if (value == wire) return dtype;
  }
  if (value == v1::DTYPE_UNSPECIFIED) {
    std::vector<std::string> names;
    for (const auto& [wire, dtype] : kWireDTypes) names.push_back(v1::DType_Name(wire));
    return absl::InvalidArgumentError(
        absl::StrCat(field, " is unset: say ", absl::StrJoin(names, ", ")));
  }
  return absl::InvalidArgumentError(absl::StrCat(field, " has unknown value ", value));
}

v1::DType DTypeToProto(DType dtype) {
  for (const auto& [wire, d] : kWireDTypes) {
    if (d == dtype) return wire;
  }
  return v1::DTYPE_UNSPECIFIED;
}

std::vector<v1::DType> WireDTypes() {
  std::vector<v1::DType> out;
  for (const auto& [wire, dtype] : kWireDTypes) out.push_back(wire);
  return out;
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
using google::protobuf::FieldDescriptor;
using google::protobuf::Message;

// The distances are a nested struct on both sides: converted by hand, as one table entry.
void DirectedToProto(const eval::DirectedDistance& d, v1::DirectedDistance* out) {
  out->set_l1(d.l1);
  out->set_l2(d.l2);
  out->set_linf(d.linf);
  out->set_samples(d.samples);
}
eval::DirectedDistance DirectedFromProto(const v1::DirectedDistance& d) {
  eval::DirectedDistance out;
  out.l1 = d.l1();
  out.l2 = d.l2();
  out.linf = d.linf();
  out.samples = d.samples();
  return out;
}
void DistancesToProto(const eval::Distances& d, v1::Distances* out) {
  DirectedToProto(d.forward, out->mutable_forward());
  DirectedToProto(d.backward, out->mutable_backward());
  out->set_l1_max(d.l1_max);
  out->set_l2_max(d.l2_max);
  out->set_linf_max(d.linf_max);
}
eval::Distances DistancesFromProto(const v1::Distances& d) {
  eval::Distances out;
  out.forward = DirectedFromProto(d.forward());
  out.backward = DirectedFromProto(d.backward());
  out.l1_max = d.l1_max();
  out.l2_max = d.l2_max();
  out.linf_max = d.linf_max();
  return out;
}

// Each type of the table's members on the wire: Fits says whether a field can hold it, Put
// writes it and Get reads it (into a field that Fits).
bool Singular(const FieldDescriptor& f, FieldDescriptor::CppType type) {
  return !f.is_repeated() && f.cpp_type() == type;
}

bool Fits(const FieldDescriptor& f, const double*) {
  return Singular(f, FieldDescriptor::CPPTYPE_DOUBLE);
}
void Put(Message* m, const FieldDescriptor* f, double v) { m->GetReflection()->SetDouble(m, f, v); }
void Get(const Message& m, const FieldDescriptor* f, double* v) {
  *v = m.GetReflection()->GetDouble(m, f);
}

bool Fits(const FieldDescriptor& f, const int64_t*) {
  return Singular(f, FieldDescriptor::CPPTYPE_INT64);
}
void Put(Message* m, const FieldDescriptor* f, int64_t v) { m->GetReflection()->SetInt64(m, f, v); }
void Get(const Message& m, const FieldDescriptor* f, int64_t* v) {
  *v = m.GetReflection()->GetInt64(m, f);
}

bool Fits(const FieldDescriptor& f, const std::string*) {
  return Singular(f, FieldDescriptor::CPPTYPE_STRING);
}
void Put(Message* m, const FieldDescriptor* f, const std::string& v) {
  m->GetReflection()->SetString(m, f, v);
}
void Get(const Message& m, const FieldDescriptor* f, std::string* v) {
  *v = m.GetReflection()->GetString(m, f);
}

// By name, as in the JSON.
bool Fits(const FieldDescriptor& f, const Schedule*) {
  return Singular(f, FieldDescriptor::CPPTYPE_STRING);
}
void Put(Message* m, const FieldDescriptor* f, Schedule v) {
  m->GetReflection()->SetString(m, f, std::string(ScheduleName(v)));
}
void Get(const Message& m, const FieldDescriptor* f, Schedule* v) {
  // A name this build does not know (a newer server's) leaves the default.
  if (absl::StatusOr<Schedule> s = ParseSchedule(m.GetReflection()->GetString(m, f)); s.ok()) {
    *v = *s;
  }
}

bool Fits(const FieldDescriptor& f, const std::vector<int64_t>*) {
  return f.is_repeated() && f.cpp_type() == FieldDescriptor::CPPTYPE_INT64;
}
void Put(Message* m, const FieldDescriptor* f, const std::vector<int64_t>& v) {
  auto field = m->GetReflection()->GetMutableRepeatedFieldRef<int64_t>(m, f);
  field.Clear();
  for (int64_t x : v) field.Add(x);
}
void Get(const Message& m, const FieldDescriptor* f, std::vector<int64_t>* v) {
  auto field = m.GetReflection()->GetRepeatedFieldRef<int64_t>(m, f);
  v->assign(field.begin(), field.end());
}

// A Distances message, absent without distances.
bool Fits(const FieldDescriptor& f, const std::optional<eval::Distances>*) {
  return Singular(f, FieldDescriptor::CPPTYPE_MESSAGE) &&
         f.message_type() == v1::Distances::descriptor();
}
void Put(Message* m, const FieldDescriptor* f, const std::optional<eval::Distances>& v) {
  if (!v) {
    m->GetReflection()->ClearField(m, f);
    return;
  }
  DistancesToProto(*v, google::protobuf::DynamicCastToGenerated<v1::Distances>(
                           m->GetReflection()->MutableMessage(m, f)));
}
void Get(const Message& m, const FieldDescriptor* f, std::optional<eval::Distances>* v) {
  if (m.GetReflection()->HasField(m, f)) {
    *v = DistancesFromProto(*google::protobuf::DynamicCastToGenerated<v1::Distances>(
        &m.GetReflection()->GetMessage(m, f)));
  }
}

// The fields a wire name walks from FinalMetrics ("refusals.link": refusals, then its link),
// the last one able to hold `member`; or why there are none.
using FieldPath = std::vector<const FieldDescriptor*>;
template <class T>
absl::StatusOr<FieldPath> FindWireField(const char* name, const T& member) {
  FieldPath path;
  const google::protobuf::Descriptor* message = v1::FinalMetrics::descriptor();
  for (const absl::string_view part : absl::StrSplit(name, '.')) {
    const FieldDescriptor* f =
        message != nullptr ? message->FindFieldByName(std::string(part)) : nullptr;
    if (f == nullptr) {
      return absl::NotFoundError(absl::StrCat("tandem.v1.FinalMetrics has no field ", name));
    }
    path.push_back(f);
    message = Singular(*f, FieldDescriptor::CPPTYPE_MESSAGE) ? f->message_type() : nullptr;
  }
  const FieldDescriptor& last = *path.back();
  if (!Fits(last, &member)) {
    const std::string type = last.message_type() != nullptr ? last.message_type()->full_name()
                                                            : std::string(last.type_name());
    return absl::InvalidArgumentError(absl::StrCat("tandem.v1.FinalMetrics.", name, " is of type ",
                                                   last.is_repeated() ? "repeated " : "", type,
                                                   ", which cannot hold the report's member"));
  }
  return path;
}
}  // namespace

template <class T>
absl::Status CheckWireField(const char* name, const T& member) {
  return FindWireField(name, member).status();
}
template absl::Status CheckWireField(const char*, const double&);
template absl::Status CheckWireField(const char*, const int64_t&);
template absl::Status CheckWireField(const char*, const std::string&);
template absl::Status CheckWireField(const char*, const Schedule&);
template absl::Status CheckWireField(const char*, const std::vector<int64_t>&);
template absl::Status CheckWireField(const char*, const std::optional<eval::Distances>&);

absl::Status CheckReportFields() {
  std::vector<std::string> errors;
  std::set<std::string> named;
  const eval::MetricsReport r;
  eval::VisitReportFields(r, [&](const char* key, const char* wire, const auto& v, eval::Written) {
    if (wire == nullptr) return;
    if (!named.insert(wire).second) {
      errors.push_back(absl::StrCat(key, ": ", wire, " is named twice"));
    } else if (absl::Status s = CheckWireField(wire, v); !s.ok()) {
      errors.push_back(absl::StrCat(key, ": ", s.message()));
    }
  });
  if (errors.empty()) return absl::OkStatus();
  return absl::InternalError(absl::StrJoin(errors, "; "));
}

// A field that FindWireField refuses is left out, and CheckReportFields names it (a test holds
// it ok).
void ReportToProto(const eval::MetricsReport& r, v1::FinalMetrics* out) {
  eval::VisitReportFields(r, [out](const char*, const char* wire, const auto& v, eval::Written) {
    if (wire == nullptr) return;  // not on the wire
    const absl::StatusOr<FieldPath> path = FindWireField(wire, v);
    if (!path.ok()) return;
    Message* m = out;
    for (size_t i = 0; i + 1 < path->size(); ++i) {
      m = m->GetReflection()->MutableMessage(m, (*path)[i]);
    }
    Put(m, path->back(), v);
  });
}

eval::MetricsReport ReportFromProto(const v1::FinalMetrics& metrics) {
  eval::MetricsReport r;
  eval::VisitReportFields(r, [&metrics](const char*, const char* wire, auto& v, eval::Written) {
    if (wire == nullptr) return;  // not on the wire: the default
    const absl::StatusOr<FieldPath> path = FindWireField(wire, v);
    if (!path.ok()) return;
    const Message* m = &metrics;
    for (size_t i = 0; i + 1 < path->size(); ++i) {
      m = &m->GetReflection()->GetMessage(*m, (*path)[i]);
    }
    Get(*m, path->back(), &v);
  });
  return r;
}

void LabelMetricsToProto(const eval::LabelMetrics& m, v1::FinalMetrics* out) {
  out->set_label(m.label);
  out->set_triangles_final(m.triangles);
  out->set_vertices_final(m.vertices);
  v1::LabelFigures* f = out->mutable_label_figures();
  f->set_area(m.area);
  f->set_volume(m.volume);
  f->set_euler(m.euler);
  f->set_components(m.components);
  f->set_manifold(m.manifold);
  f->set_closed(m.closed);
}

eval::LabelMetrics LabelMetricsFromProto(const v1::FinalMetrics& metrics) {
  const v1::LabelFigures& f = metrics.label_figures();
  eval::LabelMetrics m;
  m.label = metrics.label();
  m.triangles = metrics.triangles_final();
  m.vertices = metrics.vertices_final();
  m.area = f.area();
  m.volume = f.volume();
  m.euler = f.euler();
  m.components = f.components();
  m.manifold = f.manifold();
  m.closed = f.closed();
  return m;
}

void FinishingToProto(const TandemSession::Finishing& f, v1::Progress* out) {
  if (!f.running) return;
  out->set_finishing(f.step);
  out->set_finishing_share(f.share);
  out->set_finishing_step_seconds(f.step_seconds);
  out->set_finishing_seconds(f.seconds);
}

TandemSession::Finishing FinishingFromProto(const v1::Progress& p) {
  TandemSession::Finishing f;
  if (p.finishing().empty()) return f;
  f.running = true;
  f.step = p.finishing().c_str();  // valid while p is
  f.share = p.finishing_share();
  f.step_seconds = p.finishing_step_seconds();
  f.seconds = p.finishing_seconds();
  return f;
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

void LabelPairsToProto(std::span<const uint32_t> patch, std::span<const LabelPair> pairs,
                       LabelId background, v1::LabelPairs* out) {
  out->Clear();
  for (const LabelPair& p : pairs) {
    out->add_inside(p.inside);
    out->add_outside(p.outside);
  }
  out->set_background(background);
  const auto none = static_cast<uint32_t>(pairs.size());
  for (size_t t = 0; t < patch.size();) {
    const uint32_t k = std::min(patch[t], none);
    size_t end = t + 1;
    while (end < patch.size() && std::min(patch[end], none) == k) ++end;
    out->add_runs(k);
    out->add_runs(static_cast<uint32_t>(end - t));
    t = end;
  }
}

absl::Status LabelPairsFromProto(const v1::LabelPairs& in, size_t triangles, SealedChunk* chunk,
                                 LabelId* background) {
  if (in.inside_size() != in.outside_size()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "label_pairs: ", in.inside_size(), " inside labels, ", in.outside_size(), " outside"));
  }
  if (in.runs_size() % 2 != 0) {
    return absl::InvalidArgumentError("label_pairs.runs: an odd count (index, length pairs)");
  }
  uint64_t covered = 0;
  for (int i = 1; i < in.runs_size(); i += 2) covered += in.runs(i);
  if (covered != triangles) {
    return absl::InvalidArgumentError(
        absl::StrCat("label_pairs.runs cover ", covered, " triangles of ", triangles));
  }
  chunk->pairs.resize(static_cast<size_t>(in.inside_size()));
  for (int k = 0; k < in.inside_size(); ++k) chunk->pairs[k] = {in.inside(k), in.outside(k)};
  const auto none = static_cast<uint32_t>(chunk->pairs.size());
  chunk->patch.clear();
  chunk->patch.reserve(triangles);
  for (int i = 0; i + 1 < in.runs_size(); i += 2) {
    chunk->patch.insert(chunk->patch.end(), in.runs(i + 1), std::min(in.runs(i), none));
  }
  *background = in.background();
  return absl::OkStatus();
}

}  // namespace tandem::common
