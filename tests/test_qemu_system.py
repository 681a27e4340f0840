"""QEMU system mode on the Raspberry Pi 3 (virt, Cortex-A53) and the Q7S (vexpress-a9,
Cortex-A9): boot a Debian kernel with the project's initramfs, run the probe, power off.

Checked: the program's exit status comes back; with -icount shift=s the in-guest steady_clock
advances 2^s nanoseconds per instruction (the timed loop is 2 x SPIN instructions) and gives
identical readings in two boots; the guest reaches a TCP echo server on the host at 10.0.2.2,
by address and by the name rvd-host from the initramfs's /etc/hosts.

Needs the ARM kernels and busybox (downloads that belong to `make pil`): skipped until
`python -m rvd_pil.qemu prepare` has run, or set RVD_QEMU_FETCH=1 to let the test fetch them.
"""
from __future__ import annotations

import re
import socket
import threading

import pytest

from rvd_pil.qemu import build, system, targets
from support.system_mode import system_mode_or_skip

pytestmark = [pytest.mark.qemu, pytest.mark.slow]

SPIN = 500_000
REPEAT = 3


@pytest.fixture(scope="module")
def echo_server():
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(None)
    seen = []

    def serve():
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            with conn:
                data = b""
                while len(data) < 64 and (chunk := conn.recv(64 - len(data))):
                    data += chunk
                conn.sendall(data)
                seen.append(len(data))

    threading.Thread(target=serve, daemon=True).start()
    yield server.getsockname()[1], seen
    server.close()


@pytest.fixture(scope="module", params=["rpi3", "q7s"])
def booted(request):
    target, img = system_mode_or_skip(request.param)
    return target, img, build.cross_build(target, "qemu_probe").path


def _timings(run):
    return [int(m.group(1)) for l in run.output if (m := re.fullmatch(r"timing spin=\d+ ns=(\d+)", l))]


def test_boot_run_power_off_with_deterministic_guest_time_and_host_tcp(booted, echo_server):
    target, img, exe = booted
    port, seen = echo_server
    args = ["timing", str(SPIN), str(REPEAT), "echo", "10.0.2.2", str(port), "echo", "rvd-host", str(port)]
    runs = [system.run(target, exe, args, img=img, timeout_s=240) for _ in range(2)]
    for r in runs:
        assert not r.timed_out and r.exit_code == 0, r.console[-3000:]
        assert r.output.count("echo ok bytes=64") == 2
        assert r.boot_s is not None and r.qemu_returncode == 0  # powered off, not killed
    first, second = (_timings(r) for r in runs)
    assert len(first) == REPEAT
    # Bit-identical in-guest times from boot to boot...
    assert first == second
    # ...and 2^shift guest nanoseconds per instruction: the loop is exactly 2*SPIN instructions;
    # the clock read itself and a timer interrupt may add a little. vexpress-a9's clock ticks in us.
    # The fastest repetition is the bare loop; others may also hold kernel work (a timer tick,
    # deferred work after boot), the same in both boots.
    per_insn_ns = 2 ** target.system.icount_shift
    assert per_insn_ns * (2 * SPIN - 1000) <= min(first) <= per_insn_ns * (2 * SPIN * 1.05 + 1000), first
    assert seen.count(64) >= 4


def test_kernel_command_line_carries_the_arguments():
    t = targets.load("rpi3")
    line = system.kernel_command_line(t, ["--run", "a b", "7"])
    assert line.endswith('-- --run "a b" 7') and line.startswith("console=ttyAMA0 ")
    with pytest.raises(ValueError):
        system.kernel_command_line(t, ['say "hi"'])
    with pytest.raises(ValueError):
        system.kernel_command_line(t, ["x"] * 31)
    with pytest.raises(ValueError, match="user mode only"):
        system.image(targets.load("beaglebone"))
