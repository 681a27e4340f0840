// rvd::SolveMarker without the counting plugin (native, or under plain QEMU via the cross ctest):
// it must never fail, never disturb errno, report no count and switch itself off.
// The counts themselves are checked under the plugin by tests/test_qemu_plugin.py.
#include <doctest/doctest.h>

#include <cerrno>

#include "flight_sw/app/solve_marker.hpp"

TEST_CASE("markers are on by default exactly on the ARM builds QEMU emulates") {
#if defined(__arm__) || defined(__aarch64__)
  CHECK(rvd::kSolveMarkersByDefault);
#else
  CHECK_FALSE(rvd::kSolveMarkersByDefault);
#endif
}

TEST_CASE("a disabled marker reports no count") {
  rvd::SolveMarker marker(false);
  errno = EAGAIN;
  marker.begin(7);
  CHECK(marker.end(7) == 0);
  CHECK_FALSE(marker.counting());
  CHECK(errno == EAGAIN);
}

TEST_CASE("an enabled marker without the plugin gets ENOSYS, keeps errno and switches off") {
  rvd::SolveMarker marker(true);
  for (std::uint32_t step = 0; step < 3; ++step) {
    errno = EINTR;
    marker.begin(step);
    CHECK(marker.end(step) == 0);
    CHECK(errno == EINTR);
    CHECK_FALSE(marker.counting());
  }
}

TEST_CASE("end without begin is harmless") {
  rvd::SolveMarker marker(true);
  CHECK(marker.end(3) == 0);
  CHECK_FALSE(marker.counting());
}
