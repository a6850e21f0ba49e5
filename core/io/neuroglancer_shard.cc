// Neuroglancer's sharded layout (neuroglancer_uint64_sharded_v1): the chunk-id hash, the
// shard and minishard of an id, and whole shard files.
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <map>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "tandem/io/neuroglancer.h"
#include "tandem/status_macros.h"

namespace tandem::io {
namespace {

uint32_t Rotl(uint32_t x, int r) { return (x << r) | (x >> (32 - r)); }
uint32_t Fmix(uint32_t h) {
  h ^= h >> 16;
  h *= 0x85ebca6bu;
  h ^= h >> 13;
  h *= 0xc2b2ae35u;
  h ^= h >> 16;
  return h;
}
void PutU64(std::string* out, uint64_t v) {
  for (int i = 0; i < 8; ++i) out->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}
uint64_t Mask(int bits) { return bits >= 64 ? ~uint64_t{0} : (uint64_t{1} << bits) - 1; }

}  // namespace

std::array<uint32_t, 4> MurmurHash3X86_128(std::span<const uint8_t> key, uint32_t seed) {
  constexpr uint32_t c1 = 0x239b961b, c2 = 0xab0e9789, c3 = 0x38b34ae5, c4 = 0xa1e38b93;
  uint32_t h1 = seed, h2 = seed, h3 = seed, h4 = seed;
  const size_t blocks = key.size() / 16;
  auto word = [&](size_t at) {
    return uint32_t{key[at]} | uint32_t{key[at + 1]} << 8 | uint32_t{key[at + 2]} << 16 |
           uint32_t{key[at + 3]} << 24;
  };
  for (size_t b = 0; b < blocks; ++b) {
    uint32_t k1 = word(16 * b), k2 = word(16 * b + 4), k3 = word(16 * b + 8),
             k4 = word(16 * b + 12);
    k1 *= c1, k1 = Rotl(k1, 15), k1 *= c2, h1 ^= k1;
    h1 = Rotl(h1, 19), h1 += h2, h1 = h1 * 5 + 0x561ccd1b;
    k2 *= c2, k2 = Rotl(k2, 16), k2 *= c3, h2 ^= k2;
    h2 = Rotl(h2, 17), h2 += h3, h2 = h2 * 5 + 0x0bcaa747;
    k3 *= c3, k3 = Rotl(k3, 17), k3 *= c4, h3 ^= k3;
    h3 = Rotl(h3, 15), h3 += h4, h3 = h3 * 5 + 0x96cd1c35;
    k4 *= c4, k4 = Rotl(k4, 18), k4 *= c1, h4 ^= k4;
    h4 = Rotl(h4, 13), h4 += h1, h4 = h4 * 5 + 0x32ac3b17;
  }
  // The tail: up to 15 bytes into k1..k4 (byte i goes to k[i / 4] at bits 8 * (i % 4)).
  const size_t tail = 16 * blocks, rest = key.size() & 15;
  uint32_t k[4] = {0, 0, 0, 0};
  for (size_t i = 0; i < rest; ++i) k[i / 4] ^= uint32_t{key[tail + i]} << (8 * (i % 4));
  if (rest > 12) k[3] *= c4, k[3] = Rotl(k[3], 18), k[3] *= c1, h4 ^= k[3];
  if (rest > 8) k[2] *= c3, k[2] = Rotl(k[2], 17), k[2] *= c4, h3 ^= k[2];
  if (rest > 4) k[1] *= c2, k[1] = Rotl(k[1], 16), k[1] *= c3, h2 ^= k[1];
  if (rest > 0) k[0] *= c1, k[0] = Rotl(k[0], 15), k[0] *= c2, h1 ^= k[0];
  const uint32_t len = static_cast<uint32_t>(key.size());
  h1 ^= len, h2 ^= len, h3 ^= len, h4 ^= len;
  h1 += h2 + h3 + h4;
  h2 += h1, h3 += h1, h4 += h1;
  h1 = Fmix(h1), h2 = Fmix(h2), h3 = Fmix(h3), h4 = Fmix(h4);
  h1 += h2 + h3 + h4;
  h2 += h1, h3 += h1, h4 += h1;
  return {h1, h2, h3, h4};
}

uint64_t HashChunkId(uint64_t id, const NeuroglancerSharding& sharding) {
  const uint64_t shifted = sharding.preshift_bits >= 64 ? 0 : id >> sharding.preshift_bits;
  if (!sharding.murmurhash) return shifted;
  uint8_t bytes[8];
  for (int i = 0; i < 8; ++i) bytes[i] = static_cast<uint8_t>(shifted >> (8 * i));
  const std::array<uint32_t, 4> h = MurmurHash3X86_128(bytes, 0);
  return uint64_t{h[0]} | uint64_t{h[1]} << 32;
}

ShardLocation LocateChunk(uint64_t id, const NeuroglancerSharding& sharding) {
  const uint64_t h = HashChunkId(id, sharding);
  return {(h >> sharding.minishard_bits) & Mask(sharding.shard_bits),
          h & Mask(sharding.minishard_bits)};
}

NeuroglancerSharding ChooseSharding(size_t segments) {
  NeuroglancerSharding s;
  // Whole bits: ceil(log2(n / per)), at least 0.
  auto bits_for = [](size_t n, size_t per) {
    int bits = 0;
    while ((size_t{1} << bits) * per < n && bits < 40) ++bits;
    return bits;
  };
  s.shard_bits = bits_for(segments, size_t{1} << 14);
  const size_t per_shard = (segments >> s.shard_bits) + 1;
  s.minishard_bits = std::min(bits_for(per_shard, 32), 16);
  return s;
}

std::string ShardFileName(uint64_t shard, const NeuroglancerSharding& sharding) {
  const int digits = (sharding.shard_bits + 3) / 4;
  return absl::StrCat(absl::StrFormat("%0*x", digits, shard), ".shard");
}

absl::StatusOr<std::string> GzipBytes(std::string_view bytes) {
  z_stream z;
  std::memset(&z, 0, sizeof(z));
  // windowBits 15 + 16: a gzip header and trailer rather than zlib's.
  if (deflateInit2(&z, Z_DEFAULT_COMPRESSION, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY) != Z_OK) {
    return absl::InternalError("gzip: deflateInit2 failed");
  }
  std::string out(deflateBound(&z, bytes.size()) + 32, '\0');
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(bytes.data()));
  z.avail_in = static_cast<uInt>(bytes.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data());
  z.avail_out = static_cast<uInt>(out.size());
  const int rc = deflate(&z, Z_FINISH);
  out.resize(z.total_out);
  deflateEnd(&z);
  if (rc != Z_STREAM_END) return absl::InternalError("gzip: deflate did not finish");
  return out;
}

absl::StatusOr<std::string> BuildShard(std::vector<ShardChunk> chunks,
                                       const NeuroglancerSharding& sharding) {
  if (sharding.minishard_bits < 0 || sharding.minishard_bits > 32) {
    return absl::InvalidArgumentError(
        absl::StrCat("minishard_bits must be in [0, 32], got ", sharding.minishard_bits));
  }
  const uint64_t minishards = uint64_t{1} << sharding.minishard_bits;
  std::vector<std::pair<uint64_t, size_t>> order;  // (minishard, chunk)
  order.reserve(chunks.size());
  for (size_t i = 0; i < chunks.size(); ++i) {
    order.emplace_back(LocateChunk(chunks[i].id, sharding).minishard, i);
  }
  std::sort(order.begin(), order.end(), [&](const auto& a, const auto& b) {
    return a.first != b.first ? a.first < b.first : chunks[a.second].id < chunks[b.second].id;
  });
  for (size_t i = 1; i < order.size(); ++i) {
    if (chunks[order[i].second].id == chunks[order[i - 1].second].id) {
      return absl::InvalidArgumentError(
          absl::StrCat("two chunks with id ", chunks[order[i].second].id));
    }
  }
  // Offsets below count from the end of the shard index, as the spec's do.
  std::string body;
  struct Entry {
    uint64_t id, start, size;
  };
  std::map<uint64_t, std::vector<Entry>> by_minishard;
  for (const auto& [minishard, i] : order) {
    ShardChunk& c = chunks[i];
    if (sharding.gzip_data) {
      TANDEM_ASSIGN_OR_RETURN(std::string z, GzipBytes(c.data));
      c.data = std::move(z);
    }
    body += c.prefix;
    by_minishard[minishard].push_back({c.id, body.size(), c.data.size()});
    body += c.data;
    std::string().swap(c.prefix);
    std::string().swap(c.data);
  }
  std::string index;
  index.reserve(16 * minishards);
  std::vector<std::pair<uint64_t, uint64_t>> ranges(minishards, {0, 0});
  for (const auto& [minishard, entries] : by_minishard) {
    // [3, n] uint64le: ids, starts and sizes; ids and starts delta encoded.
    std::string raw;
    uint64_t prev_id = 0, prev_end = 0;
    for (const Entry& e : entries) PutU64(&raw, e.id - prev_id), prev_id = e.id;
    for (const Entry& e : entries) PutU64(&raw, e.start - prev_end), prev_end = e.start + e.size;
    for (const Entry& e : entries) PutU64(&raw, e.size);
    if (sharding.gzip_minishard_index) {
      TANDEM_ASSIGN_OR_RETURN(std::string z, GzipBytes(raw));
      raw = std::move(z);
    }
    ranges[minishard] = {body.size(), body.size() + raw.size()};
    body += raw;
  }
  for (const auto& [start, end] : ranges) PutU64(&index, start), PutU64(&index, end);
  return index + body;
}

}  // namespace tandem::io
