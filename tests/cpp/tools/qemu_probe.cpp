// Small guest program that exercises the emulation pieces before the flight executable exists.
// Driven by tests/test_qemu_*.py; commands run in the order given:
//
//   markers STEPS SPIN   for step s = 0..STEPS-1: SolveMarker begin(s), a loop of SPIN*(s+1)
//                        iterations of exactly two instructions, end(s); prints the counts
//   llt N                one marked region: Cholesky (Eigen LLT) of a fixed N x N SPD matrix;
//                        prints its instruction count and steady_clock time
//   timing SPIN REPEAT   REPEAT times: steady_clock around the SPIN-iteration loop; prints ns
//   threaded SPIN        a marked SPIN-iteration loop on the main thread while a second thread
//                        spins 4*SPIN iterations (per-thread counting)
//   wild                 marker calls with a slot pointer into unmapped memory (plugin robustness)
//   echo HOST PORT       TCP connect (HOST: name or address), send 64 bytes, expect them back
//   elapsed NS           one marked region: the flight software's conversion of a steady_clock
//                        duration of NS nanoseconds to microseconds (rvd::solver::FlightClock::to_us)
//   target-clock CPI HZ  the flight clock on target time (FlightClock::use_target); prints which
//                        clock it got (rvd::solver::StepClock)
//   clock SPIN           one marked region: a flight clock reading, the SPIN-iteration loop, another
//                        reading; prints both readings, the elapsed microseconds and the count
//   chrono NS            the same with std::chrono's own conversion (duration<double, micro>)
//   sum KB               one marked region: reads KB kilobytes (at most 64) of a static table
//                        that nothing outside the marked regions touches
//   touch KB             outside any region: read and write KB kilobytes (at most 1024) of another
//                        static buffer, as the link's work between two solves does in miniature
//
// The two-instruction loop is written in assembly so its instruction count is known exactly:
// a marked region of SPIN iterations counts 2*SPIN plus a constant.
#include <Eigen/Dense>

#include <netdb.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>

#include "flight_sw/app/solve_marker.hpp"
#include "flight_sw/solver/elapsed.hpp"

namespace {

// Exactly two instructions per iteration (decrement-and-set-flags, branch if not zero).
void spin(std::uint64_t iterations) {
  if (iterations == 0) return;
#if defined(__aarch64__)
  asm volatile("1: subs %0, %0, #1\n\tb.ne 1b" : "+r"(iterations) : : "cc");
#elif defined(__arm__)
  std::uint32_t n = static_cast<std::uint32_t>(iterations);
  asm volatile("1: subs %0, %0, #1\n\tbne 1b" : "+r"(n) : : "cc");
#elif defined(__x86_64__)
  asm volatile("1: dec %0\n\tjnz 1b" : "+r"(iterations) : : "cc");
#else
  for (volatile std::uint64_t i = 0; i < iterations; i = i + 1) {
  }
#endif
}

bool parse_u64(const char* s, std::uint64_t& out) {
  char* end = nullptr;
  errno = 0;
  unsigned long long v = std::strtoull(s, &end, 10);
  if (errno != 0 || end == s || *end != '\0') return false;
  out = v;
  return true;
}

int run_markers(rvd::SolveMarker& marker, std::uint64_t steps, std::uint64_t spin_base) {
  for (std::uint32_t s = 0; s < steps; ++s) {
    const std::uint64_t iterations = spin_base * (s + 1);
    marker.begin(s);
    spin(iterations);
    const std::uint64_t insns = marker.end(s);
    std::printf("marker step=%u spin=%llu insns=%llu\n", s, static_cast<unsigned long long>(iterations),
                static_cast<unsigned long long>(insns));
  }
  return 0;
}

int run_llt(rvd::SolveMarker& marker, int n, std::uint32_t step) {
  // A fixed, well-conditioned SPD matrix: M'M + n I with M filled by a simple recurrence.
  Eigen::MatrixXd m(n, n);
  std::uint32_t x = 12345;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      x = x * 1103515245u + 12345u;
      m(i, j) = static_cast<double>((x >> 8) % 2001) / 1000.0 - 1.0;
    }
  const Eigen::MatrixXd a = m.transpose() * m + n * Eigen::MatrixXd::Identity(n, n);
  Eigen::LLT<Eigen::MatrixXd> llt(n);  // workspace allocated outside the marked region
  // The clock reads stay outside the counted region (their cost depends on the emulator).
  const auto t0 = std::chrono::steady_clock::now();
  marker.begin(step);
  llt.compute(a);
  const std::uint64_t insns = marker.end(step);
  const auto t1 = std::chrono::steady_clock::now();
  const long long ns = std::chrono::duration_cast<std::chrono::nanoseconds>(t1 - t0).count();
  const Eigen::MatrixXd l = llt.matrixL();
  const double residual = (l * l.transpose() - a).norm() / a.norm();
  std::printf("llt step=%u n=%d insns=%llu ns=%lld residual=%.3g\n", step, n,
              static_cast<unsigned long long>(insns), ns, residual);
  return (llt.info() == Eigen::Success && residual < 1e-12) ? 0 : 1;
}

int run_timing(std::uint64_t spin_iterations, std::uint64_t repeat) {
  for (std::uint64_t r = 0; r < repeat; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    spin(spin_iterations);
    const auto t1 = std::chrono::steady_clock::now();
    const long long ns = std::chrono::duration_cast<std::chrono::nanoseconds>(t1 - t0).count();
    std::printf("timing spin=%llu ns=%lld\n", static_cast<unsigned long long>(spin_iterations), ns);
  }
  return 0;
}

int run_echo(const char* host, std::uint64_t port) {
  // getaddrinfo, as the flight software's link does: in the system-mode guest "rvd-host" comes
  // from the initramfs's /etc/hosts (static glibc reads it without shared NSS modules).
  addrinfo hints{};
  hints.ai_family = AF_INET;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  const std::string service = std::to_string(port);
  if (port == 0 || port > 65535 || getaddrinfo(host, service.c_str(), &hints, &found) != 0) {
    std::fprintf(stderr, "echo: cannot resolve %s:%llu\n", host, static_cast<unsigned long long>(port));
    return 2;
  }
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  const bool connected = fd >= 0 && connect(fd, found->ai_addr, found->ai_addrlen) == 0;
  freeaddrinfo(found);
  if (!connected) {
    std::fprintf(stderr, "echo: connect to %s:%llu failed: %s\n", host,
                 static_cast<unsigned long long>(port), std::strerror(errno));
    if (fd >= 0) close(fd);
    return 1;
  }
  char out[64], in[64];
  for (int i = 0; i < 64; ++i) out[i] = static_cast<char>('A' + i % 26);
  std::size_t got = 0;
  bool ok = send(fd, out, sizeof out, 0) == static_cast<ssize_t>(sizeof out);
  while (ok && got < sizeof in) {
    const ssize_t n = recv(fd, in + got, sizeof in - got, 0);
    if (n <= 0) ok = false;
    else got += static_cast<std::size_t>(n);
  }
  close(fd);
  ok = ok && std::memcmp(in, out, sizeof out) == 0;
  std::printf("echo %s bytes=%zu\n", ok ? "ok" : "failed", got);
  return ok ? 0 : 1;
}

int run_threaded(rvd::SolveMarker& marker, std::uint64_t iterations, std::uint32_t step) {
  std::thread busy([iterations] { spin(4 * iterations); });
  marker.begin(step);
  spin(iterations);
  const std::uint64_t insns = marker.end(step);
  busy.join();
  std::printf("threaded step=%u spin=%llu insns=%llu\n", step, static_cast<unsigned long long>(iterations),
              static_cast<unsigned long long>(insns));
  return 0;
}

// The marker ABI by hand, with a slot address nothing is mapped at: the plugin must refuse to
// write there and carry on (the count still goes to its log).
int run_wild() {
  const long unmapped = 0x1000;  // the first page above NULL is never mapped
  ::syscall(rvd::kSolveMarkerSyscall, 1L, 99L, unmapped);
  spin(1000);
  ::syscall(rvd::kSolveMarkerSyscall, 2L, 99L, unmapped + 8);
  std::printf("wild done\n");
  return 0;
}

// A duration converted inside a marked region. The input is read (volatile) after the begin marker
// and the result stored before the end marker, so the conversion cannot move out of the region.
int run_conversion(rvd::SolveMarker& marker, std::uint64_t ns, bool flight, std::uint32_t step) {
  volatile std::int64_t input = static_cast<std::int64_t>(ns);
  volatile double us = 0.0;
  marker.begin(step);
  const std::chrono::steady_clock::duration d = std::chrono::nanoseconds(input);
  us = flight ? rvd::solver::flight_clock().to_us(d.count()) : std::chrono::duration<double, std::micro>(d).count();
  const std::uint64_t insns = marker.end(step);
  std::printf("%s step=%u ns=%llu us=%.3f insns=%llu\n", flight ? "elapsed" : "chrono", step,
              static_cast<unsigned long long>(ns), static_cast<double>(us), static_cast<unsigned long long>(insns));
  // both conversions are exact up to the final division (ns < 2^53): the same double
  return us == std::chrono::duration<double, std::micro>(d).count() ? 0 : 1;
}

// Two flight clock readings around the loop, inside one marked region: with the target clock
// their difference is the loop's instructions plus the reading's own, to the instruction.
int run_clock(rvd::SolveMarker& marker, std::uint64_t iterations, std::uint32_t step) {
  rvd::solver::FlightClock& clock = rvd::solver::flight_clock();
  marker.begin(step);
  const rvd::solver::TimePoint t0 = clock.now();
  spin(iterations);
  const rvd::solver::TimePoint t1 = clock.now();
  const std::uint64_t insns = marker.end(step);
  std::printf("clock step=%u spin=%llu source=%d t0=%lld t1=%lld us=%.17g insns=%llu\n", step,
              static_cast<unsigned long long>(iterations), static_cast<int>(clock.source()),
              static_cast<long long>(t0.ticks), static_cast<long long>(t1.ticks), clock.to_us(t1.ticks - t0.ticks),
              static_cast<unsigned long long>(insns));
  return t1.epoch == t0.epoch && t1.ticks > t0.ticks ? 0 : 1;
}

int run_sum(rvd::SolveMarker& marker, std::uint64_t kb, std::uint32_t step) {
  static volatile double table[64 * 1024 / sizeof(double)];
  const std::uint64_t n = kb * 1024 / sizeof(double);
  marker.begin(step);
  double sum = 0.0;
  for (std::uint64_t i = 0; i < n; ++i) sum += table[i];
  const std::uint64_t insns = marker.end(step);
  std::printf("sum step=%u kb=%llu sum=%g insns=%llu\n", step, static_cast<unsigned long long>(kb), sum,
              static_cast<unsigned long long>(insns));
  return 0;
}

int run_touch(std::uint64_t kb) {
  static volatile std::uint8_t buffer[1024 * 1024];
  for (std::uint64_t i = 0; i < kb * 1024; i += 16) buffer[i] = static_cast<std::uint8_t>(buffer[i] + 1);
  std::printf("touch kb=%llu\n", static_cast<unsigned long long>(kb));
  return 0;
}

int usage() {
  std::fprintf(stderr,
               "usage: qemu_probe [markers STEPS SPIN] [llt N] [timing SPIN REPEAT] [threaded SPIN] [wild] "
               "[echo HOST PORT] [elapsed NS] [chrono NS] [target-clock CPI HZ] [clock SPIN] [sum KB] [touch KB]...\n");
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  rvd::SolveMarker marker;
  std::uint32_t next_step = 0;
  int status = 0;
  for (int i = 1; i < argc && status == 0;) {
    const std::string cmd = argv[i];
    std::uint64_t a = 0, b = 0;
    if (cmd == "markers" && i + 2 < argc && parse_u64(argv[i + 1], a) && parse_u64(argv[i + 2], b)) {
      status = run_markers(marker, a, b);
      next_step += static_cast<std::uint32_t>(a);
      i += 3;
    } else if (cmd == "llt" && i + 1 < argc && parse_u64(argv[i + 1], a) && a > 0 && a <= 2000) {
      status = run_llt(marker, static_cast<int>(a), next_step++);
      i += 2;
    } else if (cmd == "timing" && i + 2 < argc && parse_u64(argv[i + 1], a) && parse_u64(argv[i + 2], b)) {
      status = run_timing(a, b);
      i += 3;
    } else if (cmd == "threaded" && i + 1 < argc && parse_u64(argv[i + 1], a)) {
      status = run_threaded(marker, a, next_step++);
      i += 2;
    } else if (cmd == "wild") {
      status = run_wild();
      i += 1;
    } else if (cmd == "echo" && i + 2 < argc && parse_u64(argv[i + 2], a)) {
      status = run_echo(argv[i + 1], a);
      i += 3;
    } else if ((cmd == "elapsed" || cmd == "chrono") && i + 1 < argc && parse_u64(argv[i + 1], a) &&
               a < (1ULL << 53)) {
      status = run_conversion(marker, a, cmd == "elapsed", next_step++);
      i += 2;
    } else if (cmd == "target-clock" && i + 2 < argc) {
      const double cpi = std::strtod(argv[i + 1], nullptr), hz = std::strtod(argv[i + 2], nullptr);
      std::printf("target-clock source=%d\n", static_cast<int>(rvd::solver::flight_clock().use_target(cpi, hz)));
      i += 3;
    } else if (cmd == "clock" && i + 1 < argc && parse_u64(argv[i + 1], a)) {
      status = run_clock(marker, a, next_step++);
      i += 2;
    } else if (cmd == "sum" && i + 1 < argc && parse_u64(argv[i + 1], a) && a <= 64) {
      status = run_sum(marker, a, next_step++);
      i += 2;
    } else if (cmd == "touch" && i + 1 < argc && parse_u64(argv[i + 1], a) && a <= 1024) {
      status = run_touch(a);
      i += 2;
    } else {
      return usage();
    }
  }
  std::printf("counting=%d status=%d\n", marker.counting() ? 1 : 0, status);
  return status;
}
