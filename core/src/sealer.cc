#include "sealer.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <tuple>
#include <utility>

#include "grow.h"
#include "simplifier_access.h"

namespace tandem {
namespace {

// The order of a chunk's pairs.
bool PairBefore(const LabelPair& a, const LabelPair& b) {
  return std::tie(a.inside, a.outside) < std::tie(b.inside, b.outside);
}

}  // namespace

IndexedMesh WeldChunks(std::span<const SealedChunk> chunks) {
  uint32_t max_id = 0;
  bool any = false;
  for (const SealedChunk& c : chunks) {
    for (uint32_t id : c.ids) {
      max_id = std::max(max_id, id);
      any = true;
    }
  }
  IndexedMesh out;
  if (!any) return out;
  std::vector<uint32_t> index(static_cast<size_t>(max_id) + 1, kInvalid);
  std::vector<Vec3> at(index.size());
  for (const SealedChunk& c : chunks) {
    for (size_t i = 0; i < c.ids.size(); ++i) {
      index[c.ids[i]] = 0;
      at[c.ids[i]] = c.positions[i];
    }
  }
  for (size_t id = 0; id < index.size(); ++id) {  // in increasing id
    if (index[id] == kInvalid) continue;
    index[id] = static_cast<uint32_t>(out.positions.size());
    out.positions.push_back(at[id]);
  }
  for (const SealedChunk& c : chunks) {
    for (uint32_t i : c.indices) out.indices.push_back(index[c.ids[i]]);
  }
  return out;
}

void JoinPairs(std::span<const SealedChunk> chunks, std::vector<uint32_t>* patch,
               std::vector<LabelPair>* pairs) {
  pairs->clear();
  for (const SealedChunk& c : chunks) pairs->insert(pairs->end(), c.pairs.begin(), c.pairs.end());
  std::sort(pairs->begin(), pairs->end(), PairBefore);
  pairs->erase(std::unique(pairs->begin(), pairs->end()), pairs->end());
  for (const SealedChunk& c : chunks) {
    for (uint32_t p : c.patch) {
      const auto it = std::lower_bound(pairs->begin(), pairs->end(), c.pairs[p], PairBefore);
      patch->push_back(static_cast<uint32_t>(it - pairs->begin()));
    }
  }
}

SealedChunk JoinChunks(std::vector<SealedChunk> pieces) {
  if (pieces.size() == 1) return std::move(pieces[0]);
  SealedChunk out;
  JoinPairs(pieces, &out.patch, &out.pairs);
  std::vector<std::pair<uint32_t, Vec3>> verts;  // (id, position)
  bool spans = false;
  for (const SealedChunk& p : pieces) {
    for (size_t i = 0; i < p.ids.size(); ++i) verts.emplace_back(p.ids[i], p.positions[i]);
    if (!p.ids.empty()) {  // a piece may only retire vertices
      out.first_slice = spans ? std::min(out.first_slice, p.first_slice) : p.first_slice;
      out.last_slice = spans ? std::max(out.last_slice, p.last_slice) : p.last_slice;
      spans = true;
    }
    out.retired.insert(out.retired.end(), p.retired.begin(), p.retired.end());
  }
  std::sort(verts.begin(), verts.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  // A seam vertex frozen in two slabs comes from both (FreezeShared): listed once.
  verts.erase(std::unique(verts.begin(), verts.end(),
                          [](const auto& a, const auto& b) { return a.first == b.first; }),
              verts.end());
  out.ids.reserve(verts.size());
  out.positions.reserve(verts.size());
  for (const auto& [id, pos] : verts) {
    out.ids.push_back(id);
    out.positions.push_back(pos);
  }
  for (const SealedChunk& p : pieces) {
    for (uint32_t i : p.indices) {
      const auto it = std::lower_bound(out.ids.begin(), out.ids.end(), p.ids[i]);
      out.indices.push_back(static_cast<uint32_t>(it - out.ids.begin()));
    }
  }
  return out;
}

Sealer::Sealer(MeshStore* store, Simplifier* simplifier, double margin, double sag_fraction,
               uint32_t id_first, uint32_t id_stride)
    : store_(store),
      simplifier_(simplifier),
      margin_(margin),
      sag_fraction_(sag_fraction),
      next_id_(id_first),
      id_stride_(id_stride) {}

void Sealer::SetNormal(VertexId v, Vec3 n) {
  uint32_t* slot = normal_slot_.Find(v);
  if (slot == nullptr) slot = &(normal_slot_.At(v) = normals_.Take());
  normals_[*slot] = n;
}

void Sealer::ReleaseNormal(VertexId v) {
  const uint32_t* slot = normal_slot_.Find(v);
  if (slot == nullptr) return;
  normals_.Release(*slot);
  normal_slot_.Erase(v);
}

void Sealer::AddVertices(std::span<const VertexId> verts) {
  for (VertexId v : verts) {  // ids of sealed vertices are recycled
    ReleaseNormal(v);
    kept_.Erase(v);
  }
  active_.insert(active_.end(), verts.begin(), verts.end());
}

Sealer::Kept& Sealer::HandOut(VertexId v) {
  Kept& k = kept_.At(v);
  if (k.id == kNoGlobalId) {
    if (next_id_ > std::numeric_limits<uint32_t>::max() - id_stride_) {
      throw std::overflow_error("a sealed session ran out of 32-bit vertex ids");
    }
    k.id = GlobalId{next_id_};
    next_id_ += id_stride_;
    ++handed_out_;
    k.stamp = 0;
  }
  return k;
}

void Sealer::Seal(double front, Executor* executor) {
  const bool all = front == std::numeric_limits<double>::infinity();
  // 1. Freeze. Contractions keep one end's id, so every live unfrozen vertex is in active_;
  // dead ids are dropped here, before the next EXTRACT can hand them out again.
  freeze_.clear();
  size_t keep = 0;
  // The active vertices' records are at scattered ids, one cache miss each (half of this
  // scan's time, which runs over the whole front at every slice): fetched a few ahead.
  constexpr size_t kAhead = 8;
  for (size_t i = 0; i < active_.size(); ++i) {
    if (i + kAhead < active_.size()) store_->Prefetch(active_[i + kAhead]);
    const VertexId v = active_[i];
    // A dead id may have been handed to a frozen vertex since (MergeSlabs): not ours.
    if (!store_->vertex_alive(v) || (store_->box_mask(v) & kFrozen)) continue;
    if (!all && (store_->box_mask(v) & kSeam)) {  // waits for the merge (slabs.h)
      active_[keep++] = v;
      continue;
    }
    const double limit = front - margin_;
    // Its own reach first (cheap), then that of every contraction it could still take part in.
    const bool frozen =
        all || (simplifier_ == nullptr
                    ? store_->height(v) + 1.0 <= limit
                    : store_->height(v) + SimplifierSealAccess::rad(*simplifier_, v) <= limit &&
                          SimplifierSealAccess::EdgesReachAtMost(*simplifier_, v, limit));
    if (frozen && !all && NextToSeam(v)) {  // keeps the seam's fans free for the merge
      active_[keep++] = v;
    } else if (frozen) {
      freeze_.push_back(v);
    } else {
      active_[keep++] = v;
    }
  }
  active_.resize(keep);
  if (freeze_.empty() && shared_.empty()) return;
  for (VertexId v : freeze_) {
    if (simplifier_ != nullptr) {
      SimplifierSealAccess::Freeze(*simplifier_, v);
    } else {
      store_->set_box_mask(v, store_->box_mask(v) | kFrozen);
    }
  }
  // 2. Sag, before anything is sealed. The freezing vertices' normals from their whole fans,
  // and their unfrozen neighbours' for now; frozen neighbours keep theirs.
  if (simplifier_ != nullptr) {
    if (sag_fraction_ > 0.0) {
      need_.assign(freeze_.begin(), freeze_.end());
      for (VertexId v : freeze_) {
        for (TriId t : store_->vertex_triangles(v)) {
          for (VertexId x : store_->triangle(t)) {
            if (!(store_->box_mask(x) & kFrozen)) need_.push_back(x);
          }
        }
      }
      std::sort(need_.begin(), need_.end());
      need_.erase(std::unique(need_.begin(), need_.end()), need_.end());
      for (VertexId v : need_) SetNormal(v, VertexNormal(*store_, v, &fan_));
      std::span<const VertexId> moving = freeze_;
      if (store_->labeled()) {
        sag_.clear();
        for (VertexId v : freeze_) {
          if (store_->OnePatchAround(v)) sag_.push_back(v);  // as without sealing
        }
        moving = sag_;
      }
      sag_corrected_ += SimplifierSealAccess::CorrectSagAt(*simplifier_, moving, Normals(),
                                                           sag_fraction_, executor);
      for (VertexId v : need_) {
        if (!(store_->box_mask(v) & kFrozen)) ReleaseNormal(v);  // found again next time
      }
    }
    for (VertexId v : freeze_) {
      max_shape_error_ =
          std::max(max_shape_error_, SimplifierSealAccess::MeasuredShapeErrorAt(*simplifier_, v));
    }
  }
  // 3. Seal the triangles whose last corner froze now, in increasing id. Their zero-area ones
  // are mended first, as the final mesh's are without sealing (degenerate.h); a corner may
  // move if no chunk has handed it out yet. A flip's two new triangles may hold none of the
  // vertices freezing now, so they are looked for around the old triangles' corners too.
  // Shared vertices frozen since the last call (FreezeShared) may complete triangles too.
  freeze_.insert(freeze_.end(), shared_.begin(), shared_.end());
  shared_.clear();
  GatherSealable(freeze_, all);
  if (simplifier_ != nullptr) {
    need_.clear();
    for (TriId t : tris_) {
      for (VertexId v : store_->triangle(t)) need_.push_back(v);
    }
    const DegenerateCounts mended = SimplifierSealAccess::TidyDegenerateAmong(
        *simplifier_, tris_, [this](VertexId v) { return id(v) == kNoGlobalId; });
    // A zero-area triangle that seals later, at a corner handed out now: mended now, while
    // that corner may still move (frozen, but without an id), the others staying where they
    // are and the topology too. Left for later, both its coincident corners could be handed
    // out by other triangles first, and then neither may move.
    // At the end everything seals now: there is no later.
    later_.clear();
    for (TriId t : all ? std::span<const TriId>() : tris_) {
      for (VertexId v : store_->triangle(t)) {
        if (id(v) != kNoGlobalId) continue;
        for (TriId u : store_->vertex_triangles(v)) later_.push_back(u);
      }
    }
    std::sort(later_.begin(), later_.end());
    later_.erase(std::unique(later_.begin(), later_.end()), later_.end());
    SimplifierSealAccess::TidyDegenerateAmong(
        *simplifier_, later_,
        [this](VertexId v) { return id(v) == kNoGlobalId && (store_->box_mask(v) & kFrozen); },
        /*flips=*/false);
    if (mended.flipped > 0) {
      need_.insert(need_.end(), freeze_.begin(), freeze_.end());
      GatherSealable(need_, all);
    }
  }
  drop_.assign(freeze_.begin(), freeze_.end());
  for (TriId t : tris_) {
    for (VertexId v : store_->triangle(t)) {
      Kept& k = HandOut(v);
      if (k.stamp != chunk_stamp_) {
        k.stamp = chunk_stamp_;
        pend_verts_.push_back({k.id, store_->height(v), store_->position(v)});
      }
      pend_tris_.push_back(k.id);
      if (!all) drop_.push_back(v);
    }
    if (store_->labeled()) pend_pairs_.push_back(store_->pair_of(t));
  }
  for (TriId t : tris_) store_->RemoveTriangle(t);
  sealed_triangles_ += static_cast<int64_t>(tris_.size());
  // 4. Frozen vertices left without triangles leave the store. A contraction next to a frozen
  // vertex can remove one of its triangles too (the triangle on the contracted edge): such a
  // vertex may lose its last triangle unseen here, so the end of the stream looks at all.
  if (all) {  // every vertex, in increasing id as sorted below
    drop_.resize(store_->vertex_capacity());
    std::iota(drop_.begin(), drop_.end(), VertexId{0});
  } else {
    std::sort(drop_.begin(), drop_.end());
    drop_.erase(std::unique(drop_.begin(), drop_.end()), drop_.end());
  }
  for (VertexId v : drop_) {
    if (store_->vertex_alive(v) && store_->vertex_triangles(v).empty()) {
      store_->RemoveVertex(v);
      if (simplifier_ != nullptr) SimplifierSealAccess::DropQuadric(*simplifier_, v);
      ReleaseNormal(v);
      if (const Kept* k = kept_.Find(v)) {
        if (k->id != kNoGlobalId) pend_retired_.push_back(k->id);
        kept_.Erase(v);
      }
    }
  }
}

void Sealer::DropDead() {
  std::erase_if(active_, [this](VertexId v) { return !store_->vertex_alive(v); });
}

bool Sealer::NextToSeam(VertexId v) const {
  for (TriId t : store_->vertex_triangles(v)) {
    for (VertexId x : store_->triangle(t)) {
      if ((store_->box_mask(x) & (kSeam | kFrozen)) == kSeam) return true;  // not settled
    }
  }
  return false;
}

void Sealer::FreezeShared(VertexId v, GlobalId id, double shape_error) {
  max_shape_error_ = std::max(max_shape_error_, shape_error);
  Kept& k = kept_.At(v);
  k.id = id;
  k.stamp = 0;
  if (simplifier_ != nullptr) {
    SetNormal(v, VertexNormal(*store_, v, &fan_));  // its side's fan
    SimplifierSealAccess::Freeze(*simplifier_, v);
  } else {
    store_->set_box_mask(v, store_->box_mask(v) | kFrozen);
  }
  shared_.push_back(v);
}

void Sealer::GatherSealable(std::span<const VertexId> around, bool every) {
  tris_.clear();
  if (every) {  // the end of the stream: every live triangle, in increasing id
    for (TriId t = 0; t < store_->triangle_capacity(); ++t) {
      if (!store_->triangle_alive(t)) continue;
      const auto& tri = store_->triangle(t);
      if (store_->box_mask(tri[0]) & store_->box_mask(tri[1]) & store_->box_mask(tri[2]) &
          kFrozen) {
        tris_.push_back(t);
      }
    }
    return;
  }
  for (VertexId v : around) {
    if (!store_->vertex_alive(v)) continue;
    for (TriId t : store_->vertex_triangles(v)) {
      const auto& tri = store_->triangle(t);
      if (store_->box_mask(tri[0]) & store_->box_mask(tri[1]) & store_->box_mask(tri[2]) &
          kFrozen) {
        tris_.push_back(t);
      }
    }
  }
  std::sort(tris_.begin(), tris_.end());
  tris_.erase(std::unique(tris_.begin(), tris_.end()), tris_.end());
}

bool Sealer::TakeChunk(SealedChunk* out) {
  if (pend_tris_.empty() && pend_retired_.empty()) return false;
  std::sort(pend_verts_.begin(), pend_verts_.end(),
            [](const PendingVertex& a, const PendingVertex& b) { return a.id < b.id; });
  // After the merge, a settled seam vertex's two copies are two vertices of this store
  // (SettleSeams): one id, listed once.
  pend_verts_.erase(std::unique(pend_verts_.begin(), pend_verts_.end(),
                                [](const PendingVertex& a, const PendingVertex& b) {
                                  return a.id == b.id;
                                }),
                    pend_verts_.end());
  *out = SealedChunk{};
  out->index = chunks_++;
  out->positions.reserve(pend_verts_.size());
  out->ids.reserve(pend_verts_.size());
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const PendingVertex& p : pend_verts_) {
    out->positions.push_back(p.pos);
    out->ids.push_back(Value(p.id));
    lo = std::min(lo, p.height);
    hi = std::max(hi, p.height);
  }
  if (lo <= hi) {  // a chunk may only retire vertices
    out->first_slice = static_cast<int64_t>(std::floor(lo));
    out->last_slice = static_cast<int64_t>(std::ceil(hi));
  }
  out->indices.reserve(pend_tris_.size());
  for (GlobalId id : pend_tris_) {
    const auto it = std::lower_bound(out->ids.begin(), out->ids.end(), Value(id));
    out->indices.push_back(static_cast<uint32_t>(it - out->ids.begin()));
  }
  out->retired.reserve(pend_retired_.size());
  for (GlobalId id : pend_retired_) out->retired.push_back(Value(id));
  if (store_->labeled()) TakePairs(out);
  pend_verts_.clear();
  pend_tris_.clear();
  pend_pairs_.clear();
  pend_retired_.clear();
  ++chunk_stamp_;
  return true;
}

void Sealer::TakePairs(SealedChunk* out) const {
  out->pairs = pend_pairs_;
  std::sort(out->pairs.begin(), out->pairs.end(), PairBefore);
  out->pairs.erase(std::unique(out->pairs.begin(), out->pairs.end()), out->pairs.end());
  out->patch.reserve(pend_pairs_.size());
  for (const LabelPair& p : pend_pairs_) {
    out->patch.push_back(static_cast<uint32_t>(
        std::lower_bound(out->pairs.begin(), out->pairs.end(), p, PairBefore) - out->pairs.begin()));
  }
}

void Sealer::Absorb(const Sealer& other, const PartVertexMap& map,
                    std::span<const PartVertex> welded) {
  const MeshStore& src = *other.store_;
  std::vector<bool> skip(src.vertex_capacity(), false);
  for (PartVertex v : welded) skip[InPart(v)] = true;
  for (VertexId v = 0; v < src.vertex_capacity() && v < map.size(); ++v) {
    const VertexId w = map[PartVertex{v}];
    if (!src.vertex_alive(v) || w == kInvalid || skip[v]) continue;
    if (const uint32_t* slot = other.normal_slot_.Find(v)) {
      SetNormal(w, other.normals_[*slot]);
    } else {
      ReleaseNormal(w);
    }
    if (const Kept* from = other.kept_.Find(v)) {
      Kept& k = kept_.At(w);
      k.id = from->id;
      // In the other's pending chunk: in this one's now (a vertex is listed once a chunk).
      k.stamp = from->stamp == other.chunk_stamp_ ? chunk_stamp_ : 0;
    } else {
      kept_.Erase(w);
    }
  }
  for (VertexId v : other.active_) {
    if (src.vertex_alive(v) && !skip[v]) active_.push_back(map[PartVertex{v}]);
  }
  // This store's dead ids in active_ may have gone to the vertices just copied: list each
  // vertex once (Seal drops the frozen and the dead).
  std::sort(active_.begin(), active_.end());
  active_.erase(std::unique(active_.begin(), active_.end()), active_.end());
  pend_verts_.insert(pend_verts_.end(), other.pend_verts_.begin(), other.pend_verts_.end());
  pend_tris_.insert(pend_tris_.end(), other.pend_tris_.begin(), other.pend_tris_.end());
  pend_pairs_.insert(pend_pairs_.end(), other.pend_pairs_.begin(), other.pend_pairs_.end());
  pend_retired_.insert(pend_retired_.end(), other.pend_retired_.begin(),
                       other.pend_retired_.end());
  sealed_triangles_ += other.sealed_triangles_;
  sag_corrected_ += other.sag_corrected_;
  handed_out_ += other.handed_out_;
  max_shape_error_ = std::max(max_shape_error_, other.max_shape_error_);
}

size_t Sealer::MemoryBytes() const {
  return active_.capacity() * sizeof(VertexId) + kept_.MemoryBytes() + normal_slot_.MemoryBytes() +
         normals_.MemoryBytes() + fan_.capacity() * sizeof(uint32_t) +
         (freeze_.capacity() + need_.capacity() + drop_.capacity()) * sizeof(VertexId) +
         (tris_.capacity() + later_.capacity()) * sizeof(TriId) +
         pend_verts_.capacity() * sizeof(PendingVertex) +
         (pend_tris_.capacity() + pend_retired_.capacity()) * sizeof(GlobalId) +
         pend_pairs_.capacity() * sizeof(LabelPair) + sag_.capacity() * sizeof(VertexId);
}

}  // namespace tandem
