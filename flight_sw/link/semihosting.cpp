// ARM semihosting calls (see semihosting.hpp).
#include "flight_sw/link/semihosting.hpp"

#include <csetjmp>
#include <csignal>
#include <cstdint>
#include <cstring>

namespace rvd::link::semihosting {
namespace {

// Operation numbers of the semihosting specification.
constexpr long kSysOpen = 0x01, kSysClose = 0x02, kSysWrite = 0x05, kSysRead = 0x06, kSysTime = 0x11,
               kSysErrno = 0x13;
using Word = uintptr_t;  // a parameter block holds target-sized words

long call(long op, const Word* params) {
#if defined(__aarch64__)
  register long x0 asm("x0") = op;
  register const Word* x1 asm("x1") = params;
  asm volatile("hlt #0xf000" : "+r"(x0) : "r"(x1) : "memory");
  return x0;
#elif defined(__arm__)
  // Without semihosting the SVC is a Linux system call: r7 = -1 makes it a harmless ENOSYS.
  register long r0 asm("r0") = op;
  register const Word* r1 asm("r1") = params;
  register long r7 asm("r7") = -1;
#if defined(__thumb__)
  asm volatile("svc 0xab" : "+r"(r0) : "r"(r1), "r"(r7) : "memory");
#else
  asm volatile("svc 0x123456" : "+r"(r0) : "r"(r1), "r"(r7) : "memory");
#endif
  return r0;
#else
  (void)op;
  (void)params;
  return -1;
#endif
}

#if defined(__aarch64__) || defined(__arm__)
sigjmp_buf probe_jump;
void on_probe_sigill(int) { siglongjmp(probe_jump, 1); }
#endif

bool probe() {
#if defined(__aarch64__) || defined(__arm__)
  struct sigaction sa {}, old {};
  sa.sa_handler = on_probe_sigill;
  sigemptyset(&sa.sa_mask);
  if (sigaction(SIGILL, &sa, &old) != 0) return false;
  bool ok = false;
  if (sigsetjmp(probe_jump, 1) == 0) {
    const long t = call(kSysTime, nullptr);  // seconds since the epoch on the host
    ok = t > 0;                              // AArch32 without semihosting: -ENOSYS
  }
  sigaction(SIGILL, &old, nullptr);
  return ok;
#else
  return false;
#endif
}

}  // namespace

bool available() {
  static const bool ok = probe();
  return ok;
}

long open(const std::string& host_path, bool for_writing) {
  if (!available()) return -1;
  const Word params[3] = {reinterpret_cast<Word>(host_path.c_str()), for_writing ? Word{5} : Word{1},
                          host_path.size()};  // mode 1 = "rb", 5 = "wb"
  return call(kSysOpen, params);
}

void close(long handle) {
  if (handle < 0 || !available()) return;
  const Word params[1] = {static_cast<Word>(handle)};
  call(kSysClose, params);
}

long read(long handle, void* data, size_t size) {
  if (!available()) return -1;
  const Word params[3] = {static_cast<Word>(handle), reinterpret_cast<Word>(data), size};
  const long not_read = call(kSysRead, params);  // the specification returns what was NOT read
  if (not_read < 0 || static_cast<size_t>(not_read) > size) return -1;
  return static_cast<long>(size - static_cast<size_t>(not_read));
}

bool write(long handle, const void* data, size_t size) {
  if (!available()) return false;
  const Word params[3] = {static_cast<Word>(handle), reinterpret_cast<Word>(data), size};
  return call(kSysWrite, params) == 0;  // bytes NOT written
}

std::string errno_text() {
  if (!available()) return "semihosting is not available (run under QEMU with -semihosting-config enable=on,userspace=on)";
  const long e = call(kSysErrno, nullptr);
  return e > 0 ? std::strerror(static_cast<int>(e)) : "unknown error";
}

}  // namespace rvd::link::semihosting
