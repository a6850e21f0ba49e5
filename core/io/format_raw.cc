// Headerless raw voxels described by a JSON sidecar (what `tandem generate X.json` writes):
//   {"dims": [nx, ny, nz], "dtype": "int16", "spacing": [sx, sy, sz], "origin": [..],
//    "directions": [[x axis], [y axis], [z axis]] (optional, orthonormal; default identity),
//    "space": "LPS" or "RAS" (optional: the patient frame of origin and directions),
//    "byte_order": "little", "raw_file": "NAME.raw", "raw_bytes": N,
//    "suggested_isovalues": [..], "description": ".."}
// Only dims and dtype are required. raw_file is relative to the sidecar's folder and
// defaults to the sidecar's stem + ".raw". Voxels are x fastest, then y, then z.
// WriteRawJson (below) writes the same pair, with value_range and sha256 added.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <string>
#include <type_traits>

#include "absl/strings/str_cat.h"
#include "nlohmann/json.hpp"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"

namespace tandem::io::internal {
namespace {

using nlohmann::json;

absl::Status SidecarError(const std::string& path, absl::string_view what) {
  return absl::InvalidArgumentError(absl::StrCat(path, ": ", what));
}

// Reads a small text file whole (sidecars are a few hundred bytes; the cap keeps a raw
// volume mistakenly named .json from being slurped).
absl::StatusOr<std::string> ReadSmallFile(const std::string& path) {
  TANDEM_ASSIGN_OR_RETURN(uint64_t size, NonEmptyFileSize(path));
  constexpr uint64_t kMaxSidecar = 1 << 20;
  if (size > kMaxSidecar) {
    return SidecarError(
        path, absl::StrCat("not a JSON sidecar (", size, " bytes; sidecars are under 1 MiB)"));
  }
  return ReadHead(path, size, kMaxSidecar);
}

// Reads a 3-vector of numbers at key into *out; absent keys keep the default.
absl::Status ReadVec3(const std::string& path, const json& j, const char* key,
                      std::array<double, 3>* out) {
  if (!j.contains(key)) return absl::OkStatus();
  const json& v = j[key];
  if (!v.is_array() || v.size() != 3) {
    return SidecarError(path, absl::StrCat("\"", key, "\" must be an array of 3 numbers"));
  }
  for (int a = 0; a < 3; ++a) {
    if (!v[a].is_number()) {
      return SidecarError(path, absl::StrCat("\"", key, "\"[", a, "] is not a number"));
    }
    (*out)[a] = v[a].get<double>();
  }
  return absl::OkStatus();
}

absl::StatusOr<StreamVolumeSpec> ParseSidecar(const std::string& path, const json& j) {
  StreamVolumeSpec spec;
  spec.path = path;
  VolumeInfo& info = spec.info;
  if (!j.is_object()) return SidecarError(path, "JSON sidecar must be an object");

  if (!j.contains("dims")) return SidecarError(path, "missing \"dims\": [nx, ny, nz]");
  const json& dims = j["dims"];
  if (!dims.is_array() || dims.size() != 3) {
    return SidecarError(path, "\"dims\" must be an array of 3 integers [nx, ny, nz]");
  }
  int64_t* axes[3] = {&info.nx, &info.ny, &info.nz};
  for (int a = 0; a < 3; ++a) {
    if (!dims[a].is_number_integer()) {
      return SidecarError(path, absl::StrCat("\"dims\"[", a, "] is not an integer"));
    }
    *axes[a] = dims[a].get<int64_t>();
  }

  if (!j.contains("dtype") || !j["dtype"].is_string()) {
    return SidecarError(path, absl::StrCat("missing \"dtype\" (", DTypeNames(), ")"));
  }
  absl::StatusOr<DType> dtype = ParseDType(j["dtype"].get<std::string>());
  if (!dtype.ok()) return SidecarError(path, dtype.status().message());
  info.dtype = *dtype;

  TANDEM_RETURN_IF_ERROR(ReadVec3(path, j, "spacing", &info.spacing));
  info.spacing_known = j.contains("spacing");
  TANDEM_RETURN_IF_ERROR(ReadVec3(path, j, "origin", &info.origin));
  if (j.contains("directions")) {  // optional: [[x axis], [y axis], [z axis]] in the world
    info.frame = "sidecar origin, spacing and directions";
    const json& d = j["directions"];
    if (!d.is_array() || d.size() != 3) {
      return SidecarError(path, "\"directions\" must be 3 arrays of 3 numbers (the world "
                                "unit vectors of the x, y and z axes)");
    }
    for (int a = 0; a < 3; ++a) {
      json axis = json::object({{"v", d[a]}});
      if (absl::Status st = ReadVec3(path, axis, "v", &info.directions[a]); !st.ok()) {
        return SidecarError(path, absl::StrCat("\"directions\"[", a,
                                               "] must be an array of 3 numbers"));
      }
    }
  }
  if (j.contains("space")) {  // optional: the patient frame the geometry is in
    const json& sp = j["space"];
    absl::StatusOr<Space> space =
        sp.is_string() ? ParseSpace(sp.get<std::string>()) : absl::InvalidArgumentError("");
    if (!space.ok() || (*space != Space::kLPS && *space != Space::kRAS)) {
      return SidecarError(path, "\"space\" must be \"LPS\" or \"RAS\" (the patient frame of "
                                "origin and directions)");
    }
    info.space = *space;
    info.frame = absl::StrCat("sidecar origin, spacing and directions in ", SpaceName(*space));
  }
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) {
    return SidecarError(path, st.message());
  }
  if (info.nz == 0) return SidecarError(path, "\"dims\"[2] (nz) must be at least 2");

  if (j.contains("byte_order")) {
    const json& bo = j["byte_order"];
    if (!bo.is_string() || (bo != "little" && bo != "big")) {
      return SidecarError(path, "\"byte_order\" must be \"little\" or \"big\"");
    }
    spec.big_endian = bo == "big";
  }

  const std::filesystem::path json_path(path);
  std::filesystem::path raw = json_path.stem().string() + ".raw";
  if (j.contains("raw_file")) {
    if (!j["raw_file"].is_string() || j["raw_file"].get<std::string>().empty()) {
      return SidecarError(path, "\"raw_file\" must be a non-empty file name");
    }
    raw = j["raw_file"].get<std::string>();
  }
  spec.data_path = raw.is_absolute() ? raw.string() : (json_path.parent_path() / raw).string();

  const uint64_t need = VolumeBytes(info);
  if (j.contains("raw_bytes")) {
    const json& rb = j["raw_bytes"];
    if (!rb.is_number_integer() || rb.get<int64_t>() < 0) {
      return SidecarError(path, "\"raw_bytes\" must be a non-negative integer");
    }
    if (rb.get<uint64_t>() != need) {
      return SidecarError(path, absl::StrCat("size mismatch: \"raw_bytes\" is ", rb.get<uint64_t>(),
                                             " but dims ", DescribeGrid(info), " need ", need));
    }
  }

  if (j.contains("suggested_isovalues")) {
    const json& iso = j["suggested_isovalues"];
    if (!iso.is_array()) return SidecarError(path, "\"suggested_isovalues\" must be an array");
    for (const json& v : iso) {
      if (!v.is_number()) {
        return SidecarError(path, "\"suggested_isovalues\" must hold only numbers");
      }
      info.suggested_isovalues.push_back(v.get<double>());
    }
  }
  if (j.contains("description") && j["description"].is_string()) {
    info.description = j["description"].get<std::string>();
  }
  return spec;
}

}  // namespace

absl::StatusOr<std::unique_ptr<SliceSource>> OpenRawVolume(const std::string& json_path) {
  TANDEM_ASSIGN_OR_RETURN(std::string text, ReadSmallFile(json_path));
  const json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) return SidecarError(json_path, "invalid JSON in sidecar");
  absl::StatusOr<StreamVolumeSpec> spec;
  try {  // the checks above should make get<> safe; never let a json exception escape
    spec = ParseSidecar(json_path, j);
  } catch (const json::exception& e) {
    return SidecarError(json_path, absl::StrCat("bad sidecar: ", e.what()));
  }
  if (!spec.ok()) return spec.status();
  return OpenStreamVolume(*std::move(spec));
}

// ---------------------------------------------------------------------------------------
// Writer: raw voxels in STEM.raw beside the JSON sidecar.

namespace {

// The smallest and largest of integer voxels, exactly: signed types in int64, unsigned in
// uint64.
struct IntegerRange {
  bool any = false;
  int64_t lo = 0, hi = 0;
  uint64_t ulo = 0, uhi = 0;

  void Add(DType t, const uint8_t* src, size_t n) {
    switch (t) {
      case DType::kUInt8:
        return Typed<uint8_t>(src, n);
      case DType::kInt8:
        return Typed<int8_t>(src, n);
      case DType::kUInt16:
        return Typed<uint16_t>(src, n);
      case DType::kInt16:
        return Typed<int16_t>(src, n);
      case DType::kUInt32:
        return Typed<uint32_t>(src, n);
      case DType::kInt32:
        return Typed<int32_t>(src, n);
      case DType::kUInt64:
        return Typed<uint64_t>(src, n);
      case DType::kInt64:
        return Typed<int64_t>(src, n);
      case DType::kFloat32:
        return;
    }
  }
  template <typename J>
  J Json(DType t) const {
    if (IsSignedDType(t)) return J::array({lo, hi});
    return J::array({ulo, uhi});
  }

 private:
  template <typename T>
  void Typed(const uint8_t* src, size_t n) {
    for (size_t i = 0; i < n; ++i) {
      T v;
      std::memcpy(&v, src + i * sizeof(T), sizeof(T));
      if constexpr (std::is_signed_v<T>) {
        lo = any ? std::min<int64_t>(lo, v) : v;
        hi = any ? std::max<int64_t>(hi, v) : v;
      } else {
        ulo = any ? std::min<uint64_t>(ulo, v) : v;
        uhi = any ? std::max<uint64_t>(uhi, v) : v;
      }
      any = true;
    }
  }
};

}  // namespace

absl::Status WriteRawJson(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                          const VolumeWriteOptions& opts) {
  const std::filesystem::path raw_path = SiblingPath(path, ".raw");
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<ByteWriter> w,
                          ByteWriter::Open(raw_path.string(), false));
  ValueRange range;  // of every slice (RangeOf: NaNs skipped), for the sidecar's "value_range"
  IntegerRange exact;  // the same for integers, exactly (a float rounds ids past 2^24)
  Sha256 sha;
  absl::Status st = StreamSlices(
      path, info, slice_fn, opts.big_endian, w.get(),
      [&](const std::vector<uint8_t>& s) {
        if (IsIntegerDType(info.dtype)) {
          exact.Add(info.dtype, s.data(), static_cast<size_t>(info.slice_voxels()));
        } else {
          range.Merge(RangeOf(info.dtype, s.data(), info.slice_voxels()));
        }
      },
      &sha);
  if (st.ok()) st = w->Close();
  if (!st.ok()) return st;

  using ojson = nlohmann::ordered_json;
  ojson j;
  j["dims"] = {info.nx, info.ny, info.nz};
  j["dtype"] = std::string(DTypeName(info.dtype));
  j["spacing"] = {info.spacing[0], info.spacing[1], info.spacing[2]};
  j["origin"] = {info.origin[0], info.origin[1], info.origin[2]};
  if (!info.axis_aligned()) {
    const auto& d = info.directions;
    j["directions"] = {{d[0][0], d[0][1], d[0][2]}, {d[1][0], d[1][1], d[1][2]},
                       {d[2][0], d[2][1], d[2][2]}};
  }
  if (info.space == Space::kLPS || info.space == Space::kRAS) {
    j["space"] = std::string(SpaceName(info.space));
  }
  j["byte_order"] = opts.big_endian ? "big" : "little";
  j["layout"] = "x fastest, then y, then z: offset=((k*ny+j)*nx+i)*sizeof(dtype)";
  j["source"] = opts.source;
  j["license"] = opts.license;
  j["suggested_isovalues"] = info.suggested_isovalues;
  j["description"] = info.description;
  j["modality"] = opts.modality;
  if (IsIntegerDType(info.dtype) && exact.any) {
    j["value_range"] = exact.Json<ojson>(info.dtype);
  } else if (!IsIntegerDType(info.dtype) && !range.empty()) {
    j["value_range"] = {static_cast<double>(range.lo), static_cast<double>(range.hi)};
  } else {
    j["value_range"] = nullptr;
  }
  j["raw_file"] = raw_path.filename().string();
  j["raw_bytes"] = VolumeBytes(info);
  j["sha256"] = sha.HexDigest();
  // replace: invalid UTF-8 in a description must not throw.
  return WriteText(path, j.dump(1, ' ', false, ojson::error_handler_t::replace));
}

}  // namespace tandem::io::internal
