// The helpers of command.h.
#include "command.h"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <system_error>

#ifdef SLURRY_WITH_MPI
#include "slurry/mpi/mpi.h"
#endif

namespace slurry::cli {

long long parse_integer(const std::string& option, const std::string& text, long long lo, long long hi) {
  long long v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || v < lo || v > hi)
    throw UsageError(option + ": expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got \"" +
                     text + "\"");
  return v;
}

double parse_positive(const std::string& option, const std::string& text) {
  std::size_t end = 0;
  double v = 0;
  try {
    v = std::stod(text, &end);
  } catch (const std::exception&) {
    end = 0;
  }
  if (end == 0 || end != text.size() || !(v > 0) || !std::isfinite(v))
    throw UsageError(option + ": expected a number > 0, got \"" + text + "\"");
  return v;
}

std::string human_seconds(double s) {
  char buf[32];
  if (s < 60)
    std::snprintf(buf, sizeof buf, "%.1f s", s);
  else if (s < 3600)
    std::snprintf(buf, sizeof buf, "%dm%02ds", int(s) / 60, int(s) % 60);
  else
    std::snprintf(buf, sizeof buf, "%dh%02dm", int(s) / 3600, (int(s) % 3600) / 60);
  return buf;
}

int Process::report(bool collective, int code, const char* what) const {
  if (rank == 0 || !collective)
    std::fprintf(stderr, "%sslurry: error: %s%s\n", code == 1 ? "\n" : "",
                 ranks > 1 ? ("[rank " + std::to_string(rank) + "] ").c_str() : "", what);
#ifdef SLURRY_WITH_MPI
  if (!collective && ranks > 1) mpi->abort(code);
#else
  (void)collective;
#endif
  return code;
}

}  // namespace slurry::cli
