#pragma once
/// \file quote_text.h
/// Text read from a file, quoted for an error message: in single quotes, bytes outside printable
/// ASCII as '?', at most 60 characters and "..." after, so that binary garbage cannot wreck the
/// message. Frames (frame.cpp) and the PLY reader (io/src/ply.cpp) quote names with it.
#include <string>
#include <string_view>

namespace slurry {

std::string quote_text(std::string_view text);

}  // namespace slurry
