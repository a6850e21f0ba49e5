// ChunkedMeshWriter (tandem/mesh_io.h): a mesh that arrives in sealed chunks written to a
// .ply or .obj file while it comes, through scratch files of vertices and triangles.
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <vector>

#include "absl/strings/str_cat.h"
#include "mesh_io_internal.h"
#include "tandem/geometry.h"
#include "tandem/io/mesh_io.h"

namespace tandem::io {
namespace {

using internal::meshio::AppendObjFace;
using internal::meshio::AppendObjHeader;
using internal::meshio::AppendObjVec3;
using internal::meshio::AppendPlyFace;
using internal::meshio::AppendPlyHeader;
using internal::meshio::AppendVec3;
using internal::meshio::BufferedWriter;
using internal::meshio::Error;
using internal::meshio::Format;
using internal::meshio::FormatOf;

}  // namespace

bool ChunkedMeshWriter::Supports(const std::string& path) {
  const absl::StatusOr<Format> f = FormatOf(path);
  return f.ok() && (*f == Format::kPly || *f == Format::kObj);
}

absl::StatusOr<std::unique_ptr<ChunkedMeshWriter>> ChunkedMeshWriter::Open(
    const std::string& path, const MeshWriteOptions& options) {
  if (!Supports(path)) {
    return Error(absl::StatusCode::kInvalidArgument, path,
                 "sealed chunks are written as they come to .ply or .obj only");
  }
  std::FILE* verts = std::tmpfile();
  std::FILE* tris = std::tmpfile();
  if (verts == nullptr || tris == nullptr) {
    const int err = errno;
    if (verts != nullptr) std::fclose(verts);
    if (tris != nullptr) std::fclose(tris);
    return Error(absl::StatusCode::kUnavailable, path,
                 absl::StrCat("cannot create a scratch file: ", std::strerror(err)));
  }
  return std::unique_ptr<ChunkedMeshWriter>(new ChunkedMeshWriter(path, options, verts, tris));
}

ChunkedMeshWriter::~ChunkedMeshWriter() {
  std::fclose(verts_);
  std::fclose(tris_);
}

absl::Status ChunkedMeshWriter::Failed(const char* what) const {
  return Error(absl::StatusCode::kUnavailable, path_,
               absl::StrCat(what, ": ", std::strerror(errno != 0 ? errno : EIO)));
}

absl::Status ChunkedMeshWriter::Add(const SealedChunk& chunk) {
  const size_t nt = chunk.num_triangles();
  for (size_t t = 0; t < nt; ++t) {
    const uint32_t* tri = &chunk.indices[3 * t];
    const Vec3 w = TriangleAreaVector(chunk.positions[tri[0]], chunk.positions[tri[1]],
                                      chunk.positions[tri[2]]);
    uint32_t slot;
    if (free_.empty()) {
      slot = static_cast<uint32_t>(waiting_.size());
      waiting_.emplace_back();
    } else {
      slot = free_.back();
      free_.pop_back();
    }
    WaitingTriangle& waiting = waiting_[slot];
    waiting.place = triangles_ + static_cast<int64_t>(t);
    waiting.open = 3;
    for (int k = 0; k < 3; ++k) {
      const uint32_t id = chunk.ids[tri[k]];
      auto [it, fresh] = open_.try_emplace(id, OpenVertex{chunk.positions[tri[k]], Vec3{0, 0, 0}});
      it->second.normal = it->second.normal + w;
      waiting.corners[k] = id;
      waiting.next[k] = it->second.waiting;
      it->second.waiting = 3 * slot + static_cast<uint32_t>(k);
    }
  }
  triangles_ += static_cast<int64_t>(nt);
  done_.clear();
  for (uint32_t id : chunk.retired) {
    auto it = open_.find(id);
    if (it == open_.end()) continue;  // retired before any of its triangles: none it had
    const double len = Norm(it->second.normal);
    const Vec3 n = len > 0 ? it->second.normal * (1.0 / len) : Vec3{0, 0, 0};
    const float record[6] = {static_cast<float>(it->second.pos.x), static_cast<float>(it->second.pos.y),
                             static_cast<float>(it->second.pos.z), static_cast<float>(n.x),
                             static_cast<float>(n.y), static_cast<float>(n.z)};
    if (std::fwrite(record, sizeof record, 1, verts_) != 1) {
      return Failed("writing the scratch file of vertices");
    }
    const uint32_t index = static_cast<uint32_t>(vertices_++);
    for (uint32_t c = it->second.waiting; c != kNoCorner;) {
      WaitingTriangle& waiting = waiting_[c / 3];
      waiting.corners[c % 3] = index;
      const uint32_t next = waiting.next[c % 3];
      if (--waiting.open == 0) {
        done_.push_back(waiting);
        free_.push_back(c / 3);
      }
      c = next;
    }
    open_.erase(it);
  }
  // The triangles whose last vertex this chunk retired go to their places; those of one
  // chunk mostly follow each other there, written as runs.
  std::sort(done_.begin(), done_.end(),
            [](const WaitingTriangle& x, const WaitingTriangle& y) { return x.place < y.place; });
  for (size_t i = 0; i < done_.size();) {
    const int64_t place = done_[i].place;
    run_.clear();
    for (; i < done_.size() && done_[i].place == place + static_cast<int64_t>(run_.size() / 3); ++i) {
      run_.insert(run_.end(), done_[i].corners, done_[i].corners + 3);
    }
    if (place != tris_at_ &&
        std::fseek(tris_, static_cast<long>(place * 3 * sizeof(uint32_t)), SEEK_SET) != 0) {
      return Failed("writing the scratch file of triangles");
    }
    if (std::fwrite(run_.data(), sizeof(uint32_t), run_.size(), tris_) != run_.size()) {
      return Failed("writing the scratch file of triangles");
    }
    tris_at_ = place + static_cast<int64_t>(run_.size() / 3);
  }
  return absl::OkStatus();
}

size_t ChunkedMeshWriter::MemoryBytes() const {
  // A flat_hash_map slot holds its pair plus one control byte.
  return open_.capacity() * (sizeof(std::pair<const uint32_t, OpenVertex>) + 1) +
         (waiting_.capacity() + done_.capacity()) * sizeof(WaitingTriangle) +
         (free_.capacity() + run_.capacity()) * sizeof(uint32_t);
}

absl::Status ChunkedMeshWriter::Finish() {
  if (!open_.empty()) {
    return Error(absl::StatusCode::kInternal, path_,
                 absl::StrCat(open_.size(), " vertices were never retired: chunks are missing"));
  }
  const bool ply = *FormatOf(path_) == Format::kPly;
  std::FILE* file = std::fopen(path_.c_str(), "wb");
  if (file == nullptr) return Failed("cannot open for writing");
  BufferedWriter out(file);
  const size_t nv = static_cast<size_t>(vertices_), nt = static_cast<size_t>(triangles_);
  const bool normals = options_.normals;
  if (ply) {
    AppendPlyHeader(out, nv, nt, normals, options_.space);
  } else {
    AppendObjHeader(out, nv, nt, options_.space);
  }
  // Vertices: PLY one record each; OBJ the "v" lines, then the "vn" lines.
  std::vector<float> block(6 * 4096);
  for (int pass = 0; pass < (ply || !normals ? 1 : 2); ++pass) {
    std::rewind(verts_);
    for (size_t done = 0; done < nv;) {
      const size_t n = std::min<size_t>(4096, nv - done);
      if (std::fread(block.data(), 6 * sizeof(float), n, verts_) != n) {
        return Failed("reading back the scratch file of vertices");
      }
      for (size_t i = 0; i < n; ++i) {
        const float* r = &block[6 * i];
        const Vec3 p{r[0], r[1], r[2]}, q{r[3], r[4], r[5]};
        if (ply) {
          AppendVec3(out, p);
          if (normals) AppendVec3(out, q);
        } else {
          AppendObjVec3(out, pass == 0 ? "v" : "vn", pass == 0 ? p : q);
        }
      }
      done += n;
    }
  }
  std::rewind(tris_);
  std::vector<uint32_t> tris(3 * 4096);
  for (size_t done = 0; done < nt;) {
    const size_t n = std::min<size_t>(4096, nt - done);
    if (std::fread(tris.data(), 3 * sizeof(uint32_t), n, tris_) != n) {
      return Failed("reading back the scratch file of triangles");
    }
    for (size_t i = 0; i < n; ++i) {
      if (ply) {
        AppendPlyFace(out, &tris[3 * i]);
      } else {
        AppendObjFace(out, &tris[3 * i], normals);
      }
    }
    done += n;
  }
  if (const int err = out.Close(); err != 0) {
    return Error(absl::StatusCode::kUnavailable, path_,
                 absl::StrCat("write failed: ", std::strerror(err)));
  }
  return absl::OkStatus();
}

}  // namespace tandem::io
