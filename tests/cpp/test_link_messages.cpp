// The C++ side of the link schema: the golden byte vectors of schema/golden.toml, and bad input.
#include <doctest/doctest.h>

#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "flight_sw/link/messages.hpp"

using namespace rvd::msg;

namespace {
// The `hex = "..."` line of section [name] in schema/golden.toml (the format is ours and simple).
std::vector<uint8_t> golden(const std::string& name) {
  std::ifstream in(std::string(RVD_SOURCE_DIR) + "/schema/golden.toml");
  REQUIRE(in.good());
  std::string line, section;
  while (std::getline(in, line)) {
    if (line.rfind("[", 0) == 0) section = line.substr(1, line.find(']') - 1);
    if (section == name && line.rfind("hex = \"", 0) == 0) {
      std::string hex = line.substr(7, line.size() - 8);
      std::vector<uint8_t> bytes;
      for (size_t i = 0; i + 1 < hex.size(); i += 2) bytes.push_back(static_cast<uint8_t>(std::stoul(hex.substr(i, 2), nullptr, 16)));
      return bytes;
    }
  }
  FAIL("no golden vector for " << name);
  return {};
}

template <class M>
std::vector<uint8_t> encoded(const M& m) {
  std::vector<uint8_t> out(M::kSize);
  Error e = Error::BufferTooSmall;
  REQUIRE(encode(m, out.data(), out.size(), &e) == M::kSize);
  REQUIRE(e == Error::None);
  return out;
}
}  // namespace

TEST_CASE("hello golden vector") {
  Hello m;
  set_str(m.arch, "aarch64");
  set_str(m.cpu_model, "cortex-a53");
  set_str(m.compiler, "gcc 12.2.0");
  set_str(m.build, "Release -O2 -static");
  m.solver_mode = 1;
  m.solver_max_iter = 100;
  m.solver_tol = 1e-8;
  m.horizon = {30, 15, 12};
  m.period_s = {30.0, 20.0, 5.0};
  m.deadline_fraction = 0.5;
  m.pid = 4242;
  m.session = 1;
  CHECK(encoded(m) == golden("hello"));
  Hello d;
  auto g = golden("hello");
  REQUIRE(decode(g.data(), g.size(), d) == Error::None);
  CHECK(get_str(d.cpu_model) == "cortex-a53");
  CHECK(d.horizon[2] == 12);
}

TEST_CASE("nav golden vector") {
  Nav m;
  m.step = 7;
  m.flags = 1;
  m.t_s = 210.0;
  m.position_lvlh_m = {140.0, -1580.0, 60.0};
  m.velocity_lvlh_mps = {-0.9, -0.32, 0.0};
  m.q_lvlh_body = {0.7071067811865476, 0.0, 0.0, -0.7071067811865476};
  m.omega_body_rad_s = {0.0, 0.0, 0.004363323129985824};
  CHECK(encoded(m) == golden("nav"));
  Nav d;
  auto g = golden("nav");
  REQUIRE(decode(g.data(), g.size(), d) == Error::None);
  CHECK(d.position_lvlh_m[1] == -1580.0);
  CHECK(d.omega_body_rad_s[2] == 0.004363323129985824);
}

TEST_CASE("cmd golden vector") {
  Cmd m;
  m.step = 7;
  m.phase = 2;
  m.guidance_status = 1;
  m.solver_status = 1;
  m.overrun = 1;
  m.period_s = 20.0;
  m.dv_cmd_lvlh_mps = {0.01, -0.02, 0.0};
  m.dv_alloc_lvlh_mps = {0.0099, -0.0201, 0.0};
  m.pulse_s = {0.2772, 0.0, 0.0, 0.5628, 0.0, 0.0};
  m.solve_time_us = 123.5;
  m.step_time_us = 150.25;
  m.instructions = 987654321;
  m.iterations = 17;
  m.overruns = 3;
  m.primal_residual = 1e-9;
  m.dual_residual = 2e-10;
  m.objective = -42.5;
  CHECK(encoded(m) == golden("cmd"));
}

TEST_CASE("telemetry and bye golden vectors") {
  Telemetry t;
  t.steps = {60, 15, 63};
  t.overruns = {0, 1, 0};
  t.mean_solve_us = {45.5, 30.25, 12.0};
  t.max_solve_us = {90.0, 60.5, 20.75};
  t.max_step = {12, 70, 100};
  t.total_instructions = {1000000, 2000000, 3000000};
  t.peak_heap_bytes = 524288;
  t.max_rss_kb = 4096;
  t.nav_rejected = 2;
  t.nav_duplicates = 5;
  CHECK(encoded(t) == golden("telemetry"));
  Bye b;
  b.reason = 1;
  b.last_step = 137;
  set_str(b.text, "docked: 0.08 m from port");
  CHECK(encoded(b) == golden("bye"));
}

TEST_CASE("malformed bytes are rejected, never read out of bounds") {
  auto g = golden("nav");
  Nav d;
  CHECK(decode(nullptr, 0, d) == Error::TooShort);
  CHECK(decode(g.data(), 5, d) == Error::TooShort);
  CHECK(decode(g.data(), g.size() - 1, d) == Error::BadSize);
  auto bad = g;
  bad[0] = 'X';
  CHECK(decode(bad.data(), bad.size(), d) == Error::BadMagic);
  bad = g;
  bad[3] = 2;
  CHECK(decode(bad.data(), bad.size(), d) == Error::BadVersion);
  bad = g;
  bad[4] = 99;
  CHECK(decode(bad.data(), bad.size(), d) == Error::UnknownType);
  Cmd c;
  CHECK(decode(g.data(), g.size(), c) == Error::WrongType);
  // Every truncation and every single-byte header corruption is rejected without crashing.
  for (size_t n = 0; n < g.size(); ++n) CHECK(decode(g.data(), n, d) != Error::None);
}

TEST_CASE("NaN and Inf never cross the wire") {
  Nav m;
  m.position_lvlh_m[0] = std::nan("");
  uint8_t buf[Nav::kSize];
  Error e = Error::None;
  CHECK(encode(m, buf, sizeof buf, &e) == 0);
  CHECK(e == Error::NonFinite);
  auto g = golden("nav");
  const double inf = HUGE_VAL;
  uint64_t bits;
  std::memcpy(&bits, &inf, 8);
  for (int i = 0; i < 8; ++i) g[kHeaderSize + 16 + i] = static_cast<uint8_t>(bits >> (8 * i));  // position x
  Nav d;
  CHECK(decode(g.data(), g.size(), d) == Error::NonFinite);
  CHECK(encode(Nav{}, buf, 10, &e) == 0);
  CHECK(e == Error::BufferTooSmall);
}
