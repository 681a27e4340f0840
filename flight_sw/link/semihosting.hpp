// ARM semihosting file calls (ARM DUI 0471 / "Semihosting for AArch32 and AArch64"): the program
// asks the emulator to open, read and write files on the host. Under QEMU (system mode with
// -semihosting-config enable=on,userspace=on,target=native) each call runs inside one guest
// instruction: the emulated CPU stops while the host's read() blocks, so with -icount no guest
// time passes while the guest waits for the host. That makes a lockstep loop over host files
// (FIFOs) deterministic in guest time, which no guest network stack can be.
//
// Only meaningful under such an emulator: available() probes once, catching the SIGILL (AArch64
// HLT) or ENOSYS (AArch32 SVC) that real hardware or an emulator without semihosting gives.
#pragma once

#include <cstddef>
#include <string>

namespace rvd::link::semihosting {

// True when semihosting calls reach a host (probed on first use, then cached).
bool available();

// Opens `host_path` on the host: for_writing false = "rb", true = "wb". Returns a handle >= 0,
// or -1 (errno_text() then tells why).
long open(const std::string& host_path, bool for_writing);
void close(long handle);

// Reads up to `size` bytes (blocking until at least one arrives, like read() on a FIFO).
// Returns the byte count, 0 at end of file, -1 on error.
long read(long handle, void* data, size_t size);
// Writes all `size` bytes. Returns false on error.
bool write(long handle, const void* data, size_t size);

std::string errno_text();  // the host's errno of the last failed call, as text

}  // namespace rvd::link::semihosting
