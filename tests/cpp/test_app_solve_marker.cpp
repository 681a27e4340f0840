// rvd::SolveMarker without the counting plugin (native, or under plain QEMU via the cross ctest):
// it must never fail, never disturb errno, report no count and switch itself off.
// The counts themselves are checked under the plugin by tests/test_qemu_plugin.py.
#include <doctest/doctest.h>

#include <cerrno>
#include <csignal>
#include <cstddef>

#if defined(__linux__)
#include <linux/filter.h>
#include <linux/seccomp.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>
#endif

#include "flight_sw/app/solve_marker.hpp"

#ifndef RVD_TEST_TARGET_ARM
#error "tests/cpp/CMakeLists.txt passes RVD_TEST_TARGET_ARM from CMAKE_SYSTEM_PROCESSOR"
#endif

namespace {
#if defined(__linux__)
volatile std::sig_atomic_t g_marker_calls = 0;
void on_sigsys(int, siginfo_t* info, void*) {
  if (info->si_syscall == rvd::kSolveMarkerSyscall) g_marker_calls = g_marker_calls + 1;
}

// Marker syscalls made by f, counted in a child process whose seccomp filter turns exactly that
// syscall number into SIGSYS (the kernel then does not run it); -1 when seccomp is unavailable
// (qemu-user refuses PR_SET_SECCOMP, so the cross ctest under QEMU cannot count).
template <class F>
int marker_syscalls(F f) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    struct sigaction sa {};
    sa.sa_sigaction = on_sigsys;
    sa.sa_flags = SA_SIGINFO;
    ::sigaction(SIGSYS, &sa, nullptr);
    sock_filter filter[] = {
        BPF_STMT(BPF_LD | BPF_W | BPF_ABS, offsetof(seccomp_data, nr)),
        BPF_JUMP(BPF_JMP | BPF_JEQ | BPF_K, static_cast<unsigned>(rvd::kSolveMarkerSyscall), 0, 1),
        BPF_STMT(BPF_RET | BPF_K, SECCOMP_RET_TRAP),
        BPF_STMT(BPF_RET | BPF_K, SECCOMP_RET_ALLOW)};
    sock_fprog prog{static_cast<unsigned short>(sizeof filter / sizeof filter[0]), filter};
    if (::prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0 || ::prctl(PR_SET_SECCOMP, SECCOMP_MODE_FILTER, &prog) != 0)
      ::_exit(255);
    f();
    ::_exit(g_marker_calls);
  }
  int status = 0;
  if (pid < 0 || ::waitpid(pid, &status, 0) != pid || !WIFEXITED(status)) return -2;
  return WEXITSTATUS(status) == 255 ? -1 : WEXITSTATUS(status);
}
#endif

void begin_end_twice(rvd::SolveMarker& m) {
  for (std::uint32_t step = 0; step < 2; ++step) {
    m.begin(step);
    (void)m.end(step);
  }
}
}  // namespace

// The expectation comes from the build system's idea of the target processor (CMAKE_SYSTEM_PROCESSOR
// of the toolchain file), not from the compiler macros solve_marker.hpp tests.
TEST_CASE("markers are on by default exactly on the ARM builds QEMU emulates") {
  CHECK(rvd::kSolveMarkersByDefault == (RVD_TEST_TARGET_ARM != 0));
#if defined(__linux__)
  // What a default marker does, seen by the kernel: on ARM it probes once (no plugin: ENOSYS, off),
  // on the host it makes no syscall at all. An enabled marker first shows that the count works.
  const int enabled = marker_syscalls([] {
    rvd::SolveMarker m(true);
    begin_end_twice(m);
  });
  if (enabled == -1) {
    MESSAGE("seccomp unavailable here (qemu-user): marker syscalls not counted in this build");
  } else {
    CHECK(enabled == 1);  // the probe, then off
    const int by_default = marker_syscalls([] {
      rvd::SolveMarker m;
      begin_end_twice(m);
    });
    CHECK(by_default == (RVD_TEST_TARGET_ARM ? 1 : 0));
  }
#endif
}

TEST_CASE("a disabled marker reports no count") {
  rvd::SolveMarker marker(false);
  errno = EAGAIN;
  marker.begin(7);
  const std::uint64_t count = marker.end(7);
  const int after = errno;  // read before any CHECK: doctest's own output may set errno
  CHECK(count == 0);
  CHECK_FALSE(marker.counting());
  CHECK(after == EAGAIN);
}

TEST_CASE("an enabled marker without the plugin gets ENOSYS, keeps errno and switches off") {
  rvd::SolveMarker marker(true);
  for (std::uint32_t step = 0; step < 3; ++step) {
    errno = EINTR;
    marker.begin(step);
    const std::uint64_t count = marker.end(step);
    const int after = errno;  // read before any CHECK: doctest's own output may set errno
    CHECK(count == 0);
    CHECK(after == EINTR);
    CHECK_FALSE(marker.counting());
  }
}

TEST_CASE("end without begin is harmless") {
  rvd::SolveMarker marker(true);
  CHECK(marker.end(3) == 0);
  CHECK_FALSE(marker.counting());
}
