#include "input_file.h"

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <system_error>

#include "slurry/engine/errors.h"

namespace slurry::detail {

namespace fs = std::filesystem;

namespace {

std::string gib(double bytes) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g GiB", bytes / double(1ull << 30));
  return buf;
}

/// MemAvailable in bytes, or 0 if /proc/meminfo does not say.
std::uintmax_t available_memory() {
  std::ifstream in("/proc/meminfo");
  std::string key;
  std::uintmax_t kib = 0;
  std::string unit;
  while (in >> key >> kib) {
    std::getline(in, unit);
    if (key == "MemAvailable:") return kib * 1024;
  }
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? std::uintmax_t(pages) * std::uintmax_t(page) : 0;
}

}  // namespace

std::uintmax_t regular_file_size(const fs::path& path, const std::string& expected) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  const auto fail = [&](const std::string& what) { throw IoError(path.string() + ": " + what + " (expected " + expected + ")"); };
  if (ec && ec != std::errc::no_such_file_or_directory) {
    if (ec == std::errc::too_many_symbolic_link_levels) fail("a loop of symbolic links");
    fail("cannot be examined: " + ec.message());
  }
  const char* what = nullptr;
  switch (st.type()) {
    case fs::file_type::regular: break;
    case fs::file_type::not_found: {
      std::error_code lec;
      what = fs::is_symlink(fs::symlink_status(path, lec)) ? "a symbolic link to a file that does not exist"
                                                           : "no such file";
      break;
    }
    case fs::file_type::directory: what = "a directory, not a file"; break;
    case fs::file_type::fifo: what = "a FIFO (named pipe), not a regular file"; break;
    case fs::file_type::socket: what = "a socket, not a regular file"; break;
    case fs::file_type::block:
    case fs::file_type::character: what = "a device, not a regular file"; break;
    default: what = "not a regular file"; break;
  }
  if (what) fail(what);
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec) fail("its size cannot be read: " + ec.message());
  if (::access(path.c_str(), R_OK) != 0) fail(std::string("cannot be read: ") + std::strerror(errno));
  return size;
}

void require_memory_for(const fs::path& path, std::uintmax_t bytes) {
  const std::uintmax_t free = available_memory();
  if (free > 0 && bytes > free)
    throw ResourceError(path.string() + ": " + gib(double(bytes)) + " to read, more than the " + gib(double(free)) +
                        " of memory available (expected a smaller file, or more free memory)");
}

}  // namespace slurry::detail
