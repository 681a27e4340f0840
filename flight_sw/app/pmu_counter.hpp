// User-mode instruction counts from the CPU's performance monitoring unit (Linux perf_event_open).
// Used in QEMU system mode, where QEMU's emulated PMU counts retired instructions exactly under
// -icount and excludes the kernel's (interrupt) work, so the count of a solve repeats run after run.
// open() fails cleanly where there is no PMU (e.g. QEMU's Cortex-A9 model): counts are then 0.
#pragma once

#include <cstdint>
#include <cstring>
#include <string>

#if defined(__linux__)
#include <linux/perf_event.h>
#include <sys/ioctl.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif

namespace rvd {

class PmuCounter {
 public:
  PmuCounter() = default;
  PmuCounter(const PmuCounter&) = delete;
  PmuCounter& operator=(const PmuCounter&) = delete;
  ~PmuCounter() { close_fd(); }

  // True when the counter is usable; else error() says why.
  bool open() {
#if defined(__linux__)
    struct perf_event_attr attr;
    std::memset(&attr, 0, sizeof attr);
    attr.type = PERF_TYPE_HARDWARE;
    attr.size = sizeof attr;
    attr.config = PERF_COUNT_HW_INSTRUCTIONS;
    attr.disabled = 1;
    attr.exclude_kernel = 1;  // the solve's own instructions, not the interrupts that hit it
    attr.exclude_hv = 1;
    fd_ = static_cast<int>(::syscall(SYS_perf_event_open, &attr, 0, -1, -1, 0));
    if (fd_ < 0) error_ = std::string("perf_event_open: ") + std::strerror(errno);
    return fd_ >= 0;
#else
    error_ = "no perf events on this platform";
    return false;
#endif
  }
  bool usable() const { return fd_ >= 0; }
  const std::string& error() const { return error_; }

  void start() {
#if defined(__linux__)
    if (fd_ < 0) return;
    ::ioctl(fd_, PERF_EVENT_IOC_RESET, 0);
    ::ioctl(fd_, PERF_EVENT_IOC_ENABLE, 0);
#endif
  }
  // Instructions since start(); 0 when unusable.
  uint64_t stop() {
#if defined(__linux__)
    if (fd_ < 0) return 0;
    ::ioctl(fd_, PERF_EVENT_IOC_DISABLE, 0);
    uint64_t n = 0;
    if (::read(fd_, &n, sizeof n) != static_cast<ssize_t>(sizeof n)) return 0;
    return n;
#else
    return 0;
#endif
  }

 private:
  void close_fd() {
#if defined(__linux__)
    if (fd_ >= 0) ::close(fd_);
#endif
    fd_ = -1;
  }
  int fd_ = -1;
  std::string error_;
};

}  // namespace rvd
