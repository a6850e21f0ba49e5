// NRRD reader: attached (.nrrd, header then a blank line then data) and detached (.nhdr
// with "data file:"). Supported: dimension 3; the 8-, 16-, 32- and 64-bit integer types and
// float, with their aliases; encodings raw and gzip; endian little/big; "spacings" or "space
// directions" (lengths = spacing, unit vectors = the grid axes in the file's space: rotations and
// flips are applied, sheared grids refused); "space origin"; "byte skip" >= 0 (and -1 for raw
// data); "content" becomes the description and a "suggested_isovalues:=v1 v2" key/value pair is
// read back. WriteNrrd (below) writes both forms, raw or gzip, in either byte order.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"

namespace tandem::io::internal {
namespace {

absl::Status NrrdError(const std::string& path, absl::string_view what) {
  return absl::InvalidArgumentError(absl::StrCat(path, ": ", what));
}

struct NrrdHeader {
  std::vector<std::pair<std::string, std::string>> fields;  // lower-cased name, value
  std::vector<std::pair<std::string, std::string>> key_values;
  uint64_t data_offset = 0;  // first byte after the blank line (attached data)
  bool has_blank_line = false;

  const std::string* Find(absl::string_view name) const {
    for (const auto& [k, v] : fields) {
      if (k == name) return &v;
    }
    return nullptr;
  }
  // NRRD allows some fields with or without the inner space ("data file" / "datafile").
  const std::string* Find(absl::string_view a, absl::string_view b) const {
    const std::string* v = Find(a);
    return v != nullptr ? v : Find(b);
  }
};

// The patient frame a "space" field names (NRRD's long names or their initials); any other
// (scanner-xyz, 3D-right-handed, left-anterior-superior, ...) is a frame of the file's own.
Space NrrdSpace(const std::string& space) {
  const std::string s = absl::AsciiStrToLower(absl::StripAsciiWhitespace(space));
  if (s == "left-posterior-superior" || s == "lps") return Space::kLPS;
  if (s == "right-anterior-superior" || s == "ras") return Space::kRAS;
  return Space::kGrid;
}

absl::StatusOr<NrrdHeader> ReadHeader(const std::string& path, uint64_t file_size) {
  // Headers are small text; 1 MiB is far more than any real one and bounds the read.
  constexpr uint64_t kMaxHeader = 1 << 20;
  TANDEM_ASSIGN_OR_RETURN(std::string read, ReadHead(path, file_size, kMaxHeader));
  const std::string& text = read;

  if (!text.starts_with("NRRD000") || text.size() < 8 || text[7] < '1' || text[7] > '5') {
    return NrrdError(path, "not a NRRD file (it must start with \"NRRD000X\")");
  }
  NrrdHeader h;
  size_t pos = 0;
  bool first = true;
  while (pos < text.size()) {
    size_t eol = text.find('\n', pos);
    if (eol == std::string::npos) {
      if (text.size() == kMaxHeader && file_size > kMaxHeader) {
        return NrrdError(path, "header longer than 1 MiB or not terminated by a blank line");
      }
      eol = text.size();
    }
    absl::string_view line(text.data() + pos, eol - pos);
    pos = eol + 1;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (first) {  // the magic line
      first = false;
      continue;
    }
    if (line.empty()) {
      h.has_blank_line = true;
      h.data_offset = std::min<uint64_t>(pos, text.size());
      break;
    }
    if (line.front() == '#') continue;
    const size_t kv = line.find(":=");
    const size_t field = line.find(": ");
    if (kv != absl::string_view::npos && (field == absl::string_view::npos || kv < field)) {
      h.key_values.emplace_back(std::string(line.substr(0, kv)), std::string(line.substr(kv + 2)));
    } else if (field != absl::string_view::npos) {
      h.fields.emplace_back(
          absl::AsciiStrToLower(absl::StripAsciiWhitespace(line.substr(0, field))),
          std::string(absl::StripAsciiWhitespace(line.substr(field + 2))));
    } else {
      return NrrdError(path, absl::StrCat("malformed header line \"", line, "\""));
    }
  }
  return h;
}

// The NRRD type names of each DType (the standard's synonyms, lower case), the first the
// one written.
struct NrrdType {
  DType dtype;
  std::vector<absl::string_view> names;
};
const std::vector<NrrdType>& NrrdTypes() {
  static const auto* types = new std::vector<NrrdType>{
      {DType::kUInt8, {"uint8", "uchar", "unsigned char", "uint8_t"}},
      {DType::kInt8, {"int8", "signed char", "int8_t"}},
      {DType::kUInt16, {"uint16", "ushort", "unsigned short", "unsigned short int", "uint16_t"}},
      {DType::kInt16,
       {"int16", "short", "short int", "signed short", "signed short int", "int16_t"}},
      {DType::kUInt32, {"uint32", "uint", "unsigned int", "uint32_t"}},
      {DType::kInt32, {"int32", "int", "signed int", "int32_t"}},
      {DType::kUInt64,
       {"uint64", "ulonglong", "unsigned long long", "unsigned long long int", "uint64_t"}},
      {DType::kInt64,
       {"int64", "longlong", "long long", "long long int", "signed long long",
        "signed long long int", "int64_t"}},
      {DType::kFloat32, {"float"}},
  };
  return *types;
}

absl::StatusOr<DType> ParseNrrdType(const std::string& path, const std::string& name) {
  const std::string t = absl::AsciiStrToLower(name);
  std::string supported;
  for (const NrrdType& type : NrrdTypes()) {
    for (absl::string_view n : type.names) {
      if (t == n) return type.dtype;
    }
    absl::StrAppend(&supported, supported.empty() ? "" : ", ", type.names[0]);
  }
  return NrrdError(path,
                   absl::StrCat("unsupported type '", name, "' (supported: ", supported, ")"));
}

// Parses "(a,b,c) (d,e,f) ..." into vectors of 3.
absl::StatusOr<std::vector<std::array<double, 3>>> ParseVectors(const std::string& path,
                                                                absl::string_view field,
                                                                absl::string_view text) {
  std::vector<std::array<double, 3>> vecs;
  size_t pos = 0;
  while (true) {
    const size_t open = text.find_first_not_of(" \t", pos);
    if (open == absl::string_view::npos) break;
    if (text[open] != '(') {
      return NrrdError(path, absl::StrCat("\"", field, "\": expected \"(x,y,z)\" vectors, got \"",
                                          text, "\" (non-spatial axes are not supported)"));
    }
    const size_t close = text.find(')', open);
    if (close == absl::string_view::npos) {
      return NrrdError(path, absl::StrCat("\"", field, "\": missing ')' in \"", text, "\""));
    }
    std::vector<absl::string_view> parts =
        absl::StrSplit(text.substr(open + 1, close - open - 1), ',');
    std::array<double, 3> v{};
    if (parts.size() != 3) {
      return NrrdError(
          path, absl::StrCat("\"", field, "\": vectors must have 3 components (\"", text, "\")"));
    }
    for (int a = 0; a < 3; ++a) {
      if (!absl::SimpleAtod(absl::StripAsciiWhitespace(parts[a]), &v[a])) {
        return NrrdError(path, absl::StrCat("\"", field, "\": bad number \"", parts[a], "\""));
      }
    }
    vecs.push_back(v);
    pos = close + 1;
  }
  return vecs;
}

absl::StatusOr<StreamVolumeSpec> ParseNrrd(const std::string& path, const NrrdHeader& h) {
  StreamVolumeSpec spec;
  spec.path = path;
  spec.data_path = path;
  VolumeInfo& info = spec.info;

  const std::string* type = h.Find("type");
  if (type == nullptr) return NrrdError(path, "missing \"type\" field");
  TANDEM_ASSIGN_OR_RETURN(DType dtype, ParseNrrdType(path, *type));
  info.dtype = dtype;

  const std::string* dimension = h.Find("dimension");
  int dim = 0;
  if (dimension == nullptr || !absl::SimpleAtoi(*dimension, &dim)) {
    return NrrdError(path, "missing or bad \"dimension\" field");
  }
  if (dim != 3) {
    return NrrdError(path, absl::StrCat("dimension is ", dim, "; only 3-D volumes are supported"));
  }
  const std::string* sizes = h.Find("sizes");
  if (sizes == nullptr) return NrrdError(path, "missing \"sizes\" field");
  int64_t n[3];
  TANDEM_RETURN_IF_ERROR(ParseNumbers(path, "sizes", *sizes, 3, n));
  info.nx = n[0];
  info.ny = n[1];
  info.nz = n[2];

  if (const std::string* dirs = h.Find("space directions"); dirs != nullptr) {
    TANDEM_ASSIGN_OR_RETURN(auto v, ParseVectors(path, "space directions", *dirs));
    if (v.size() != 3) return NrrdError(path, "\"space directions\" needs 3 vectors");
    // Each vector is one voxel step in the world: its length is the spacing, its direction
    // the axis (rotations and flips applied; ValidateVolumeInfo refuses shear).
    for (int a = 0; a < 3; ++a) {
      const auto& d = v[a];
      const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      if (!(len > 0) || !std::isfinite(len)) {
        return NrrdError(path, absl::StrCat("\"space directions\" vector ", a, " has length ",
                                            len));
      }
      info.spacing[a] = len;
      for (int b = 0; b < 3; ++b) info.directions[a][b] = d[b] / len + 0.0;
    }
  } else if (const std::string* sp = h.Find("spacings"); sp != nullptr) {
    TANDEM_RETURN_IF_ERROR(ParseNumbers(path, "spacings", *sp, 3, info.spacing.data()));
    for (double& s : info.spacing) s = std::abs(s);
  } else {
    info.spacing_known = false;
  }
  if (const std::string* space = h.Find("space"); space != nullptr) {
    info.frame = absl::StrCat("NRRD space ", *space);
    info.space = NrrdSpace(*space);
  } else if (h.Find("space directions") != nullptr) {
    info.frame = "NRRD space directions";
  }
  if (const std::string* org = h.Find("space origin"); org != nullptr) {
    TANDEM_ASSIGN_OR_RETURN(auto v, ParseVectors(path, "space origin", *org));
    if (v.size() != 1) return NrrdError(path, "\"space origin\" must be one (x,y,z) vector");
    info.origin = v[0];
  }
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) return NrrdError(path, st.message());

  const std::string* encoding = h.Find("encoding");
  if (encoding == nullptr) return NrrdError(path, "missing \"encoding\" field");
  const std::string enc = absl::AsciiStrToLower(*encoding);
  if (enc == "gzip" || enc == "gz") {
    spec.gzip = true;
  } else if (enc != "raw") {
    return NrrdError(path,
                     absl::StrCat("unsupported encoding '", *encoding, "' (supported: raw, gzip)"));
  }
  if (const std::string* endian = h.Find("endian"); endian != nullptr) {
    const std::string e = absl::AsciiStrToLower(*endian);
    if (e != "little" && e != "big") {
      return NrrdError(path, absl::StrCat("bad endian '", *endian, "' (little or big)"));
    }
    spec.big_endian = e == "big";
  }
  if (const std::string* ls = h.Find("line skip", "lineskip"); ls != nullptr && *ls != "0") {
    return NrrdError(path, "\"line skip\" is not supported (only 0)");
  }
  int64_t byte_skip = 0;
  if (const std::string* bs = h.Find("byte skip", "byteskip"); bs != nullptr) {
    if (!absl::SimpleAtoi(*bs, &byte_skip) || byte_skip < -1 || (byte_skip == -1 && spec.gzip)) {
      return NrrdError(path, absl::StrCat("unsupported \"byte skip: ", *bs,
                                          "\" (>= 0, or -1 with raw encoding)"));
    }
  }

  if (const std::string* df = h.Find("data file", "datafile"); df != nullptr) {
    if (*df == "LIST" || df->find(' ') != std::string::npos || df->find('%') != std::string::npos) {
      return NrrdError(
          path, absl::StrCat("\"data file: ", *df, "\": only a single data file is supported"));
    }
    const std::filesystem::path p(*df);
    spec.data_path =
        p.is_absolute() ? p.string() : (std::filesystem::path(path).parent_path() / p).string();
    spec.data_offset = 0;
  } else {
    if (VolumeExtension(path) == ".nhdr") {
      return NrrdError(path, "detached header has no \"data file\" field");
    }
    if (!h.has_blank_line) return NrrdError(path, "no data after the header (missing blank line)");
    spec.data_offset = h.data_offset;
  }
  if (byte_skip == -1) {
    // Data is the last bytes of the file.
    TANDEM_ASSIGN_OR_RETURN(uint64_t size, FileSize(spec.data_path));
    const uint64_t need = VolumeBytes(info);
    if (size < spec.data_offset + need) {
      return absl::DataLossError(absl::StrCat(
          path, ": truncated: expected ", need, " bytes of voxel data (", DescribeGrid(info),
          "), file has ", size - std::min(size, spec.data_offset)));
    }
    spec.data_offset = size - need;
  } else if (spec.gzip) {
    spec.skip_bytes = static_cast<uint64_t>(byte_skip);  // counts decompressed bytes
  } else {
    spec.data_offset += static_cast<uint64_t>(byte_skip);
  }

  if (const std::string* content = h.Find("content"); content != nullptr) {
    info.description = *content;
  }
  for (const auto& [k, v] : h.key_values) {
    if (k != "suggested_isovalues") continue;
    for (absl::string_view part : absl::StrSplit(v, absl::ByAnyChar(" \t,"), absl::SkipEmpty())) {
      double iso;
      if (absl::SimpleAtod(part, &iso)) info.suggested_isovalues.push_back(iso);
    }
  }
  return spec;
}

}  // namespace

absl::StatusOr<std::unique_ptr<SliceSource>> OpenNrrdVolume(const std::string& path) {
  TANDEM_ASSIGN_OR_RETURN(uint64_t size, NonEmptyFileSize(path));
  TANDEM_ASSIGN_OR_RETURN(NrrdHeader header, ReadHeader(path, size));
  TANDEM_ASSIGN_OR_RETURN(StreamVolumeSpec spec, ParseNrrd(path, header));
  return OpenStreamVolume(std::move(spec));
}

// ---------------------------------------------------------------------------------------
// Writer.

namespace {

std::string OneLine(absl::string_view s) {
  return absl::StrReplaceAll(s, {{"\r", " "}, {"\n", " "}});
}

}  // namespace

absl::Status WriteNrrd(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                       const VolumeWriteOptions& opts) {
  const bool detached = VolumeExtension(path) == ".nhdr";
  absl::string_view type = "float";
  for (const NrrdType& t : NrrdTypes()) {
    if (t.dtype == info.dtype) type = t.names[0];
  }
  const auto& s = info.spacing;
  const auto& o = info.origin;
  std::string dirs;  // one voxel step per axis, in the world
  for (int a = 0; a < 3; ++a) {
    const auto& d = info.directions[a];
    absl::StrAppend(&dirs, a ? " (" : "(", FormatDouble(d[0] * s[a] + 0.0), ",",
                    FormatDouble(d[1] * s[a] + 0.0), ",", FormatDouble(d[2] * s[a] + 0.0), ")");
  }
  std::string header = absl::StrCat(
      "NRRD0004\n# written by tandem\ntype: ", type, "\ndimension: 3\nsizes: ", info.nx, " ",
      info.ny, " ", info.nz, "\n",
      info.space == Space::kLPS   ? "space: left-posterior-superior"
      : info.space == Space::kRAS ? "space: right-anterior-superior"
                                  : "space dimension: 3",
      "\nspace directions: ", dirs,
      "\nspace origin: (",
      FormatDouble(o[0]), ",", FormatDouble(o[1]), ",", FormatDouble(o[2]),
      ")\nkinds: domain domain domain\nendian: ", opts.big_endian ? "big" : "little",
      "\nencoding: ", opts.gzip ? "gzip" : "raw", "\n");
  if (!info.description.empty())
    absl::StrAppend(&header, "content: ", OneLine(info.description), "\n");
  if (!info.suggested_isovalues.empty()) {
    absl::StrAppend(&header, "suggested_isovalues:=");
    for (size_t i = 0; i < info.suggested_isovalues.size(); ++i) {
      absl::StrAppend(&header, i ? " " : "", FormatDouble(info.suggested_isovalues[i]));
    }
    absl::StrAppend(&header, "\n");
  }
  std::string data_path = path;
  if (detached) {
    data_path = SiblingPath(path, opts.gzip ? ".raw.gz" : ".raw").string();
    absl::StrAppend(&header, "data file: ", std::filesystem::path(data_path).filename().string(),
                    "\n");
  } else {
    absl::StrAppend(&header, "\n");  // the blank line that ends an attached header
  }
  return WriteHeaderThenVoxels(path, header, data_path, info, slice_fn, opts);
}

}  // namespace tandem::io::internal
