// ITK MetaImage reader and writer: .mha (header and data in one file) and .mhd (header,
// data in ElementDataFile), read like NRRD through the shared contiguous-data source (one
// slice at a time, mapped when uncompressed and in host byte order).
// Supported: ObjectType = Image, NDims = 3, one channel, binary data; ElementType MET_UCHAR,
// MET_CHAR, MET_USHORT, MET_SHORT, MET_UINT, MET_INT, MET_ULONG, MET_LONG (4 bytes, as
// MetaIO sizes them), MET_ULONG_LONG, MET_LONG_LONG, MET_FLOAT (others are refused:
// tandem's volumes hold no other type); ElementSpacing (else ElementSize); Offset / Position /
// Origin; TransformMatrix / Rotation / Orientation, the world directions of the grid's x, y and z
// axes one after the other, as ITK writes them (its direction matrix column by column); the world
// is ITK's, LPS, whatever AnatomicalOrientation says (reported in the description); byte order
// (ElementByteOrderMSB / BinaryDataByteOrderMSB); CompressedData (a zlib stream, optionally
// CompressedDataSize bytes long); HeaderSize (bytes before the data in the data file, -1 =
// the data ends the file); ElementDataFile LOCAL or one file (relative to the header).
// tandem's own SuggestedIsovalues field (MetaIO keeps unknown fields) carries the volume's
// suggested iso-values, as NRRD's suggested_isovalues key does.
#include <zlib.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"

namespace tandem::io::internal {
namespace {

absl::Status MetaError(const std::string& path, absl::string_view what) {
  return absl::InvalidArgumentError(absl::StrCat(path, ": ", what));
}

struct MetaHeader {
  std::vector<std::pair<std::string, std::string>> fields;  // lower-cased key, value
  uint64_t data_offset = 0;  // the byte after the ElementDataFile line

  const std::string* Find(std::initializer_list<absl::string_view> keys) const {
    for (absl::string_view key : keys) {
      for (const auto& [k, v] : fields) {
        if (k == key) return &v;
      }
    }
    return nullptr;
  }
};

// "Key = Value" lines up to ElementDataFile, which ends the header.
absl::StatusOr<MetaHeader> ReadHeader(const std::string& path, uint64_t file_size) {
  constexpr uint64_t kMaxHeader = 1 << 20;  // real headers are a few hundred bytes
  TANDEM_ASSIGN_OR_RETURN(std::string read, ReadHead(path, file_size, kMaxHeader));
  const std::string& text = read;
  MetaHeader h;
  size_t pos = 0;
  while (pos < text.size()) {
    size_t eol = text.find('\n', pos);
    const bool last = eol == std::string::npos;
    if (last) eol = text.size();
    absl::string_view line(text.data() + pos, eol - pos);
    pos = last ? eol : eol + 1;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    if (absl::StripAsciiWhitespace(line).empty()) continue;
    const size_t eq = line.find('=');
    if (eq == absl::string_view::npos) {
      return MetaError(path, absl::StrCat("not a MetaImage header line: \"", line.substr(0, 80),
                                          "\" (expected Key = Value)"));
    }
    std::string key = absl::AsciiStrToLower(absl::StripAsciiWhitespace(line.substr(0, eq)));
    std::string value(absl::StripAsciiWhitespace(line.substr(eq + 1)));
    const bool data_file = key == "elementdatafile";
    h.fields.emplace_back(std::move(key), std::move(value));
    if (data_file) {
      h.data_offset = pos;
      return h;
    }
  }
  if (file_size > kMaxHeader) {
    return MetaError(path, "no ElementDataFile line in the first 1 MiB (not a MetaImage?)");
  }
  return MetaError(path, "no ElementDataFile line (it ends a MetaImage header)");
}

// True, False (MetaIO writes these; 1 / 0 read too).
absl::StatusOr<bool> Flag(const std::string& path, absl::string_view key, const std::string& v) {
  const std::string s = absl::AsciiStrToLower(v);
  if (s == "true" || s == "1") return true;
  if (s == "false" || s == "0") return false;
  return MetaError(path, absl::StrCat(key, " = ", v, ": expected True or False"));
}

// MetaIO's ElementType names of each DType, the first the one written (MET_LONG and
// MET_ULONG are 4 bytes in MetaIO's own size table).
struct MetaType {
  DType dtype;
  std::vector<absl::string_view> names;
};
const std::vector<MetaType>& MetaTypes() {
  static const auto* types = new std::vector<MetaType>{
      {DType::kUInt8, {"MET_UCHAR"}},
      {DType::kInt8, {"MET_CHAR"}},
      {DType::kUInt16, {"MET_USHORT"}},
      {DType::kInt16, {"MET_SHORT"}},
      {DType::kUInt32, {"MET_UINT", "MET_ULONG"}},
      {DType::kInt32, {"MET_INT", "MET_LONG"}},
      {DType::kUInt64, {"MET_ULONG_LONG"}},
      {DType::kInt64, {"MET_LONG_LONG"}},
      {DType::kFloat32, {"MET_FLOAT"}},
  };
  return *types;
}

absl::StatusOr<DType> ElementType(const std::string& path, const std::string& name) {
  std::string supported;
  for (const MetaType& t : MetaTypes()) {
    for (absl::string_view n : t.names) {
      if (name == n) return t.dtype;
      absl::StrAppend(&supported, supported.empty() ? "" : ", ", n);
    }
  }
  return MetaError(path, absl::StrCat("ElementType ", name, " is not supported (", supported,
                                      ": the types tandem's volumes hold)"));
}

absl::StatusOr<StreamVolumeSpec> ParseHeader(const std::string& path, const MetaHeader& h) {
  StreamVolumeSpec spec;
  spec.path = path;
  spec.data_path = path;
  VolumeInfo& info = spec.info;
  if (const std::string* type = h.Find({"objecttype"}); type != nullptr && *type != "Image") {
    return MetaError(path, absl::StrCat("ObjectType = ", *type, ": only Image is supported"));
  }
  const std::string* ndims = h.Find({"ndims"});
  int nd = 0;
  if (ndims == nullptr || !absl::SimpleAtoi(*ndims, &nd)) {
    return MetaError(path, "missing or bad NDims");
  }
  if (nd != 3) return MetaError(path, absl::StrCat("NDims = ", nd, ": only 3-D images are read"));
  const std::string* dims = h.Find({"dimsize"});
  if (dims == nullptr) return MetaError(path, "missing DimSize");
  int64_t n[3];
  TANDEM_RETURN_IF_ERROR(ParseNumbers(path, "DimSize", *dims, 3, n));
  info.nx = n[0];
  info.ny = n[1];
  info.nz = n[2];
  const std::string* type = h.Find({"elementtype"});
  if (type == nullptr) return MetaError(path, "missing ElementType");
  TANDEM_ASSIGN_OR_RETURN(DType dtype, ElementType(path, *type));
  info.dtype = dtype;
  if (const std::string* ch = h.Find({"elementnumberofchannels"}); ch != nullptr && *ch != "1") {
    return MetaError(path, absl::StrCat("ElementNumberOfChannels = ", *ch,
                                        ": only one channel (greyscale) is read"));
  }
  if (const std::string* binary = h.Find({"binarydata"}); binary != nullptr) {
    TANDEM_ASSIGN_OR_RETURN(bool b, Flag(path, "BinaryData", *binary));
    if (!b) return MetaError(path, "BinaryData = False (text voxels) is not supported");
  }
  if (const std::string* sp = h.Find({"elementspacing", "elementsize"}); sp != nullptr) {
    if (absl::Status st = ParseNumbers(path, "ElementSpacing", *sp, 3, info.spacing.data());
        !st.ok()) {
      return st;
    }
  } else {
    info.spacing_known = false;
  }
  if (const std::string* o = h.Find({"offset", "position", "origin"}); o != nullptr) {
    if (absl::Status st = ParseNumbers(path, "Offset", *o, 3, info.origin.data()); !st.ok())
      return st;
  }
  if (const std::string* m = h.Find({"transformmatrix", "rotation", "orientation"}); m != nullptr) {
    double d[9];
    TANDEM_RETURN_IF_ERROR(ParseNumbers(path, "TransformMatrix", *m, 9, d));
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) info.directions[a][b] = d[3 * a + b] + 0.0;
    }
  }
  info.frame = "MetaImage physical space (ITK's LPS)";
  info.space = Space::kLPS;
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) return MetaError(path, st.message());
  if (const std::string* o = h.Find({"anatomicalorientation"}); o != nullptr) {
    info.description = absl::StrCat("MetaImage, AnatomicalOrientation ", *o);
  }
  if (const std::string* isos = h.Find({"suggestedisovalues"}); isos != nullptr) {
    for (absl::string_view part :
         absl::StrSplit(*isos, absl::ByAnyChar(" \t"), absl::SkipEmpty())) {
      double iso;
      if (absl::SimpleAtod(part, &iso) && std::isfinite(iso))
        info.suggested_isovalues.push_back(iso);
    }
  }
  if (const std::string* msb = h.Find({"elementbyteordermsb", "binarydatabyteordermsb"});
      msb != nullptr) {
    TANDEM_ASSIGN_OR_RETURN(bool b, Flag(path, "ElementByteOrderMSB", *msb));
    spec.big_endian = b;
  }
  if (const std::string* c = h.Find({"compresseddata"}); c != nullptr) {
    TANDEM_ASSIGN_OR_RETURN(bool b, Flag(path, "CompressedData", *c));
    spec.gzip = spec.zlib = b;
  }
  int64_t header_size = 0;
  if (const std::string* hs = h.Find({"headersize"}); hs != nullptr) {
    if (!absl::SimpleAtoi(*hs, &header_size) || header_size < -1 ||
        (header_size == -1 && spec.gzip)) {
      return MetaError(path, absl::StrCat("HeaderSize = ", *hs,
                                          " (bytes before the data, or -1 for uncompressed "
                                          "data at the end of the file)"));
    }
  }
  const std::string& data_file = *h.Find({"elementdatafile"});
  if (data_file == "LOCAL") {
    spec.data_offset = h.data_offset;
  } else if (data_file.empty() || absl::StartsWith(data_file, "LIST") ||
             absl::StrContains(data_file, "%")) {
    return MetaError(path, absl::StrCat("ElementDataFile = ", data_file,
                                        ": only LOCAL or one data file is supported"));
  } else {
    const std::filesystem::path p(data_file);
    spec.data_path =
        p.is_absolute() ? p.string() : (std::filesystem::path(path).parent_path() / p).string();
  }
  if (header_size > 0) spec.data_offset = static_cast<uint64_t>(header_size);
  if (header_size == -1) {
    TANDEM_ASSIGN_OR_RETURN(uint64_t size, FileSize(spec.data_path));
    const uint64_t need = VolumeBytes(info);
    if (size < need) {
      return absl::DataLossError(absl::StrCat(path, ": truncated: expected ", need,
                                              " bytes of voxel data (", DescribeGrid(info),
                                              "), the data file has ", size));
    }
    spec.data_offset = size - need;
  }
  return spec;
}

}  // namespace

absl::StatusOr<std::unique_ptr<SliceSource>> OpenMetaImageVolume(const std::string& path) {
  TANDEM_ASSIGN_OR_RETURN(uint64_t size, NonEmptyFileSize(path));
  TANDEM_ASSIGN_OR_RETURN(MetaHeader header, ReadHeader(path, size));
  TANDEM_ASSIGN_OR_RETURN(StreamVolumeSpec spec, ParseHeader(path, header));
  return OpenStreamVolume(std::move(spec));
}

absl::Status WriteMetaImage(const std::string& path, const VolumeInfo& info,
                            const SliceFn& slice_fn, const VolumeWriteOptions& opts) {
  if (opts.gzip) {
    return absl::UnimplementedError(absl::StrCat(
        path, ": MetaImage is written uncompressed (.nrrd, .nii.gz and .zarr compress)"));
  }
  const bool detached = VolumeExtension(path) == ".mhd";
  absl::string_view type = "MET_FLOAT";
  for (const MetaType& t : MetaTypes()) {
    if (t.dtype == info.dtype) type = t.names[0];
  }
  const auto triple = [](const std::array<double, 3>& v) {
    return absl::StrCat(FormatDouble(v[0] + 0.0), " ", FormatDouble(v[1] + 0.0), " ",
                        FormatDouble(v[2] + 0.0));
  };
  const auto& d = info.directions;
  std::string header = absl::StrCat(
      "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = ",
      opts.big_endian ? "True" : "False",
      "\nCompressedData = False\nTransformMatrix = ", triple(d[0]), " ", triple(d[1]), " ",
      triple(d[2]), "\nOffset = ", triple(info.origin), "\nElementSpacing = ", triple(info.spacing),
      "\nDimSize = ", info.nx, " ", info.ny, " ", info.nz, "\nElementType = ", type, "\n");
  if (!info.suggested_isovalues.empty()) {
    absl::StrAppend(&header, "SuggestedIsovalues =");
    for (double v : info.suggested_isovalues) absl::StrAppend(&header, " ", FormatDouble(v));
    absl::StrAppend(&header, "\n");
  }
  std::string data_path = path;
  if (detached) {
    data_path = SiblingPath(path, ".raw").string();
    absl::StrAppend(
        &header, "ElementDataFile = ", std::filesystem::path(data_path).filename().string(), "\n");
  } else {
    absl::StrAppend(&header, "ElementDataFile = LOCAL\n");
  }
  return WriteHeaderThenVoxels(path, header, data_path, info, slice_fn, opts);
}

}  // namespace tandem::io::internal
