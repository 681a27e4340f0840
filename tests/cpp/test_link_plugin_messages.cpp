// The C++ side of the configuration and guidance-law messages: the golden byte vectors of
// schema/golden.toml ([config], [law]), and a config from the host opened by the flight software.
#include <doctest/doctest.h>

#include <array>
#include <fstream>
#include <string>
#include <vector>

#include "flight_sw/link/messages.hpp"
#include "tests/cpp/golden_vectors.hpp"

using namespace rvd::msg;

namespace {
using golden_vectors::auth_for;
using golden_vectors::sealed;
std::vector<uint8_t> golden(const std::string& name) { return golden_vectors::vector_of(name); }
}  // namespace

TEST_CASE("config golden vector (the flight software's echo)") {
  Config m;
  m.mass_kg = 20.0;
  m.thrust_n = 1.0;
  m.min_impulse_bit_s = 0.01;
  m.horizon = {30, 15, 12};
  m.pinned = 2;
  m.period_s = {30.0, 20.0, 5.0};
  m.u_max_mps = {0.1786, 0.1786, 0.0357};
  set_str(m.law, "fast_mpc_3phase");
  set_str(m.settings, "rendezvous.N=30;recovery=off");
  CHECK(sealed(m, Role::Flight, 2) == golden("config"));
  auto g = golden("config");
  Config d;
  LinkAuth host = auth_for(Role::Host);
  REQUIRE(receive(host, g.data(), g.size(), d) == Error::None);
  CHECK(d.thrust_n == 1.0);
  CHECK(get_str(d.settings) == "rendezvous.N=30;recovery=off");
  // The flight software does not take its own echo as a config from the host.
  LinkAuth flight = auth_for(Role::Flight);
  CHECK(receive(flight, g.data(), g.size(), d) == Error::BadTag);
}

TEST_CASE("law golden vector") {
  Law m;
  m.step = 42;
  m.fault = 2;
  m.n_values = 2;
  m.faults = 3;
  set_str(m.names, "dv_norm_mps,tgo_s");
  m.values[0] = 0.125;
  m.values[1] = 600.5;
  CHECK(sealed(m, Role::Flight, 43) == golden("law"));
}
