// 64-bit FNV-1a hash (Fowler, Noll and Vo; parameters of the IETF draft
// draft-eastlake-fnv, "The FNV Non-Cryptographic Hash Algorithm"): the scene file's
// fingerprint and the checksum of a checkpoint's payload. Not cryptographic: it detects
// truncation, corruption and edits, not deliberate forgery.
#pragma once
#include <cstdint>
#include <string_view>

namespace slurry::detail {

inline constexpr std::uint64_t kFnvOffset = 0xcbf29ce484222325ull;
inline constexpr std::uint64_t kFnvPrime = 0x100000001b3ull;

inline std::uint64_t fnv1a64(std::string_view bytes, std::uint64_t h = kFnvOffset) {
  for (const char c : bytes) {
    h ^= std::uint64_t(static_cast<unsigned char>(c));
    h *= kFnvPrime;
  }
  return h;
}

}  // namespace slurry::detail
