// Following an acquisition in progress (tandem/follow.h): one polling loop, with the notion
// of "the next slice is complete" supplied per kind of input.
#include "tandem/io/follow.h"

#include <chrono>
#include <filesystem>
#include <map>
#include <thread>

#include "absl/strings/str_cat.h"
#include "follow_internal.h"
#include "tandem/status_macros.h"
#include "volume_io_internal.h"
#include "tandem/io/series.h"
#include "tandem/io/zarr.h"
#include "zarr_internal.h"

namespace tandem::io {
namespace {

using Clock = std::chrono::steady_clock;

double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

using internal::Growing;

// Numbered single-page TIFFs: slice k is the k-th name in natural order, complete once its
// size has held for stable_s.
class GrowingTiffs final : public Growing {
 public:
  GrowingTiffs(std::string dir, double stable_s) : dir_(std::move(dir)), stable_s_(stable_s) {}

  absl::StatusOr<int64_t> Complete(bool* changed) override { return Scan(changed, false); }

  // The acquisition is over: files need not hold their size any longer.
  absl::StatusOr<int64_t> Final() override {
    bool changed = false;
    return Scan(&changed, true);
  }

  absl::StatusOr<int64_t> Scan(bool* changed, bool final) {
    absl::StatusOr<std::vector<std::string>> files = ListSliceFiles(dir_);
    if (absl::IsNotFound(files.status()) && taken_.empty()) return 0;  // not created yet
    if (!files.ok()) return files.status();
    const std::vector<std::string> tiffs = TiffNames(*files);
    // Names already taken must stay a prefix: a slice cannot arrive before one sent.
    for (size_t i = 0; i < taken_.size(); ++i) {
      if (i >= tiffs.size() || tiffs[i] != taken_[i]) {
        return absl::FailedPreconditionError(absl::StrCat(
            i < tiffs.size() ? tiffs[i] : taken_[i],
            i < tiffs.size() ? ": appeared after later slices were already read (slice files "
                               "must arrive in name order)"
                             : ": disappeared while the acquisition was followed"));
      }
    }
    // Sizes of every file not taken yet (so each one's clock starts when it is first seen),
    // then the run of stable ones after the taken prefix.
    const auto now = Clock::now();
    int64_t complete = static_cast<int64_t>(taken_.size());
    bool run = true;
    for (size_t i = taken_.size(); i < tiffs.size(); ++i) {
      std::error_code ec;
      const uint64_t size = std::filesystem::file_size(tiffs[i], ec);
      if (ec) {
        run = false;
        continue;
      }
      auto [it, inserted] = sizes_.try_emplace(tiffs[i], Seen{size, now});
      if (inserted || it->second.size != size) {
        it->second = Seen{size, now};
        *changed = true;
      }
      run = run && size > 0 && (final || Seconds(now - it->second.since) >= stable_s_);
      if (run) ++complete;
    }
    // Remember the complete names (they must not change order from now on).
    for (int64_t i = static_cast<int64_t>(taken_.size()); i < complete; ++i) {
      taken_.push_back(tiffs[i]);
    }
    return complete;
  }

  absl::StatusOr<VolumeInfo> Info() override {
    TANDEM_ASSIGN_OR_RETURN(VolumeInfo info, internal::TiffSequenceInfo(taken_.front()));
    info.description = absl::StrCat("TIFF sequence followed in ", dir_);
    return info;
  }

  absl::Status Read(int64_t k, const VolumeInfo& info, std::vector<uint8_t>* bytes) override {
    return internal::ReadTiffSequenceSlice(taken_[k], taken_.front(), info, bytes);
  }

  std::string Dir() const override { return dir_; }

 private:
  struct Seen {
    uint64_t size;
    Clock::time_point since;
  };
  std::string dir_;
  double stable_s_;
  std::vector<std::string> taken_;  // complete files, in order
  std::map<std::string, Seen> sizes_;
};

// A Zarr array growing along z: the planes of complete chunk rows.
class GrowingZarr final : public Growing {
 public:
  GrowingZarr(std::string store, std::string selector)
      : store_(std::move(store)), selector_(std::move(selector)) {}

  absl::StatusOr<int64_t> Complete(bool* changed) override {
    ZarrReadOptions o{.array = selector_};
    absl::StatusOr<int64_t> n = CountCompleteZarrPlanes(store_, o, known_);
    if (!n.ok()) {
      // Before the first plane a store may not exist or be half set up: keep waiting (the
      // problem is reported if nothing ever comes).
      if (known_ == 0) {
        problem_ = std::string(n.status().message());
        return 0;
      }
      return n.status();
    }
    if (*n > known_) *changed = true;
    known_ = std::max(known_, *n);
    return known_;
  }

  absl::StatusOr<VolumeInfo> Info() override {
    TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<SliceSource> src, Open(0));
    VolumeInfo info = src->info();
    info.nz = 0;
    return info;
  }

  absl::Status Read(int64_t k, const VolumeInfo& info, std::vector<uint8_t>* bytes) override {
    // The reader is reopened (from plane k) when the array has grown past what it saw.
    if (reader_ == nullptr || reader_->next_slice() != k || k >= reader_->info().nz) {
      TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<SliceSource> src, Open(k));
      reader_ = std::move(src);
    }
    if (reader_->info().nx != info.nx || reader_->info().ny != info.ny ||
        reader_->info().dtype != info.dtype) {
      return absl::FailedPreconditionError(
          absl::StrCat(store_, ": the array's plane size or type changed while it was followed"));
    }
    return reader_->ReadSlice(bytes);
  }

  std::string Dir() const override { return store_; }

 private:
  absl::StatusOr<std::unique_ptr<SliceSource>> Open(int64_t first) {
    return OpenZarrVolume(store_, ZarrReadOptions{.array = selector_, .first_plane = first});
  }
  std::string store_, selector_;
  int64_t known_ = 0;
 public:
  std::string Problem() const override { return problem_; }
 private:
  std::string problem_;
  std::unique_ptr<SliceSource> reader_;
};

// A folder whose kind is decided by its first files: numbered TIFFs if any file is a TIFF,
// else a DICOM series.
class GrowingFolder final : public Growing {
 public:
  GrowingFolder(std::string dir, const FollowOptions& opts)
      : dir_(std::move(dir)),
        stable_s_(opts.stable_s),
        done_file_(opts.done_file),
        series_(opts.dicom_series),
        note_(opts.note) {}

  absl::StatusOr<int64_t> Complete(bool* changed) override {
    TANDEM_RETURN_IF_ERROR(Decide());
    return inner_ ? inner_->Complete(changed) : 0;
  }
  absl::StatusOr<int64_t> Final() override {
    TANDEM_RETURN_IF_ERROR(Decide());
    return inner_ ? inner_->Final() : 0;
  }
  absl::StatusOr<VolumeInfo> Info() override { return inner_->Info(); }
  absl::Status Read(int64_t k, const VolumeInfo& info, std::vector<uint8_t>* bytes) override {
    return inner_->Read(k, info, bytes);
  }
  std::string Dir() const override { return dir_; }
  std::string Problem() const override { return inner_ ? inner_->Problem() : ""; }

 private:
  absl::Status Decide() {
    if (inner_) return absl::OkStatus();
    absl::StatusOr<std::vector<std::string>> files = ListSliceFiles(dir_);
    if (absl::IsNotFound(files.status())) return absl::OkStatus();
    if (!files.ok()) return files.status();
    bool other = false;
    for (const std::string& f : *files) {
      other = other || std::filesystem::path(f).filename() != done_file_;
    }
    if (!TiffNames(*files).empty()) {
      if (!series_.empty()) {
        return absl::InvalidArgumentError(absl::StrCat(
            dir_, ": --series picks a series of a DICOM folder; this one holds TIFF slices"));
      }
      inner_ = std::make_unique<GrowingTiffs>(dir_, stable_s_);
    } else if (other) {
      inner_ = internal::MakeGrowingDicom(dir_, stable_s_, done_file_, series_, note_);
    }
    return absl::OkStatus();
  }
  std::string dir_;
  double stable_s_;
  std::string done_file_, series_;
  std::function<void(const std::string&)> note_;
  std::unique_ptr<Growing> inner_;
};

class FollowSource final : public SliceSource {
 public:
  FollowSource(std::unique_ptr<Growing> growing, FollowOptions opts)
      : growing_(std::move(growing)), opts_(std::move(opts)), last_new_(Clock::now()) {}

  // Waits for the first slice; then the geometry is known.
  absl::Status Start() {
    TANDEM_ASSIGN_OR_RETURN(bool ready, WaitFor(0));
    if (!ready) {
      return absl::DeadlineExceededError(absl::StrCat(
          growing_->Dir(), ": no complete slice appeared within ", opts_.settle_s,
          " s (--settle); is the acquisition writing there (TIFF slices or a Zarr array)?",
          growing_->Problem().empty() ? "" : " Last problem: ", growing_->Problem()));
    }
    TANDEM_ASSIGN_OR_RETURN(VolumeInfo info, growing_->Info());
    info_ = std::move(info);
    info_.nz = opts_.expect_slices;
    VolumeInfo check = info_;
    if (check.nz == 0) check.nz = 2;
    if (absl::Status st = ValidateVolumeInfo(check); !st.ok()) {
      return absl::InvalidArgumentError(absl::StrCat(growing_->Dir(), ": ", st.message()));
    }
    return absl::OkStatus();
  }

  const VolumeInfo& info() const override { return info_; }
  int64_t next_slice() const override { return next_; }

  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override {
    if (!sticky_.ok()) return sticky_;
    if (opts_.expect_slices > 0 && next_ >= opts_.expect_slices) {
      return absl::OutOfRangeError(
          absl::StrCat(growing_->Dir(), ": all ", opts_.expect_slices, " expected slices read"));
    }
    absl::StatusOr<bool> ready = WaitFor(next_);
    if (!ready.ok()) return sticky_ = ready.status();
    if (!*ready) {
      if (opts_.expect_slices > 0) {
        return sticky_ = absl::DeadlineExceededError(absl::StrCat(
                   growing_->Dir(), ": the acquisition stopped after ", next_, " of ",
                   opts_.expect_slices, " expected slices (", end_reason_, ")"));
      }
      if (next_ < 2) {
        return sticky_ = absl::DeadlineExceededError(absl::StrCat(
                   growing_->Dir(), ": the acquisition ended with ", next_,
                   " slice(s); a volume needs at least 2 (", end_reason_, ")"));
      }
      return absl::OutOfRangeError(absl::StrCat(growing_->Dir(), ": acquisition over after ",
                                                next_, " slices (", end_reason_, ")"));
    }
    if (absl::Status st = growing_->Read(next_, info_, bytes); !st.ok()) return sticky_ = st;
    ++next_;
    if (opts_.progress) opts_.progress(complete_, next_);
    return absl::OkStatus();
  }

 private:
  // Polls until slice k is complete (true) or the acquisition is over (false).
  absl::StatusOr<bool> WaitFor(int64_t k) {
    while (true) {
      bool changed = false;
      TANDEM_ASSIGN_OR_RETURN(int64_t n, growing_->Complete(&changed));
      const auto now = Clock::now();
      if (changed) last_new_ = now;
      if (n != complete_ && opts_.progress) opts_.progress(n, next_);
      complete_ = std::max(complete_, n);
      if (complete_ > k) return true;
      if (!opts_.done_file.empty()) {
        std::error_code ec;
        if (std::filesystem::exists(std::filesystem::path(growing_->Dir()) / opts_.done_file,
                                    ec)) {
          // Files written just before the marker count once they are stable.
          std::this_thread::sleep_for(std::chrono::duration<double>(opts_.stable_s + opts_.poll_s));
          return End(k, absl::StrCat("marker ", opts_.done_file, " appeared"));
        }
      }
      if (Seconds(now - last_new_) >= opts_.settle_s) {
        return End(k, absl::StrCat("nothing new for ", opts_.settle_s, " s"));
      }
      std::this_thread::sleep_for(std::chrono::duration<double>(opts_.poll_s));
    }
  }

  // The acquisition is over: slices held back may go now; true if slice k exists.
  absl::StatusOr<bool> End(int64_t k, std::string reason) {
    end_reason_ = std::move(reason);
    TANDEM_ASSIGN_OR_RETURN(int64_t n, growing_->Final());
    complete_ = std::max(complete_, n);
    return complete_ > k;
  }

  std::unique_ptr<Growing> growing_;
  FollowOptions opts_;
  VolumeInfo info_;
  int64_t next_ = 0, complete_ = 0;
  Clock::time_point last_new_;
  std::string end_reason_;
  absl::Status sticky_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<SliceSource>> FollowVolume(const std::string& path,
                                                          const FollowOptions& opts) {
  if (!(opts.settle_s > 0) || !(opts.stable_s >= 0) || !(opts.poll_s > 0) ||
      opts.expect_slices < 0) {
    return absl::InvalidArgumentError(
        "follow: --settle and the poll interval must be > 0, --expect-slices >= 0");
  }
  std::unique_ptr<Growing> growing;
  auto [store, selector] = SplitZarrSelector(path);
  std::error_code ec;
  if (internal::LooksLikeZarr(store) || store.ends_with(".zarr")) {
    if (!opts.dicom_series.empty()) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": --series picks a series of a DICOM folder; this is a Zarr store"));
    }
    growing = std::make_unique<GrowingZarr>(store, selector);
  } else if (std::filesystem::is_directory(path, ec) || !std::filesystem::exists(path, ec)) {
    // A folder, or one the instrument has not created yet: its first files tell TIFF
    // slices from a DICOM series.
    growing = std::make_unique<GrowingFolder>(path, opts);
  } else {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": --follow needs a folder (numbered TIFF slices) or a Zarr store (X.zarr), "
              "not a file"));
  }
  auto source = std::make_unique<FollowSource>(std::move(growing), opts);
  TANDEM_RETURN_IF_ERROR(source->Start());
  return std::unique_ptr<SliceSource>(std::move(source));
}

}  // namespace tandem::io
