// link_auth_bench: what the message tag costs the flight computer, per message type. Driven by
// rvd_pil/bench/link_auth.py, natively (wall time) and under QEMU user mode with the instruction-counting
// plugin (instructions, through the same markers the solves use).
//
//   link_auth_bench [N]     N messages per measurement (default 2000)
//
// For each message: encode alone, encode + seal (the tag), decode alone, open + decode. Output, one
// line per message type:
//   auth msg=nav bytes=152 encode_ns=... seal_ns=... decode_ns=... open_ns=...
//        encode_insns=... seal_insns=... decode_insns=... open_insns=...
// Times are the fastest of 5 rounds per message (ns per message); instructions are per message,
// 0 when no plugin answers the markers (native runs).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "flight_sw/app/solve_marker.hpp"
#include "flight_sw/link/messages.hpp"

using namespace rvd;
using Clock = std::chrono::steady_clock;

namespace {

struct Cost {
  double ns = 0.0;
  unsigned long long insns = 0;
};

// f(i) for i in [0, n): the fastest per-call time over 5 rounds, and instructions per call.
template <class F>
Cost measure(SolveMarker& marker, uint32_t& marker_step, int n, F&& f) {
  Cost c;
  c.ns = 1e300;
  for (int round = 0; round < 5; ++round) {
    const uint32_t step = marker_step++;
    marker.begin(step);
    const auto t0 = Clock::now();
    for (int i = 0; i < n; ++i) {
      f(i);
      asm volatile("" ::: "memory");  // each call's stores and loads happen: nothing is hoisted out of the loop
    }
    const double ns = std::chrono::duration<double, std::nano>(Clock::now() - t0).count() / n;
    const uint64_t insns = marker.end(step);
    if (ns < c.ns) c.ns = ns;
    if (round == 0) c.insns = insns / static_cast<uint64_t>(n);
  }
  return c;
}

volatile uint8_t g_sink;  // keeps the loops from being optimised away

template <class M>
void bench(const char* name, const M& m, int n, SolveMarker& marker, uint32_t& marker_step) {
  uint8_t key[msg::kKeySize];
  for (size_t i = 0; i < sizeof key; ++i) key[i] = static_cast<uint8_t>(i * 13 + 1);
  // The sender is the side that sends M: the host for nav, the flight software for the rest.
  const msg::Role sender = M::kType == msg::Type::Nav ? msg::Role::Host : msg::Role::Flight;
  const msg::Role receiver = sender == msg::Role::Host ? msg::Role::Flight : msg::Role::Host;
  msg::LinkAuth tx(key, sizeof key, "bench-run", sender), rx(key, sizeof key, "bench-run", receiver);
  std::vector<uint8_t> sealed(static_cast<size_t>(n) * 5 * M::kSize);  // every round opens fresh numbers
  uint8_t buf[M::kSize];
  const Cost encode = measure(marker, marker_step, n, [&](int) { g_sink = static_cast<uint8_t>(msg::encode(m, buf, sizeof buf)); });
  size_t next = 0;
  const Cost seal = measure(marker, marker_step, n, [&](int) {
    g_sink = static_cast<uint8_t>(msg::seal(tx, m, sealed.data() + next * M::kSize, M::kSize));
    next = (next + 1) % (static_cast<size_t>(n) * 5);
  });
  M out;
  const Cost decode = measure(marker, marker_step, n, [&](int i) {
    g_sink = static_cast<uint8_t>(msg::decode(sealed.data() + static_cast<size_t>(i) * M::kSize, M::kSize, out));
  });
  size_t opened = 0, ok = 0;
  const Cost open = measure(marker, marker_step, n, [&](int) {
    ok += msg::receive(rx, sealed.data() + opened * M::kSize, M::kSize, out) == msg::Error::None;
    ++opened;
  });
  if (ok != opened) {
    std::fprintf(stderr, "link_auth_bench: %zu of %zu %s messages did not open\n", opened - ok, opened, name);
    std::exit(1);
  }
  std::printf("auth msg=%s bytes=%zu encode_ns=%.1f seal_ns=%.1f decode_ns=%.1f open_ns=%.1f "
              "encode_insns=%llu seal_insns=%llu decode_insns=%llu open_insns=%llu\n",
              name, M::kSize, encode.ns, seal.ns, decode.ns, open.ns, encode.insns, seal.insns, decode.insns,
              open.insns);
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  const int n = argc > 1 ? std::atoi(argv[1]) : 2000;
  if (n <= 0) {
    std::fprintf(stderr, "usage: link_auth_bench [N > 0]\n");
    return 2;
  }
  SolveMarker marker(true);  // answered by the plugin under QEMU, a no-op elsewhere
  uint32_t step = 1;
  msg::Nav nav;
  nav.q_lvlh_body = {1.0, 0.0, 0.0, 0.0};
  nav.position_lvlh_m = {140.0, -1580.0, 60.0};
  bench("nav", nav, n, marker, step);
  msg::Cmd cmd;
  cmd.period_s = 30.0;
  bench("cmd", cmd, n, marker, step);
  bench("telemetry", msg::Telemetry{}, n, marker, step);
  bench("hello", msg::Hello{}, n, marker, step);
  return 0;
}
