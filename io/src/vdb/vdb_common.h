#pragma once
// What the two OpenVDB translation units of slurry::io share (private to io/).
#include <openvdb/openvdb.h>

#include <filesystem>
#include <string>

namespace slurry::io::detail {

/// openvdb::initialize() once per process (registers the grid and point types).
void initialize_openvdb();
/// Writes `grids` to `<path>.tmp-PID-N`, then renames it onto `path`; IoError on failure
/// (the temporary file is removed, an existing file at `path` is left untouched).
void write_grids_atomically(const std::filesystem::path& path, const openvdb::GridPtrVec& grids);
/// The grid called `name` from a .vdb file; IoError naming the file (and the grids it has).
openvdb::GridBase::Ptr read_grid(const std::filesystem::path& path, const std::string& name);

}  // namespace slurry::io::detail
