#include "tandem/client/chunk_store.h"

#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <system_error>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "tandem/status_macros.h"

namespace tandem::client {
namespace {

namespace fs = std::filesystem;

constexpr char kSessionTag[] = "session";

// FNV-1a, 64 bits: tells a chunk file from one of the same size written by another run.
uint64_t Checksum(const std::string& bytes) {
  uint64_t h = 0xcbf29ce484222325u;
  for (unsigned char c : bytes) h = (h ^ c) * 0x100000001b3u;
  return h;
}

std::string ManifestLine(const v1::SealedChunk& c) {
  return absl::StrFormat("%d\t%d\t%d\t%d\t%d\t%d\t%d\t%016x\n", c.index(), c.surface(),
                         c.first_slice(), c.last_slice(), c.triangles(), c.vertices(),
                         c.draco().size(), Checksum(c.draco()));
}

absl::Status WriteWhole(const fs::path& path, const std::string& bytes) {
  // Under a temporary name, then renamed: the file has its name only once it is whole.
  const fs::path part = fs::path(path.string() + ".part");
  {
    std::ofstream out(part, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.close();
    if (!out) return absl::UnavailableError(absl::StrCat(part.string(), ": cannot write"));
  }
  std::error_code ec;
  fs::rename(part, path, ec);
  if (ec) return absl::UnavailableError(absl::StrCat(path.string(), ": ", ec.message()));
  return absl::OkStatus();
}

absl::StatusOr<std::string> ReadWhole(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat(path.string(), ": cannot open"));
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) return absl::DataLossError(absl::StrCat(path.string(), ": cannot read"));
  return bytes;
}

// One line of the manifest as the chunk it describes (draco left empty), or nothing.
std::optional<v1::SealedChunk> ParseLine(absl::string_view line, uint64_t* bytes,
                                         uint64_t* checksum) {
  const std::vector<absl::string_view> f = absl::StrSplit(line, '\t');
  int64_t v[6];
  int32_t surface = 0;
  if (f.size() != 8 || !absl::SimpleAtoi(f[0], &v[0]) || !absl::SimpleAtoi(f[1], &surface) ||
      !absl::SimpleAtoi(f[2], &v[2]) || !absl::SimpleAtoi(f[3], &v[3]) ||
      !absl::SimpleAtoi(f[4], &v[4]) || !absl::SimpleAtoi(f[5], &v[5]) ||
      !absl::SimpleAtoi(f[6], bytes) || !absl::SimpleHexAtoi(f[7], checksum)) {
    return std::nullopt;
  }
  v1::SealedChunk c;
  c.set_index(v[0]);
  c.set_surface(surface);
  c.set_first_slice(v[2]);
  c.set_last_slice(v[3]);
  c.set_triangles(v[4]);
  c.set_vertices(v[5]);
  return c;
}

}  // namespace

std::string ChunkStore::ChunkPath(int64_t index) const {
  return (fs::path(dir_) / absl::StrFormat("chunk_%06d.drc", index)).string();
}

absl::Status ChunkStore::RewriteManifest(const std::vector<std::string>& lines) {
  std::string text = absl::StrCat(kSessionTag, "\t", session_, "\n");
  for (const std::string& line : lines) text += line;
  return WriteWhole(fs::path(dir_) / kManifest, text);
}

absl::StatusOr<std::vector<v1::SealedChunk>> ChunkStore::Load(const std::string& session_id) {
  std::vector<v1::SealedChunk> out;
  session_.clear();
  saved_ = 0;
  const fs::path manifest = fs::path(dir_) / kManifest;
  std::error_code ec;
  if (!fs::exists(manifest, ec)) return out;
  TANDEM_ASSIGN_OR_RETURN(std::string text, ReadWhole(manifest));
  // Only whole lines: the last one may have been cut short by the kill.
  std::vector<absl::string_view> lines = absl::StrSplit(text, '\n');
  lines.pop_back();  // after the last newline: empty, or a line cut short
  if (lines.empty() || lines[0] != absl::StrCat(kSessionTag, "\t", session_id)) return out;
  std::vector<std::string> kept;
  for (size_t i = 1; i < lines.size(); ++i) {
    uint64_t bytes = 0, checksum = 0;
    std::optional<v1::SealedChunk> c = ParseLine(lines[i], &bytes, &checksum);
    if (!c || c->index() != static_cast<int64_t>(out.size())) break;
    absl::StatusOr<std::string> draco = ReadWhole(ChunkPath(c->index()));
    if (!draco.ok() || draco->size() != bytes || Checksum(*draco) != checksum) break;
    c->set_draco(*std::move(draco));
    kept.push_back(absl::StrCat(lines[i], "\n"));
    out.push_back(*std::move(c));
  }
  session_ = session_id;
  saved_ = static_cast<int64_t>(out.size());
  if (kept.size() + 1 != lines.size() || text.back() != '\n') {
    TANDEM_RETURN_IF_ERROR(RewriteManifest(kept));
  }
  return out;
}

absl::Status ChunkStore::Save(const std::string& session_id, const v1::SealedChunk& c) {
  if (session_id != session_) {
    session_ = session_id;
    saved_ = 0;
    TANDEM_RETURN_IF_ERROR(RewriteManifest({}));
  }
  if (c.index() < saved_) return absl::OkStatus();  // resent after a resume: kept already
  if (c.index() > saved_) {
    return absl::DataLossError(absl::StrCat("sealed chunk ", c.index(), " arrived; ", dir_,
                                            " holds chunks 0..", saved_ - 1));
  }
  TANDEM_RETURN_IF_ERROR(WriteWhole(ChunkPath(c.index()), c.draco()));
  const fs::path manifest = fs::path(dir_) / kManifest;
  std::ofstream out(manifest, std::ios::binary | std::ios::app);
  out << ManifestLine(c);
  out.close();
  if (!out) return absl::UnavailableError(absl::StrCat(manifest.string(), ": cannot write"));
  ++saved_;
  return absl::OkStatus();
}

}  // namespace tandem::client
