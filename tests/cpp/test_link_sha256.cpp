// SHA-256 and HMAC-SHA-256 against the published test vectors: FIPS 180-4's examples (NIST CSRC)
// and RFC 4231's HMAC-SHA-256 cases 1-7; splitting the input anywhere gives the same digest.
#include <doctest/doctest.h>

#include <string>
#include <vector>

#include "flight_sw/link/sha256.hpp"

using namespace rvd::link;

namespace {
std::string hex(const uint8_t* p, size_t n) {
  static const char* d = "0123456789abcdef";
  std::string s;
  for (size_t i = 0; i < n; ++i) {
    s += d[p[i] >> 4];
    s += d[p[i] & 15];
  }
  return s;
}
std::vector<uint8_t> bytes(const std::string& s) { return {s.begin(), s.end()}; }

std::string sha256(const std::vector<uint8_t>& m) {
  Sha256 h;
  h.update(m.data(), m.size());
  uint8_t out[32];
  h.finish(out);
  return hex(out, 32);
}

std::string hmac(const std::vector<uint8_t>& key, const std::vector<uint8_t>& m) {
  HmacSha256 h(key.data(), key.size());
  uint8_t out[32];
  h.mac(m.data(), m.size(), out);
  return hex(out, 32);
}
}  // namespace

TEST_CASE("SHA-256: FIPS 180-4 examples") {
  CHECK(sha256({}) == "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  CHECK(sha256(bytes("abc")) == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  CHECK(sha256(bytes("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq")) ==
        "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  CHECK(sha256(std::vector<uint8_t>(1000000, 'a')) ==
        "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
}

TEST_CASE("SHA-256: any split of the input gives the same digest (block and padding edges)") {
  std::vector<uint8_t> m(200);
  for (size_t i = 0; i < m.size(); ++i) m[i] = static_cast<uint8_t>(i * 37 + 11);
  for (size_t len : {0u, 1u, 55u, 56u, 63u, 64u, 65u, 119u, 120u, 128u, 200u}) {
    const std::vector<uint8_t> part(m.begin(), m.begin() + len);
    const std::string whole = sha256(part);
    for (size_t cut = 0; cut <= len; ++cut) {
      Sha256 h;
      h.update(part.data(), cut);
      h.update(part.data() + cut, len - cut);
      uint8_t out[32];
      h.finish(out);
      CHECK(hex(out, 32) == whole);
    }
  }
}

TEST_CASE("HMAC-SHA-256: RFC 4231 test cases 1-7") {
  CHECK(hmac(std::vector<uint8_t>(20, 0x0b), bytes("Hi There")) ==
        "b0344c61d8db38535ca8afceaf0bf12b881dc200c9833da726e9376c2e32cff7");
  CHECK(hmac(bytes("Jefe"), bytes("what do ya want for nothing?")) ==
        "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843");
  CHECK(hmac(std::vector<uint8_t>(20, 0xaa), std::vector<uint8_t>(50, 0xdd)) ==
        "773ea91e36800e46854db8ebd09181a72959098b3ef8c122d9635514ced565fe");
  std::vector<uint8_t> key4;
  for (int i = 1; i <= 25; ++i) key4.push_back(static_cast<uint8_t>(i));
  CHECK(hmac(key4, std::vector<uint8_t>(50, 0xcd)) ==
        "82558a389a443c0ea4cc819899f2083a85f0faa3e578f8077a2e3ff46729665b");
  CHECK(hmac(std::vector<uint8_t>(20, 0x0c), bytes("Test With Truncation")).substr(0, 32) ==
        "a3b6167473100ee06e0c796c2955552b");
  const std::vector<uint8_t> long_key(131, 0xaa);  // longer than a block: hashed first
  CHECK(hmac(long_key, bytes("Test Using Larger Than Block-Size Key - Hash Key First")) ==
        "60e431591ee0b67f0d8a26aacbf5b77f8e0bc6213728c5140546040f0ee37f54");
  CHECK(hmac(long_key, bytes("This is a test using a larger than block-size key and a larger than block-size data. "
                             "The key needs to be hashed before being used by the HMAC algorithm.")) ==
        "9b09ffa71b942fcb27635fbcd5b0e944bfdc63644f0713938a7f51535c3a35e2");
}

TEST_CASE("HMAC over two parts equals HMAC over their concatenation; the object is reusable") {
  const auto key = bytes("Jefe");
  const auto m = bytes("what do ya want for nothing?");
  HmacSha256 h(key.data(), key.size());
  for (size_t cut = 0; cut <= m.size(); ++cut) {
    uint8_t out[32];
    h.mac(m.data(), cut, m.data() + cut, m.size() - cut, out);
    CHECK(hex(out, 32) == "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843");
  }
  const uint8_t a[3] = {1, 2, 3}, b[3] = {1, 2, 4};
  CHECK(equal_constant_time(a, a, 3));
  CHECK_FALSE(equal_constant_time(a, b, 3));
  CHECK(equal_constant_time(a, b, 2));
}
