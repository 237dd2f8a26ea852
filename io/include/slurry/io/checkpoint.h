// Checkpoint files (run.h, "Checkpoints"): `checkpoint_NNNN.slc` beside the frames, holding
// the run's and the solver's state after frame NNNN; or, for a run split over processes with
// output.per_rank, one `checkpoint_NNNN.rankR.slc` per process R, each in this format with the
// process's own part of the solver's state.
//
//   offset  size  field
//        0     8  magic "SLURRYCP"
//        8     4  format version (kCheckpointVersion)
//       12     4  byte-order mark 0x01020304 (read on the machine kind that wrote it)
//       16     8  FNV-1a hash of the scene file (Scene::source_hash)
//       24     4  frame index
//       28     4  zero
//       32     8  payload size in bytes
//       40     8  FNV-1a hash of the payload
//       48     -  payload: the run section (length-prefixed), then Solver::save_state
//
// Written atomically: a temporary name in the same directory, fsync, rename, fsync of the
// directory, so that the final name only ever names a complete file, even after a power cut.
#pragma once
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

namespace slurry::detail {

inline constexpr std::uint32_t kCheckpointVersion = 1;

struct Checkpoint {
  std::filesystem::path file;
  std::uint32_t version = 0;
  std::uint64_t scene_hash = 0;
  int frame = 0;
  std::string payload;
};

/// `<directory>/checkpoint_NNNN.slc`.
std::filesystem::path checkpoint_file(const std::filesystem::path& directory, int frame);
/// `<directory>/checkpoint_NNNN.rankR.slc`: process R's part of a checkpoint of a run split over
/// processes with output.per_rank (its particles only; the parts of all processes together are
/// the checkpoint).
std::filesystem::path checkpoint_part_file(const std::filesystem::path& directory, int frame, int rank);
/// The checkpoints of a directory with their frames, oldest first: each whole file, and each
/// complete set of parts (ranks 0 .. K - 1 of one frame) named by its part 0.
std::vector<std::pair<int, std::filesystem::path>> list_checkpoints(
    const std::filesystem::path& directory);
/// The files of the checkpoint `file` names: itself for a whole file; every part of its frame,
/// by rank, for a part 0 (checkpoint_NNNN.rank0.slc).
std::vector<std::filesystem::path> checkpoint_parts(const std::filesystem::path& file);
/// Receives payload bytes in order (Solver::StateSink).
using PayloadSink = std::function<void(const char* data, std::size_t size)>;
/// Writes one checkpoint atomically, its payload streamed: `produce` hands it to the sink piece by piece, and the
/// pieces go to the temporary file as they come (small ones through a 1 MiB buffer), the size
/// and checksum accumulating; they are written into the header before the fsync. No copy of
/// the state is held. Throws IoError (or what `produce` throws; the temporary file is removed).
void write_checkpoint(const std::filesystem::path& file, std::uint64_t scene_hash, int frame,
                      const std::function<void(const PayloadSink&)>& produce);
/// Reads a checkpoint and checks its magic, version, byte order, length and checksum. Throws
/// IoError naming the file and what is wrong (the scene hash is left to the caller).
Checkpoint read_checkpoint(const std::filesystem::path& file);

}  // namespace slurry::detail
