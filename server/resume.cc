#include "tandem/server/resume.h"

#include <openssl/crypto.h>
#include <openssl/rand.h>

#include <array>
#include <random>

#include "absl/strings/escaping.h"
#include "absl/strings/str_format.h"

namespace tandem::server {

std::string NewSecret() {
  std::array<unsigned char, 16> bytes{};
  if (RAND_bytes(bytes.data(), static_cast<int>(bytes.size())) != 1) {
    std::random_device device;  // (reads the kernel's generator too)
    for (unsigned char& b : bytes) b = static_cast<unsigned char>(device());
  }
  return absl::BytesToHexString(
      absl::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
}

bool ResumeTable::AdmitStream(int64_t max_sessions) {
  absl::MutexLock lock(&mu_);
  // Sessions waiting for a resume hold a slot too (their memory), but give it up, oldest
  // first, to a stream that would be refused without it.
  if (streams_ + ParkedLocked() >= max_sessions &&
      !(streams_ < max_sessions && EvictOldestLocked())) {
    return false;
  }
  ++streams_;
  return true;
}

void ResumeTable::StreamEnded() {
  absl::MutexLock lock(&mu_);
  --streams_;
}

std::optional<ParkedSession> ResumeTable::ParkAndWait(ParkedSession parked) {
  const std::string id = parked.feed->id();
  absl::MutexLock lock(&mu_);
  --streams_;  // the slot is the parked session's from now on (or freed: it ends)
  if (closed_ || window_ <= absl::ZeroDuration()) return parked;
  parked.feed->SetWaiting(true);
  parked_[id] = Entry{std::move(parked), absl::Now()};
  auto gone = [this, &id]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    auto it = parked_.find(id);
    return closed_ || it == parked_.end() || it->second.evicted;
  };
  mu_.AwaitWithDeadline(absl::Condition(&gone), absl::Now() + window_);
  auto it = parked_.find(id);
  if (it == parked_.end()) return std::nullopt;  // adopted
  std::optional<ParkedSession> out = std::move(it->second.session);
  parked_.erase(it);
  out->feed->SetWaiting(false);
  return out;
}

bool ResumeTable::EvictOldestLocked() {
  Entry* oldest = nullptr;
  for (auto& [id, entry] : parked_) {
    if (!entry.evicted && (oldest == nullptr || entry.since < oldest->since)) oldest = &entry;
  }
  if (oldest == nullptr) return false;
  oldest->evicted = true;  // its waiter ends it
  return true;
}

int64_t ResumeTable::parked() const {
  absl::MutexLock lock(&mu_);
  return ParkedLocked();
}

int64_t ResumeTable::ParkedLocked() const {
  int64_t n = 0;
  for (const auto& [id, entry] : parked_) n += entry.evicted ? 0 : 1;
  return n;
}

absl::StatusOr<ParkedSession> ResumeTable::Adopt(const std::string& id, const std::string& token,
                                                 int64_t next_slice, int64_t chunks_received,
                                                 int64_t* expected_slice,
                                                 std::vector<v1::SealedChunk>* replay) {
  absl::MutexLock lock(&mu_);
  auto it = parked_.find(id);
  if (it == parked_.end()) {
    return absl::NotFoundError(absl::StrFormat(
        "no session '%s' is waiting to be resumed on this server (unknown, finished, or its "
        "client left longer ago than tandem-server --resume-window-seconds = %g s)",
        absl::string_view(id).substr(0, 64), absl::ToDoubleSeconds(window_)));
  }
  if (it->second.evicted) return absl::NotFoundError(absl::StrFormat(
      "session %s was ended while it waited to be resumed: a new stream needed its slot "
      "(tandem-server --max-sessions)", id));
  ParkedSession& p = it->second.session;
  if (token.size() != p.token.size() ||
      CRYPTO_memcmp(token.data(), p.token.data(), token.size()) != 0) {
    return absl::PermissionDeniedError(absl::StrFormat(
        "wrong resume token for session %s: only the client that started a session (its "
        "first Progress.resume_token) can resume it",
        id));
  }
  *expected_slice = p.job->slices();
  if (next_slice != *expected_slice) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "session %s expects slice %d next (it consumed slices 0..%d); this stream starts at "
        "slice %d",
        id, *expected_slice, *expected_slice - 1, next_slice));
  }
  if (chunks_received < 0 || chunks_received > p.job->chunks_posted()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "Resume.chunks_received = %d, but session %s has sent %d sealed chunks", chunks_received,
        id, p.job->chunks_posted()));
  }
  if (absl::Status st = p.feed->ChunksFrom(static_cast<size_t>(chunks_received), replay);
      !st.ok()) {
    return st;
  }
  (void)p.feed->Acknowledge(chunks_received);  // (within the chunks posted: checked above)
  ParkedSession out = std::move(p);
  parked_.erase(it);
  out.feed->SetWaiting(false);
  return out;
}

void ResumeTable::Close() {
  absl::MutexLock lock(&mu_);
  closed_ = true;
}

}  // namespace tandem::server
