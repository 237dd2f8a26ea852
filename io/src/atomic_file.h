#pragma once
/// \file atomic_file.h
/// Writing a file atomically: the bytes go to `<target>.tmp-<pid>-<n>` in the same directory,
/// which is renamed onto the target by commit() and removed otherwise, so the target's name only
/// ever names a complete file (a killed process leaves a temporary file, never half a frame). No
/// fsync: a power cut may still lose the most recent file. Errors throw IoError naming the target.
#include <atomic>
#include <filesystem>
#include <fstream>
#include <string>

#if defined(_WIN32)
#include <process.h>
#else
#include <unistd.h>
#endif

#include "slurry/engine/errors.h"
#include "slurry/engine/quote_text.h"

namespace slurry::io::detail {

namespace fs = std::filesystem;

class AtomicFile {
 public:
  explicit AtomicFile(const fs::path& target) : target_(target), temp_(temp_name(target)) {
    out_.open(temp_, std::ios::binary | std::ios::trunc);
    if (!out_)
      fail("cannot create the temporary file " + quote_text(temp_.string()) + " (expected a writable directory)");
  }
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;
  ~AtomicFile() {
    if (committed_) return;
    if (out_.is_open()) out_.close();
    std::error_code ignored;
    fs::remove(temp_, ignored);
  }

  void write(const void* p, std::size_t n) {
    out_.write(static_cast<const char*>(p), static_cast<std::streamsize>(n));
    if (!out_)
      fail("writing " + quote_text(temp_.string()) + " failed (disk full or I/O error?); the target file was not changed");
  }

  /// Closes the temporary file and renames it onto the target.
  void commit() {
    out_.flush();
    out_.close();
    if (out_.fail())
      fail("flushing " + quote_text(temp_.string()) + " failed (disk full or I/O error?); the target file was not changed");
    std::error_code ec;
    fs::rename(temp_, target_, ec);
    if (ec)
      fail("renaming the temporary file " + quote_text(temp_.string()) + " onto it failed: " + ec.message());
    committed_ = true;
  }

 private:
  [[noreturn]] void fail(const std::string& what) const { throw IoError(target_.string() + ": " + what); }

  static fs::path temp_name(const fs::path& target) {
    static std::atomic<unsigned long> counter{0};
#if defined(_WIN32)
    const long pid = _getpid();
#else
    const long pid = static_cast<long>(::getpid());
#endif
    fs::path p = target;
    p += ".tmp-" + std::to_string(pid) + "-" + std::to_string(counter++);
    return p;
  }

  fs::path target_;
  fs::path temp_;
  std::ofstream out_;
  bool committed_ = false;
};

}  // namespace slurry::io::detail
