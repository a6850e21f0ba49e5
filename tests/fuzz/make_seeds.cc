// Writes the seed corpora of the reader fuzz targets (tests/fuzz/corpus/<target>/) with
// the project's own writers: tiny volumes (a few hundred bytes to a few KB) in every
// variant the readers support. Run by tests/fuzz/run.sh --seeds; the output is checked in.
//   fuzz_make_seeds OUT_DIR
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "tandem/io/open_volume.h"
#include "tandem/io/series.h"
#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"
#include "tandem/io/zarr.h"

namespace fs = std::filesystem;
using tandem::DType;
using tandem::VolumeInfo;
using tandem::io::VolumeWriteOptions;

namespace {

std::string Slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void Put(const fs::path& p, const std::string& bytes) {
  fs::create_directories(p.parent_path());
  std::ofstream(p, std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

VolumeInfo Info(int64_t nx, int64_t ny, int64_t nz, DType t) {
  VolumeInfo info;
  info.nx = nx;
  info.ny = ny;
  info.nz = nz;
  info.dtype = t;
  return info;
}

// A ball-like field in the stored type, so the volumes hold a surface.
void Write(const fs::path& path, const VolumeInfo& info, const VolumeWriteOptions& opts = {}) {
  auto fn = [&](int64_t z, std::vector<uint8_t>* bytes) {
    bytes->assign(info.slice_bytes(), 0);
    const size_t es = tandem::DTypeSize(info.dtype);
    for (int64_t j = 0; j < info.ny; ++j) {
      for (int64_t i = 0; i < info.nx; ++i) {
        const double dx = i - info.nx / 2.0, dy = j - info.ny / 2.0, dz = z - info.nz / 2.0;
        const double v = 100.0 - 10.0 * (dx * dx + dy * dy + dz * dz);
        uint8_t* p = bytes->data() + (j * info.nx + i) * es;
        switch (info.dtype) {
          case DType::kUInt8: *p = static_cast<uint8_t>(v < 0 ? 0 : v); break;
          case DType::kUInt16: { uint16_t x = static_cast<uint16_t>(v < 0 ? 0 : v * 100); std::memcpy(p, &x, 2); break; }
          case DType::kInt16: { int16_t x = static_cast<int16_t>(v); std::memcpy(p, &x, 2); break; }
          case DType::kFloat32: { float x = static_cast<float>(v); std::memcpy(p, &x, 4); break; }
          // The wider integers as label maps: ids past float's 2^24 (and uint64's past 2^53).
          case DType::kInt8: {
            int8_t x = static_cast<int8_t>(v < 0 ? -1 : v);
            std::memcpy(p, &x, 1);
            break;
          }
          case DType::kUInt32: {
            uint32_t x = v < 0 ? 0 : 0x1000001u + static_cast<uint32_t>(v);
            std::memcpy(p, &x, 4);
            break;
          }
          case DType::kInt32: {
            int32_t x = v < 0 ? 0 : 0x7000001 + static_cast<int32_t>(v);
            std::memcpy(p, &x, 4);
            break;
          }
          case DType::kUInt64: {
            uint64_t x = v < 0 ? 0 : (uint64_t{1} << 60) + 1 + static_cast<uint64_t>(v);
            std::memcpy(p, &x, 8);
            break;
          }
          case DType::kInt64: {
            int64_t x = v < 0 ? 0 : (int64_t{1} << 54) + 1 + static_cast<int64_t>(v);
            std::memcpy(p, &x, 8);
            break;
          }
        }
      }
    }
    return absl::OkStatus();
  };
  absl::Status st = tandem::io::WriteVolume(path.string(), info, fn, opts);
  if (!st.ok()) {
    std::fprintf(stderr, "%s\n", std::string(st.message()).c_str());
    std::exit(1);
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: fuzz_make_seeds OUT_DIR\n");
    return 2;
  }
  const fs::path out(argv[1]);
  const fs::path tmp = fs::temp_directory_path() / ("tandem-seeds-" + std::to_string(getpid()));
  fs::create_directories(tmp);
  for (const char* t : {"fuzz_raw_json", "fuzz_nrrd", "fuzz_nifti", "fuzz_tiff", "fuzz_metaimage",
                        "fuzz_zarr", "fuzz_dicom"}) {
    fs::create_directories(out / t);
  }

  // raw + JSON: [u16 LE raw size][sidecar], the sidecar written as fz.json -> fz.raw.
  int n = 0;
  auto raw_seed = [&](VolumeInfo info, VolumeWriteOptions opts) {
    info.suggested_isovalues = {50.0};
    info.description = "fuzz seed";
    Write(tmp / "fz.json", info, opts);
    const uint64_t size = fs::file_size(tmp / "fz.raw");
    std::string seed;
    seed.push_back(static_cast<char>(size & 0xff));
    seed.push_back(static_cast<char>((size >> 8) & 0xff));
    seed += Slurp(tmp / "fz.json");
    Put(out / "fuzz_raw_json" / ("seed_" + std::to_string(++n)), seed);
  };
  VolumeWriteOptions big;
  big.big_endian = true;
  raw_seed(Info(5, 4, 3, DType::kUInt8), {});
  VolumeInfo spaced = Info(4, 4, 3, DType::kInt16);
  spaced.spacing = {0.5, 1.0, 2.0};
  spaced.origin = {-1.0, 0.0, 3.0};
  raw_seed(spaced, big);
  raw_seed(Info(3, 3, 2, DType::kFloat32), {});
  raw_seed(Info(6, 2, 2, DType::kUInt16), {});
  raw_seed(Info(4, 3, 2, DType::kUInt32), {});
  raw_seed(Info(3, 3, 2, DType::kUInt64), big);
  raw_seed(Info(5, 2, 2, DType::kInt8), {});

  // NRRD: attached raw / gzip / big-endian, and detached headers matching the target's
  // 4096-byte companions fz.raw and fz.raw.gz.
  VolumeWriteOptions gz;
  gz.gzip = true;
  Write(out / "fuzz_nrrd" / "seed_attached_uint8.nrrd", Info(5, 4, 3, DType::kUInt8));
  Write(out / "fuzz_nrrd" / "seed_attached_gzip_int16.nrrd", spaced, gz);
  Write(out / "fuzz_nrrd" / "seed_attached_big_float32.nrrd", Info(3, 3, 2, DType::kFloat32), big);
  Write(out / "fuzz_nrrd" / "seed_attached_big_uint32.nrrd", Info(4, 3, 2, DType::kUInt32), big);
  Write(out / "fuzz_nrrd" / "seed_attached_gzip_int64.nrrd", Info(3, 3, 2, DType::kInt64), gz);
  Write(tmp / "fz.nhdr", Info(16, 16, 16, DType::kUInt8));
  Put(out / "fuzz_nrrd" / "seed_detached_raw", Slurp(tmp / "fz.nhdr"));
  Write(tmp / "fz.nhdr", Info(8, 8, 32, DType::kUInt16), gz);
  Put(out / "fuzz_nrrd" / "seed_detached_gzip", Slurp(tmp / "fz.nhdr"));
  Put(out / "fuzz_nrrd" / "seed_handwritten_byteskip",
      "NRRD0004\n# hand-written: spacings, byte skip -1, key/value pairs\ntype: unsigned char\n"
      "dimension: 3\nsizes: 2 2 2\nspacings: 1.5 1 0.5\nspace origin: (1,2,3)\nendian: little\n"
      "encoding: raw\nbyte skip: -1\ncontent: handwritten\nsuggested_isovalues:=1 2\n\n"
      "PADDING\x01\x02\x03\x04\x05\x06\x07\x08");

  // NIfTI-1: plain, big-endian, scaled uint16, gzip.
  Write(out / "fuzz_nifti" / "seed_uint8.nii", Info(5, 4, 3, DType::kUInt8));
  Write(out / "fuzz_nifti" / "seed_big_int16.nii", spaced, big);
  VolumeWriteOptions scaled;
  scaled.nifti_scl_slope = 2.0f;
  scaled.nifti_scl_inter = 1.0f;
  Write(out / "fuzz_nifti" / "seed_scaled_uint16.nii", Info(4, 3, 2, DType::kUInt16), scaled);
  Write(out / "fuzz_nifti" / "seed_gzip_float32.nii.gz", Info(3, 3, 2, DType::kFloat32));
  Write(out / "fuzz_nifti" / "seed_uint32.nii", Info(4, 3, 2, DType::kUInt32));
  Write(out / "fuzz_nifti" / "seed_big_uint64.nii", Info(3, 3, 2, DType::kUInt64), big);
  Write(out / "fuzz_nifti" / "seed_int8.nii", Info(5, 2, 2, DType::kInt8));

  // TIFF: strips, big-endian, tiles, deflate.
  Write(out / "fuzz_tiff" / "seed_strips_uint8.tif", Info(5, 4, 3, DType::kUInt8));
  Write(out / "fuzz_tiff" / "seed_big_uint16.tif", Info(4, 3, 2, DType::kUInt16), big);
  VolumeWriteOptions tiles;
  tiles.tiff_tile_size = 16;
  Write(out / "fuzz_tiff" / "seed_tiles_uint8.tif", Info(17, 16, 2, DType::kUInt8), tiles);
  VolumeWriteOptions deflate;
  deflate.gzip = true;
  Write(out / "fuzz_tiff" / "seed_deflate_int16.tif", spaced, deflate);
  Write(out / "fuzz_tiff" / "seed_uint32.tif", Info(4, 3, 2, DType::kUInt32));
  Write(out / "fuzz_tiff" / "seed_big_uint64.tif", Info(3, 3, 2, DType::kUInt64), big);
  Write(out / "fuzz_tiff" / "seed_deflate_int32.tif", Info(4, 3, 2, DType::kInt32), deflate);

  // MetaImage: attached in every type and both byte orders, and hand-written headers for the
  // variants: zlib data, synonyms, HeaderSize -1, detached data files (the target's fz.raw
  // and fz.zraw companions).
  Write(out / "fuzz_metaimage" / "seed_uint8.mha", Info(5, 4, 3, DType::kUInt8));
  Write(out / "fuzz_metaimage" / "seed_big_int16.mha", spaced, big);
  Write(out / "fuzz_metaimage" / "seed_float32.mha", Info(3, 3, 2, DType::kFloat32));
  Write(out / "fuzz_metaimage" / "seed_uint16.mha", Info(4, 3, 2, DType::kUInt16));
  Write(out / "fuzz_metaimage" / "seed_uint32.mha", Info(4, 3, 2, DType::kUInt32));
  Write(out / "fuzz_metaimage" / "seed_big_int64.mha", Info(3, 3, 2, DType::kInt64), big);
  Write(out / "fuzz_metaimage" / "seed_int8.mha", Info(5, 2, 2, DType::kInt8));
  const std::string mha = "ObjectType = Image\nNDims = 3\nBinaryData = True\n";
  Put(out / "fuzz_metaimage" / "seed_zlib.mha",
      mha +
          "CompressedData = True\nCompressedDataSize = 11\nDimSize = 2 2 2\n"
          "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n" +
          std::string("\x78\x9c\x63\x60\x80\x03\x00\x00\x08\x00\x01", 11));
  Put(out / "fuzz_metaimage" / "seed_detached_raw.mha",
      mha +
          "DimSize = 16 16 16\nElementSize = 0.5 0.5 2\nPosition = 1 2 3\n"
          "Rotation = 0 1 0 1 0 0 0 0 -1\nAnatomicalOrientation = RAI\n"
          "ElementType = MET_UCHAR\nElementDataFile = fz.raw\n");
  Put(out / "fuzz_metaimage" / "seed_detached_zraw.mha",
      mha +
          "CompressedData = True\nElementByteOrderMSB = True\nDimSize = 8 8 32\n"
          "ElementType = MET_USHORT\nElementDataFile = fz.zraw\n");
  Put(out / "fuzz_metaimage" / "seed_tail.mha",
      mha +
          "HeaderSize = -1\nDimSize = 8 8 16\nElementType = MET_SHORT\n"
          "ElementDataFile = fz.raw\n");

  // fuzz_zarr: one-chunk arrays (chunk = the whole volume) packed as version byte, metadata
  // length, metadata, chunk.
  int zn = 0;
  for (int version : {2, 3}) {
    for (auto [codec, t] : {std::pair{tandem::io::ZarrCompressor::kNone, DType::kUInt8},
                            {tandem::io::ZarrCompressor::kBloscLz4, DType::kUInt16},
                            {tandem::io::ZarrCompressor::kZstd, DType::kInt16},
                            {tandem::io::ZarrCompressor::kGzip, DType::kFloat32},
                            {tandem::io::ZarrCompressor::kBloscZstd, DType::kUInt32},
                            {tandem::io::ZarrCompressor::kNone, DType::kUInt64},
                            {tandem::io::ZarrCompressor::kBloscLz4, DType::kInt8},
                            {tandem::io::ZarrCompressor::kZstd, DType::kInt64}}) {
      const fs::path store = tmp / ("z" + std::to_string(zn) + ".zarr");
      const VolumeInfo info = Info(6, 5, 3, t);
      tandem::io::ZarrWriteOptions zo;
      zo.version = version;
      zo.compressor = codec;
      zo.ome = false;
      zo.big_endian = zn % 3 == 1;
      zo.chunks = {3, 5, 6};
      const fs::path staged = tmp / "staged.json";
      Write(staged, info);  // the same field, then copied into the store
      auto src = tandem::io::OpenVolume(staged.string());
      absl::Status st = tandem::io::WriteZarr(
          store.string(), info, [&](int64_t, std::vector<uint8_t>* b) { return (*src)->ReadSlice(b); },
          zo);
      if (!st.ok()) {
        std::fprintf(stderr, "%s\n", std::string(st.message()).c_str());
        return 1;
      }
      const std::string meta = Slurp(store / (version == 3 ? "zarr.json" : ".zarray"));
      const std::string chunk = Slurp(store / (version == 3 ? "c/0/0/0" : "0.0.0"));
      std::string seed(1, static_cast<char>(version == 3 ? 1 : 0));
      seed.push_back(static_cast<char>(meta.size() & 0xff));
      seed.push_back(static_cast<char>(meta.size() >> 8));
      seed += meta + chunk;
      Put(out / "fuzz_zarr" / ("seed_v" + std::to_string(version) + "_" + std::to_string(zn) + ".bin"),
          seed);
      ++zn;
    }
  }

  // A sharded v3 array: one shard of two 1 x 3 x 3 inner chunks, index (and crc32c slot)
  // at the end.
  {
    const std::string meta =
        R"({"zarr_format": 3, "node_type": "array", "shape": [2, 3, 3], "data_type": "uint8",)"
        R"( "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": [2, 3, 3]}},)"
        R"( "chunk_key_encoding": {"name": "default"}, "fill_value": 0, "codecs": [{"name":)"
        R"( "sharding_indexed", "configuration": {"chunk_shape": [1, 3, 3], "codecs": [{"name":)"
        R"( "bytes"}], "index_codecs": [{"name": "bytes", "configuration": {"endian":)"
        R"( "little"}}, {"name": "crc32c"}], "index_location": "end"}}]})";
    std::string shard;
    for (int v = 0; v < 18; ++v) shard.push_back(static_cast<char>(v * 14));
    for (uint64_t e : {uint64_t{0}, uint64_t{9}, uint64_t{9}, uint64_t{9}}) {
      for (int b = 0; b < 8; ++b) shard.push_back(static_cast<char>(e >> (8 * b)));
    }
    shard.append(4, '\0');
    std::string seed(1, '\1');
    seed.push_back(static_cast<char>(meta.size() & 0xff));
    seed.push_back(static_cast<char>(meta.size() >> 8));
    Put(out / "fuzz_zarr" / "seed_v3_sharded.bin", seed + meta + shard);
  }

  // fuzz_zarr, the inputs that cost minutes or gigabytes: a million one-voxel chunks, a
  // blosc chunk of 100 bytes claiming 64 MiB, a shape beyond any volume, nested JSON, and
  // OME groups (mode byte 2) whose dataset paths are fine, go up, or are absolute.
  auto zarr_seed = [&](const std::string& name, char mode, const std::string& meta,
                       const std::string& chunk) {
    std::string seed(1, mode);
    seed.push_back(static_cast<char>(meta.size() & 0xff));
    seed.push_back(static_cast<char>(meta.size() >> 8));
    Put(out / "fuzz_zarr" / name, seed + meta + chunk);
  };
  zarr_seed("seed_tiny_chunks.bin", 0,
            R"({"zarr_format": 2, "shape": [100, 100, 100], "chunks": [1, 1, 1], "dtype": "|u1",)"
            R"( "compressor": null, "fill_value": 0})",
            "");
  {
    std::string blosc("\x02\x01\x01\x02", 4);
    for (uint32_t v : {64u << 20, 1u << 16, 100u}) {
      for (int b = 0; b < 4; ++b) blosc.push_back(static_cast<char>(v >> (8 * b)));
    }
    blosc.resize(100, '\0');
    zarr_seed("seed_blosc_claim.bin", 0,
              R"({"zarr_format": 2, "shape": [2, 4096, 8192], "chunks": [1, 4096, 8192],)"
              R"( "dtype": "<u2", "compressor": {"id": "blosc"}, "fill_value": 0})",
              blosc);
  }
  zarr_seed("seed_huge_shape.bin", 0,
            R"({"zarr_format": 2, "shape": [1125899906842624, 4, 4], "chunks": [1, 4, 4],)"
            R"( "dtype": "|u1", "compressor": null, "fill_value": 0})",
            "");
  zarr_seed("seed_nested.bin", 0,
            R"({"zarr_format": 2, "shape": [2, 3, 3], "chunks": [2, 3, 3], "dtype": )" +
                std::string(100, '[') + std::string(100, ']') + "}",
            "");
  for (const char* path : {"0", "../0", "/tmp/0"}) {
    zarr_seed(std::string("seed_ome_") +
                  (path[0] == '0'   ? "ok"
                   : path[0] == '.' ? "up"
                                    : "abs") +
                  ".bin",
              2,
              std::string(R"({"multiscales": [{"version": "0.4", "axes": ["z", "y", "x"],)"
                          R"( "datasets": [{"path": ")") +
                  path +
                  R"(", "coordinateTransformations": [{"type": "scale", "scale": [2, 1, 1]}]}]}]})",
              std::string(18, '\x40'));
  }

  // fuzz_dicom: two slices of a series (GDCM-written) packed as [u32 LE size of a][a][b],
  // in three transfer syntaxes and with a CT rescale.
  // Two slices of value 7z + 1 (GDCM-written) in dir; false if GDCM refused.
  auto write_series = [&](const fs::path& dir, tandem::io::DicomSyntax syntax, DType t,
                          double intercept) {
    tandem::io::DicomWriteOptions opts;
    opts.syntax = syntax;
    opts.rescale_intercept = intercept;
    VolumeInfo info = Info(6, 5, 2, t);
    absl::Status st = tandem::io::WriteDicomSeries(
        dir.string(), info,
        [&](int64_t z, std::vector<uint8_t>* b) {
          b->assign(info.slice_bytes(), static_cast<uint8_t>(7 * z + 1));
          return absl::OkStatus();
        },
        opts);
    if (!st.ok()) std::fprintf(stderr, "%s\n", std::string(st.message()).c_str());
    return st.ok();
  };
  auto pack = [](const std::string& x, const std::string& y) {
    std::string seed;
    for (int i = 0; i < 4; ++i) seed.push_back(static_cast<char>((x.size() >> (8 * i)) & 0xff));
    return seed + x + y;
  };
  int dn = 0;
  for (auto [syntax, t] : {std::pair{tandem::io::DicomSyntax::kExplicitLittle, DType::kInt16},
                           {tandem::io::DicomSyntax::kImplicitLittle, DType::kUInt8},
                           {tandem::io::DicomSyntax::kJpegLossless, DType::kUInt16}}) {
    const fs::path dir = tmp / ("dcm" + std::to_string(dn));
    if (!write_series(dir, syntax, t, dn == 0 ? -1024 : 0)) return 1;
    Put(out / "fuzz_dicom" / ("seed_" + std::to_string(dn++) + ".bin"),
        pack(Slurp(dir / "IM00001.dcm"), Slurp(dir / "IM00002.dcm")));
  }
  // fuzz_dicom, the files that crashed or hung GDCM: RLE fragment headers declaring 0 or
  // 0xFFFFFFFF segments (SIGFPE, SIGSEGV), sequences nested 40 deep (the stack overflowed
  // at a few thousand, 15 took minutes), a length past the end of the file.
  {
    const fs::path dir = tmp / "rle";
    if (!write_series(dir, tandem::io::DicomSyntax::kRle, DType::kInt16, 0)) return 1;
    const std::string a = Slurp(dir / "IM00001.dcm"), b = Slurp(dir / "IM00002.dcm");
    const size_t pixels = b.find(std::string("\xe0\x7f\x10\x00OB\0\0\xff\xff\xff\xff", 12));
    if (pixels == std::string::npos) return 1;
    const size_t table = static_cast<uint8_t>(b[pixels + 16]);  // a small offset table
    for (uint32_t segments : {0u, 0xffffffffu}) {
      std::string bad = b;
      for (int i = 0; i < 4; ++i) {
        bad[pixels + 12 + 8 + table + 8 + i] = static_cast<char>(segments >> (8 * i));
      }
      Put(out / "fuzz_dicom" / ("seed_rle_" + std::to_string(segments & 0xff) + ".bin"),
          pack(a, bad));
    }
    const fs::path plain = tmp / "dcm0";
    const std::string p = Slurp(plain / "IM00002.dcm");
    const size_t at = p.rfind(std::string("\xe0\x7f\x10\x00", 4));
    std::string nested;
    for (int d = 0; d < 40; ++d)
      nested += std::string(
          "\x40\x00\x30\xa7SQ\0\0\xff\xff\xff\xff"
          "\xfe\xff\x00\xe0\xff\xff\xff\xff",
          20);
    for (int d = 0; d < 40; ++d)
      nested += std::string(
          "\xfe\xff\x0d\xe0\0\0\0\0"
          "\xfe\xff\xdd\xe0\0\0\0\0",
          16);
    Put(out / "fuzz_dicom" / "seed_nested_40.bin",
        pack(Slurp(plain / "IM00001.dcm"), p.substr(0, at) + nested + p.substr(at)));
    Put(out / "fuzz_dicom" / "seed_length_past_end.bin",
        pack(Slurp(plain / "IM00001.dcm"),
             p.substr(0, at) + std::string("\x09\x00\x10\x10OB\0\0\xf0\xff\xff\xff", 12) +
                 p.substr(at)));
  }

  fs::remove_all(tmp);
  std::printf("seeds written under %s\n", out.string().c_str());
  return 0;
}
