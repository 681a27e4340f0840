// What the link-message tests share: the golden byte vectors of schema/golden.toml (written by
// schema/golden_packer.py, independently of the generated codecs) and sealing under its [auth] key.
#pragma once

#include <doctest/doctest.h>

#include <array>
#include <fstream>
#include <string>
#include <vector>

#include "flight_sw/link/messages.hpp"

namespace rvd::msg::golden_vectors {

// The `hex = "..."` line of section [name] in schema/golden.toml (the format is ours and simple).
inline std::vector<uint8_t> vector_of(const std::string& name) {
  std::ifstream in(std::string(RVD_SOURCE_DIR) + "/schema/golden.toml");
  REQUIRE(in.good());
  std::string line, section;
  while (std::getline(in, line)) {
    if (line.rfind("[", 0) == 0) section = line.substr(1, line.find(']') - 1);
    if (section == name && line.rfind("hex = \"", 0) == 0) {
      const std::string hex = line.substr(7, line.size() - 8);
      std::vector<uint8_t> bytes;
      for (size_t i = 0; i + 1 < hex.size(); i += 2)
        bytes.push_back(static_cast<uint8_t>(std::stoul(hex.substr(i, 2), nullptr, 16)));
      return bytes;
    }
  }
  FAIL("no golden vector for " << name);
  return {};
}

// The golden [auth] section: key 00 01 .. 1f, run id "golden-run-7".
inline std::array<uint8_t, kKeySize> key() {
  std::array<uint8_t, kKeySize> k{};
  for (size_t i = 0; i < k.size(); ++i) k[i] = static_cast<uint8_t>(i);
  return k;
}
constexpr const char* kRun = "golden-run-7";

inline LinkAuth auth_for(Role role) {
  const auto k = key();
  return LinkAuth(k.data(), k.size(), kRun, role);
}

// M sealed by `sender` as its message number `seq` of the run.
template <class M>
std::vector<uint8_t> sealed(const M& m, Role sender = Role::Flight, uint32_t seq = 1) {
  LinkAuth a = auth_for(sender);
  std::vector<uint8_t> out(M::kSize);
  Error e = Error::BufferTooSmall;
  REQUIRE(encode(m, out.data(), out.size(), &e) == M::kSize);
  REQUIRE(e == Error::None);
  std::vector<uint8_t> scratch(M::kSize);
  for (uint32_t i = 1; i < seq; ++i) REQUIRE(a.seal(scratch.data(), scratch.size()) == Error::None);
  REQUIRE(a.seal(out.data(), out.size()) == Error::None);
  CHECK(a.last_sent() == seq);
  return out;
}

}  // namespace rvd::msg::golden_vectors
