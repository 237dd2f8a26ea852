#include "slurry/io/checkpoint.h"

#include <fcntl.h>
#include <unistd.h>
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <new>
#include <regex>

#include "fnv1a.h"
#include "input_file.h"
#include "slurry/engine/errors.h"

namespace slurry::detail {
namespace fs = std::filesystem;
namespace {

constexpr char kMagic[8] = {'S', 'L', 'U', 'R', 'R', 'Y', 'C', 'P'};
constexpr std::uint32_t kByteOrder = 0x01020304;
constexpr std::size_t kHeaderBytes = 48;

template <class V>
void put(std::string& h, const V& v) {
  h.append(reinterpret_cast<const char*>(&v), sizeof v);
}

template <class V>
V take(const std::string& h, std::size_t at) {
  V v;
  std::memcpy(&v, h.data() + at, sizeof v);
  return v;
}

[[noreturn]] void io_fail(const fs::path& file, const std::string& what) {
  throw IoError(file.string() + ": " + what);
}

void write_all(int fd, const char* p, std::size_t n, const fs::path& temp) {
  while (n > 0) {
    const ssize_t w = ::write(fd, p, n);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0)
      io_fail(temp, std::string("writing the checkpoint failed: ") + std::strerror(errno));
    p += w;
    n -= std::size_t(w);
  }
}

}  // namespace

fs::path checkpoint_file(const fs::path& directory, int frame) {
  char name[40];
  std::snprintf(name, sizeof name, "checkpoint_%04d.slc", frame);
  return directory / name;
}

fs::path checkpoint_part_file(const fs::path& directory, int frame, int rank) {
  char name[64];
  std::snprintf(name, sizeof name, "checkpoint_%04d.rank%d.slc", frame, rank);
  return directory / name;
}

namespace {

/// The checkpoint files of a directory: whole ones (rank -1) and parts, with their frames.
struct Listed {
  int frame, rank;
  fs::path file;
};

std::vector<Listed> list_all(const fs::path& directory) {
  std::vector<Listed> out;
  static const std::regex name(R"(checkpoint_(\d{4,9})(?:\.rank(\d{1,9}))?\.slc)");
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) return out;
  for (const auto& e : fs::directory_iterator(directory, ec)) {
    std::smatch m;
    const std::string n = e.path().filename().string();
    if (std::regex_match(n, m, name))
      out.push_back({std::stoi(m[1].str()), m[2].matched ? std::stoi(m[2].str()) : -1, e.path()});
  }
  if (ec) io_fail(directory, "cannot list the output directory: " + ec.message());
  std::sort(out.begin(), out.end(), [](const Listed& a, const Listed& b) {
    return a.frame != b.frame ? a.frame < b.frame : a.rank < b.rank;
  });
  return out;
}

}  // namespace

std::vector<std::pair<int, fs::path>> list_checkpoints(const fs::path& directory) {
  std::vector<std::pair<int, fs::path>> out;
  const auto all = list_all(directory);
  for (std::size_t i = 0; i < all.size();) {
    std::size_t j = i;
    while (j < all.size() && all[j].frame == all[i].frame) ++j;
    // [i, j): one frame's files, the whole one first (rank -1), then the parts by rank. A set of
    // parts counts when its ranks are 0 .. K - 1 with none missing.
    std::size_t k = i;
    if (all[k].rank < 0) out.emplace_back(all[k].frame, all[k].file), ++k;
    bool whole_set = k < j;
    for (std::size_t q = k; q < j; ++q) whole_set = whole_set && all[q].rank == int(q - k);
    if (whole_set) out.emplace_back(all[k].frame, all[k].file);
    i = j;
  }
  return out;
}

std::vector<fs::path> checkpoint_parts(const fs::path& file) {
  static const std::regex part(R"(checkpoint_(\d{4,9})\.rank0\.slc)");
  std::smatch m;
  const std::string n = file.filename().string();
  if (!std::regex_match(n, m, part)) return {file};
  const int frame = std::stoi(m[1].str());
  std::vector<fs::path> out;
  for (const auto& l : list_all(file.parent_path().empty() ? fs::path(".") : file.parent_path()))
    if (l.frame == frame && l.rank >= 0) out.push_back(l.file);
  return out;
}

void write_checkpoint(const fs::path& file, std::uint64_t scene_hash, int frame,
                      const std::function<void(const PayloadSink&)>& produce) {
  // The header with the payload's size and checksum still zero; both are written at their
  // offsets (32, 40) once the payload has gone through.
  std::string header(kMagic, sizeof kMagic);
  put(header, kCheckpointVersion);
  put(header, kByteOrder);
  put(header, scene_hash);
  put(header, std::int32_t(frame));
  put(header, std::uint32_t(0));
  put(header, std::uint64_t(0));
  put(header, std::uint64_t(0));
  fs::path temp = file;
  static unsigned long counter = 0;
  temp += ".tmp-" + std::to_string(long(::getpid())) + "-" + std::to_string(counter++);
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0)
    io_fail(temp, std::string("cannot create the temporary checkpoint: ") + std::strerror(errno));
  try {
    write_all(fd, header.data(), header.size(), temp);
    constexpr std::size_t kBuffer = std::size_t(1) << 20;
    std::string buffer;
    buffer.reserve(kBuffer);
    std::uint64_t size = 0, checksum = kFnvOffset;
    produce([&](const char* data, std::size_t n) {
      checksum = fnv1a64(std::string_view(data, n), checksum);
      size += n;
      if (buffer.size() + n <= kBuffer) {
        buffer.append(data, n);
        return;
      }
      write_all(fd, buffer.data(), buffer.size(), temp);
      buffer.clear();
      if (n < kBuffer)
        buffer.append(data, n);
      else
        write_all(fd, data, n, temp);  // a whole channel: straight from the solver's memory
    });
    write_all(fd, buffer.data(), buffer.size(), temp);
    std::string tail;
    put(tail, size);
    put(tail, checksum);
    if (::pwrite(fd, tail.data(), tail.size(), 32) != ssize_t(tail.size()))
      io_fail(temp, std::string("writing the checkpoint's header failed: ") + std::strerror(errno));
    if (::fsync(fd) != 0) io_fail(temp, std::string("fsync failed: ") + std::strerror(errno));
  } catch (...) {
    ::close(fd);
    ::unlink(temp.c_str());
    throw;
  }
  if (::close(fd) != 0) {
    ::unlink(temp.c_str());
    io_fail(temp, std::string("closing the checkpoint failed: ") + std::strerror(errno));
  }
  if (::rename(temp.c_str(), file.c_str()) != 0) {
    const int err = errno;
    ::unlink(temp.c_str());
    io_fail(file,
            std::string("renaming the temporary checkpoint onto it failed: ") + std::strerror(err));
  }
  // The rename itself is durable once the directory is synced.
  const fs::path dir = file.has_parent_path() ? file.parent_path() : fs::path(".");
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

namespace {

Checkpoint read_checkpoint_file(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) io_fail(file, "cannot open the checkpoint");
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) io_fail(file, "read error");
  if (bytes.size() < kHeaderBytes)
    io_fail(file, "truncated: " + std::to_string(bytes.size()) + " bytes, shorter than the " +
                      std::to_string(kHeaderBytes) + "-byte header");
  if (std::memcmp(bytes.data(), kMagic, sizeof kMagic) != 0)
    io_fail(file, "not a slurry checkpoint (no SLURRYCP magic)");
  Checkpoint c;
  c.file = file;
  c.version = take<std::uint32_t>(bytes, 8);
  if (c.version != kCheckpointVersion)
    io_fail(file, "checkpoint format version " + std::to_string(c.version) +
                      ", this slurry reads version " + std::to_string(kCheckpointVersion));
  if (take<std::uint32_t>(bytes, 12) != kByteOrder)
    io_fail(file, "written on a machine of another byte order");
  c.scene_hash = take<std::uint64_t>(bytes, 16);
  c.frame = take<std::int32_t>(bytes, 24);
  const auto size = take<std::uint64_t>(bytes, 32), sum = take<std::uint64_t>(bytes, 40);
  if (size != bytes.size() - kHeaderBytes)
    io_fail(file, "truncated or padded: the header announces " + std::to_string(size) +
                      " payload bytes, the file holds " +
                      std::to_string(bytes.size() - kHeaderBytes));
  bytes.erase(0, kHeaderBytes);  // the payload without a second copy of the file in memory
  c.payload = std::move(bytes);
  if (fnv1a64(c.payload) != sum) io_fail(file, "checksum mismatch (the file is corrupt)");
  if (c.frame < 0) io_fail(file, "negative frame index " + std::to_string(c.frame));
  return c;
}

}  // namespace

Checkpoint read_checkpoint(const fs::path& file) {
  const std::uintmax_t size = detail::regular_file_size(file, "a slurry checkpoint");
  detail::require_memory_for(file, size);
  try {
    return read_checkpoint_file(file);
  } catch (const std::bad_alloc&) {
    // The free-memory check passed (a sparse file, memory taken since), but it did not fit.
    throw ResourceError(file.string() + ": out of memory reading the checkpoint (" + std::to_string(size) +
                        " bytes); expected a checkpoint that fits in the available memory");
  }
}

}  // namespace slurry::detail
