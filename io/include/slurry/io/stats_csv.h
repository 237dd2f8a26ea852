#pragma once
/// \file stats_csv.h
/// stats.csv, the run statistics beside the frames: a header line, then one row of RunStats
/// (stats.h) per frame, numbers with 9 significant digits.
#include <filesystem>
#include <string>

#include "slurry/engine/stats.h"

namespace slurry::io {

/// The header line of stats.csv; with `error_estimate` (output.error_estimate) it ends with the
/// columns error_energy and error_centroid.
std::string stats_csv_header(bool error_estimate = false);
/// One row of stats.csv (no line break), with the error estimate's columns if asked.
std::string stats_csv_row(const RunStats& s, bool error_estimate = false);
/// Keeps the header of the stats.csv at `file` and its rows of frames <= last (a resumed run
/// writes the later ones again); nothing if there is no such file. Throws IoError.
void truncate_stats_csv(const std::filesystem::path& file, int last);

}  // namespace slurry::io
