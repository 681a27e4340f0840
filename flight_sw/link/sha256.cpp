// SHA-256 and HMAC-SHA-256 (see sha256.hpp).
#include "flight_sw/link/sha256.hpp"

#include <cstring>

namespace rvd::link {
namespace {

// The first 32 bits of the fractional parts of the cube roots of the first 64 primes (FIPS 180-4 §4.2.2).
constexpr uint32_t kRound[64] = {
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2,
};

inline uint32_t rotr(uint32_t x, int n) { return (x >> n) | (x << (32 - n)); }

}  // namespace

void Sha256::reset() {
  // The first 32 bits of the fractional parts of the square roots of the first 8 primes (§5.3.3).
  h_ = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
  total_bytes_ = 0;
  fill_ = 0;
}

void Sha256::compress(const uint8_t* block) {
  uint32_t w[64];
  for (int i = 0; i < 16; ++i)
    w[i] = (uint32_t{block[4 * i]} << 24) | (uint32_t{block[4 * i + 1]} << 16) | (uint32_t{block[4 * i + 2]} << 8) |
           uint32_t{block[4 * i + 3]};
  for (int i = 16; i < 64; ++i) {
    const uint32_t s0 = rotr(w[i - 15], 7) ^ rotr(w[i - 15], 18) ^ (w[i - 15] >> 3);
    const uint32_t s1 = rotr(w[i - 2], 17) ^ rotr(w[i - 2], 19) ^ (w[i - 2] >> 10);
    w[i] = w[i - 16] + s0 + w[i - 7] + s1;
  }
  uint32_t a = h_[0], b = h_[1], c = h_[2], d = h_[3], e = h_[4], f = h_[5], g = h_[6], h = h_[7];
  for (int i = 0; i < 64; ++i) {
    const uint32_t t1 = h + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) + kRound[i] + w[i];
    const uint32_t t2 = (rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
    h = g;
    g = f;
    f = e;
    e = d + t1;
    d = c;
    c = b;
    b = a;
    a = t1 + t2;
  }
  h_[0] += a;
  h_[1] += b;
  h_[2] += c;
  h_[3] += d;
  h_[4] += e;
  h_[5] += f;
  h_[6] += g;
  h_[7] += h;
}

void Sha256::update(const uint8_t* data, std::size_t n) {
  if (n == 0) return;
  total_bytes_ += n;
  if (fill_ > 0) {
    const std::size_t take = n < kBlockSize - fill_ ? n : kBlockSize - fill_;
    std::memcpy(buf_.data() + fill_, data, take);
    fill_ += take;
    data += take;
    n -= take;
    if (fill_ < kBlockSize) return;
    compress(buf_.data());
    fill_ = 0;
  }
  for (; n >= kBlockSize; data += kBlockSize, n -= kBlockSize) compress(data);
  if (n > 0) {
    std::memcpy(buf_.data(), data, n);
    fill_ = n;
  }
}

void Sha256::finish(uint8_t out[kDigestSize]) {
  const uint64_t bits = total_bytes_ * 8;
  buf_[fill_++] = 0x80;
  if (fill_ > kBlockSize - 8) {  // no room for the length: one more block
    std::memset(buf_.data() + fill_, 0, kBlockSize - fill_);
    compress(buf_.data());
    fill_ = 0;
  }
  std::memset(buf_.data() + fill_, 0, kBlockSize - 8 - fill_);
  for (int i = 0; i < 8; ++i) buf_[kBlockSize - 1 - i] = static_cast<uint8_t>(bits >> (8 * i));
  compress(buf_.data());
  for (int i = 0; i < 8; ++i) {
    out[4 * i] = static_cast<uint8_t>(h_[i] >> 24);
    out[4 * i + 1] = static_cast<uint8_t>(h_[i] >> 16);
    out[4 * i + 2] = static_cast<uint8_t>(h_[i] >> 8);
    out[4 * i + 3] = static_cast<uint8_t>(h_[i]);
  }
}

void HmacSha256::set_key(const uint8_t* key, std::size_t n) {
  uint8_t block[Sha256::kBlockSize] = {};
  if (n > Sha256::kBlockSize) {
    Sha256 k;
    k.update(key, n);
    k.finish(block);
  } else if (n > 0) {
    std::memcpy(block, key, n);
  }
  uint8_t pad[Sha256::kBlockSize];
  for (std::size_t i = 0; i < Sha256::kBlockSize; ++i) pad[i] = block[i] ^ 0x36;
  inner_.reset();
  inner_.update(pad, sizeof pad);
  for (std::size_t i = 0; i < Sha256::kBlockSize; ++i) pad[i] = block[i] ^ 0x5c;
  outer_.reset();
  outer_.update(pad, sizeof pad);
  std::memset(block, 0, sizeof block);
  std::memset(pad, 0, sizeof pad);
}

void HmacSha256::mac(const uint8_t* head, std::size_t head_size, const uint8_t* body, std::size_t body_size,
                     uint8_t out[kTagSize]) const {
  Sha256 inner = inner_;
  inner.update(head, head_size);
  inner.update(body, body_size);
  uint8_t inner_digest[Sha256::kDigestSize];
  inner.finish(inner_digest);
  Sha256 outer = outer_;
  outer.update(inner_digest, sizeof inner_digest);
  outer.finish(out);
}

}  // namespace rvd::link
