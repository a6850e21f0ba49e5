// Conversions between core types and the tandem.v1 wire messages, shared by the server,
// the client and the tests (one copy of each mapping).
#ifndef TANDEM_PROTO_COMMON_WIRE_H_
#define TANDEM_PROTO_COMMON_WIRE_H_

#include <grpcpp/support/status.h>

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/eval/label_metrics.h"
#include "tandem/eval/report.h"
#include "tandem/tandem.h"
#include "tandem/v1/tandem.pb.h"
#include "tandem/volume.h"

namespace tandem::common {

inline constexpr char kDefaultServerAddress[] = "127.0.0.1:50051";
// Largest FinalMesh chunk the server sends (well below gRPC's 4 MiB default).
inline constexpr size_t kFinalMeshChunkBytes = size_t{1} << 20;
// Default SliceChunk payload of the client (an 8 MiB slice goes in 8 messages).
inline constexpr size_t kDefaultSliceChunkBytes = size_t{1} << 20;
// The client's limit for one response message (previews are not chunked).
inline constexpr int kClientMaxReceiveBytes = 256 << 20;

std::string ServiceVersion();  // "tandem <project version>"

// DTYPE_UNSPECIFIED (and unknown values) → InvalidArgument naming `field`.
absl::StatusOr<DType> DTypeFromProto(int value, const std::string& field);
v1::DType DTypeToProto(DType dtype);
// Every DType the wire carries, in the order the server lists them (ServerInfo.dtypes).
std::vector<v1::DType> WireDTypes();
// SCHEDULE_UNSPECIFIED → kTandemLag; unknown values → InvalidArgument.
absl::StatusOr<Schedule> ScheduleFromProto(int value);
v1::Schedule ScheduleToProto(Schedule schedule);

// Every field of MetricsReport's table (VisitReportFields) that names a FinalMetrics field:
// all but input and frame, which the client knows itself. Driven by the table through protobuf
// reflection; a field whose name CheckReportFields refuses is left out.
void ReportToProto(const eval::MetricsReport& report, v1::FinalMetrics* out);
eval::MetricsReport ReportFromProto(const v1::FinalMetrics& metrics);
// One label's figures (a label session's per-label FinalMetrics: label, label_figures,
// triangles_final, vertices_final); the name stays off the wire (the client's --label-names).
void LabelMetricsToProto(const eval::LabelMetrics& m, v1::FinalMetrics* out);
eval::LabelMetrics LabelMetricsFromProto(const v1::FinalMetrics& metrics);

// A label session's sealed chunk: the pairs its triangles separate (`patch` indexes `pairs`,
// one per triangle in the order its Draco buffer decodes them; past the pairs: no label's),
// as runs of one pair.
void LabelPairsToProto(std::span<const uint32_t> patch, std::span<const LabelPair> pairs,
                       LabelId background, v1::LabelPairs* out);
// The other way, for a chunk of `triangles` decoded triangles: chunk->patch and pairs, and
// the background. InvalidArgument naming the field when the runs do not cover the triangles
// exactly or the pairs' lists differ in length.
absl::Status LabelPairsFromProto(const v1::LabelPairs& in, size_t triangles, SealedChunk* chunk,
                                 LabelId* background);

// OK when FinalMetrics has the field `wire` ("refusals.link": link of the sub-message refusals)
// of a type that holds `member`: double, int64, string (std::string and Schedule, by name),
// repeated int64 (std::vector<int64_t>), Distances (std::optional<Distances>).
template <class T>
absl::Status CheckWireField(const char* wire, const T& member);
// CheckWireField for every wire name of VisitReportFields, each named once; the error lists
// every one that fails. WireReport.TableNamesFinalMetricsFields holds it OK.
absl::Status CheckReportFields();

// Canonical codes are numbered the same in Abseil and gRPC.
// A session's finishing gauge into Progress's finishing fields, and back (running = a step
// is named).
void FinishingToProto(const TandemSession::Finishing& f, v1::Progress* out);
TandemSession::Finishing FinishingFromProto(const v1::Progress& p);

grpc::Status ToGrpcStatus(const absl::Status& status);
absl::Status FromGrpcStatus(const grpc::Status& status);

}  // namespace tandem::common

#endif  // TANDEM_PROTO_COMMON_WIRE_H_
