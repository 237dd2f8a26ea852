#pragma once
/// \file input_file.h
/// Checks a reader makes before it opens a file: that the path names a regular file (a FIFO
/// would block the reader forever, a directory or a device cannot be read as one), and that a
/// file read whole fits in the memory the machine has free. Both throw with a message that names
/// the file, says what was found and what was expected.
#include <cstdint>
#include <filesystem>
#include <string>

namespace slurry::detail {

/// The size of the regular file at `path` (links followed). Throws IoError naming the path and
/// what it is instead: missing, a directory, a FIFO, a socket, a device, a loop of symbolic
/// links, or unreadable; `expected` completes the message ("expected a PLY file").
std::uintmax_t regular_file_size(const std::filesystem::path& path, const std::string& expected);

/// Throws ResourceError naming `path` if reading `bytes` of it into memory would take more than
/// the memory available now (MemAvailable of /proc/meminfo; the physical memory where that is
/// unknown).
void require_memory_for(const std::filesystem::path& path, std::uintmax_t bytes);

}  // namespace slurry::detail
