// SHA-256 (FIPS 180-4) and HMAC-SHA-256 (RFC 2104) for the link's message tags.
//
// Small and self-contained: no heap, no tables beyond the 64 round constants, fixed-size state on
// the stack or in the owner. HmacSha256 hashes the key's inner and outer pads once (set_key), so a
// tag costs the message's blocks plus one more compression for the outer hash; mac() copies the
// two prepared states and never modifies the object, so one key can tag from any number of
// places. The control flow does not depend on the data (the same instructions for every key and
// message of a given length), which also keeps emulated instruction counts repeatable.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

namespace rvd::link {

class Sha256 {
 public:
  static constexpr std::size_t kDigestSize = 32;
  static constexpr std::size_t kBlockSize = 64;

  Sha256() { reset(); }
  void reset();
  void update(const uint8_t* data, std::size_t n);
  // Pads, writes the digest; the object must be reset() before it is used again.
  void finish(uint8_t out[kDigestSize]);

 private:
  void compress(const uint8_t* block);

  std::array<uint32_t, 8> h_{};
  std::array<uint8_t, kBlockSize> buf_{};
  uint64_t total_bytes_ = 0;
  std::size_t fill_ = 0;
};

class HmacSha256 {
 public:
  static constexpr std::size_t kTagSize = Sha256::kDigestSize;

  HmacSha256() = default;
  HmacSha256(const uint8_t* key, std::size_t n) { set_key(key, n); }
  // Any key length (longer than a block: hashed first, as RFC 2104 says).
  void set_key(const uint8_t* key, std::size_t n);
  // out = HMAC(key, head || body); either part may be empty.
  void mac(const uint8_t* head, std::size_t head_size, const uint8_t* body, std::size_t body_size,
           uint8_t out[kTagSize]) const;
  void mac(const uint8_t* data, std::size_t n, uint8_t out[kTagSize]) const { mac(data, n, nullptr, 0, out); }

 private:
  Sha256 inner_, outer_;  // after absorbing key ^ ipad and key ^ opad
};

// Compares without an early exit, so the time taken does not tell how many leading bytes matched.
inline bool equal_constant_time(const uint8_t* a, const uint8_t* b, std::size_t n) {
  uint8_t diff = 0;
  for (std::size_t i = 0; i < n; ++i) diff = static_cast<uint8_t>(diff | (a[i] ^ b[i]));
  return diff == 0;
}

}  // namespace rvd::link
