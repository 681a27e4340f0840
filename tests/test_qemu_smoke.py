"""QEMU user-mode smoke test, part of `make test`: the target registry, a cross build for the Q7S
(armhf, Cortex-A9; the cross compiler and qemu-user come with tools/install-deps test), the C++
tests under qemu-arm through ctest, and the probe program (solve markers without the plugin,
TCP to the host) under qemu-arm."""
from __future__ import annotations

import json
import shutil
import socket
import struct
import subprocess
import threading

import pytest

from rvd_pil.qemu import build, targets, user

pytestmark = pytest.mark.qemu


# ------------------------------------------------------------------------------- registry
def test_registry_describes_every_target():
    assert set(targets.names()) == {"rpi3", "q7s", "beaglebone", "rpi4", "host"}
    q7s = targets.load("q7s")
    assert (q7s.arch, q7s.cpu, q7s.clock_hz) == ("armhf", "cortex-a9", 766e6)
    # Cortex-A9 has VFPv3: a VFPv4 build (vfma) would die with SIGILL on the Q7S.
    assert q7s.compile_flags == ["-mcpu=cortex-a9", "-mfpu=neon", "-mfloat-abi=hard"]
    assert (q7s.qemu_user, q7s.qemu_cpu, q7s.system.machine) == ("qemu-arm", "cortex-a9", "vexpress-a9")
    rpi3 = targets.load("rpi3")
    assert (rpi3.arch, rpi3.qemu_user, rpi3.qemu_cpu, rpi3.clock_hz) == ("aarch64", "qemu-aarch64", "cortex-a53", 1.2e9)
    assert rpi3.system.machine == "virt" and "dtb-randomness=off" in rpi3.system.machine_options
    assert targets.load("beaglebone").system is None  # no AM335x machine in QEMU 7.2
    assert not targets.load("host").emulated
    for name in targets.names():
        t = targets.load(name)
        if t.emulated:
            assert 0 < t.cpi.low <= t.cpi.nominal <= t.cpi.high and t.cpi.basis and t.clock_source
            assert t.toolchain_file.exists()


def test_target_time_is_instructions_times_cpi_over_clock():
    q7s = targets.load("q7s")
    nominal, low, high = q7s.target_time_s(7.66e6)  # 1/100 s of cycles at CPI 1
    assert nominal == pytest.approx(q7s.cpi.nominal / 100)
    assert (low, high) == (pytest.approx(q7s.cpi.low / 100), pytest.approx(q7s.cpi.high / 100))
    with pytest.raises(ValueError, match="no CPI model"):
        targets.load("host").target_time_s(1)


def test_cpu_model_can_be_swapped_by_argument_or_environment(monkeypatch):
    a8 = targets.load("q7s", cpu="cortex-a8")
    assert (a8.qemu_cpu, a8.clock_hz, a8.build_name) == ("cortex-a8", 766e6, "q7s-cortex-a8")
    assert a8.cpi == targets.load("beaglebone").cpi
    # vexpress-a9's A9MPCore peripherals take no other core: the override leaves user mode only, and says so
    assert targets.load("q7s").system is not None and a8.system is None
    assert "vexpress-a9" in a8.system_note and "cortex-a8" in a8.system_note
    monkeypatch.setenv(targets.CPU_ENV, "cortex-a72")
    assert targets.load("rpi3").qemu_cpu == "cortex-a72"
    with pytest.raises(ValueError, match="is aarch64, target 'q7s' is armhf"):
        targets.load("q7s")
    with pytest.raises(ValueError, match="unknown CPU 'cortex-a99'"):
        targets.load("rpi3", cpu="cortex-a99")
    with pytest.raises(ValueError, match="unknown target"):
        targets.load("pi5")


def test_qemu_enforces_the_cpu_model(tmp_path):
    """The emulated CPU model is what keeps a wrong build honest: one VFPv4 instruction (vfma, as
    GCC emits for -mfpu=neon-vfpv4) runs on a Cortex-A7 and dies with SIGILL on a Cortex-A9."""
    src = tmp_path / "vfma.c"
    src.write_text('int main(void) { __asm__ volatile("vfma.f64 d0, d1, d2"); return 0; }\n')
    exe = tmp_path / "vfma"
    subprocess.run(["arm-linux-gnueabihf-gcc", "-static", "-O1", "-mcpu=cortex-a7", "-mfpu=neon-vfpv4",
                    "-mfloat-abi=hard", str(src), "-o", str(exe)], check=True)
    assert subprocess.run(["qemu-arm", "-cpu", "cortex-a7", str(exe)]).returncode == 0
    a9 = subprocess.run(["qemu-arm", "-cpu", "cortex-a9", str(exe)], capture_output=True)
    assert a9.returncode in (-4, 132), a9  # SIGILL


# ------------------------------------------------------------------------------- cross build
@pytest.fixture(scope="module")
def q7s_build():
    for tool in ("qemu-arm", "arm-linux-gnueabihf-g++", "cmake", "ctest"):
        assert shutil.which(tool), f"{tool} is missing: run tools/install-deps test"
    target = targets.load("q7s", cpu="cortex-a9")
    bdir = build.configure(target)
    probe = build.build(bdir, ["qemu_probe"])["qemu_probe"]
    try:
        build.build(bdir)  # everything else: C++ tests, tools, the flight executable
        build_error = None
    except RuntimeError as exc:  # reported by the ctest test; the probe tests still run
        build_error = str(exc)
    return target, bdir, probe, build_error


def _elf_summary(path):
    """(class, machine, ARM hard-float flag, has PT_INTERP) from the ELF header."""
    data = path.read_bytes()
    assert data[:4] == b"\x7fELF"
    elf_class = data[4]
    machine, = struct.unpack_from("<H", data, 18)
    if elf_class == 1:
        phoff, flags = struct.unpack_from("<I", data, 28)[0], struct.unpack_from("<I", data, 36)[0]
        phentsize, phnum = struct.unpack_from("<HH", data, 42)
    else:
        phoff, flags = struct.unpack_from("<Q", data, 32)[0], struct.unpack_from("<I", data, 48)[0]
        phentsize, phnum = struct.unpack_from("<HH", data, 54)
    types = [struct.unpack_from("<I", data, phoff + i * phentsize)[0] for i in range(phnum)]
    return elf_class, machine, bool(flags & 0x400), 3 in types  # EF_ARM_ABI_FLOAT_HARD, PT_INTERP


def test_cross_build_is_static_hard_float_arm(q7s_build):
    _, _, probe, _ = q7s_build
    elf_class, machine, hard_float, dynamic = _elf_summary(probe.path)
    assert (elf_class, machine) == (1, 40)  # 32-bit ARM
    assert hard_float and not dynamic
    assert probe.size_bytes == probe.path.stat().st_size > 0


def test_cpp_tests_pass_under_qemu_arm(q7s_build):
    _, bdir, _, build_error = q7s_build
    assert build_error is None, build_error
    shown = json.loads(subprocess.run(["ctest", "--show-only=json-v1"], cwd=bdir, capture_output=True,
                                      text=True, check=True).stdout)
    assert len(shown["tests"]) >= 2
    for t in shown["tests"]:  # every test runs through the emulator with the pinned CPU model
        assert t["command"][0].endswith("qemu-arm") and t["command"][1:3] == ["-cpu", "cortex-a9"], t
    result = build.ctest(bdir)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "100% tests passed" in result.stdout


def test_probe_under_qemu_user_without_plugin_and_tcp_to_host(q7s_build):
    target, _, probe, _ = q7s_build
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def echo_once():
        conn, _ = server.accept()
        with conn:
            data = b""
            while len(data) < 64 and (chunk := conn.recv(64 - len(data))):
                data += chunk
            conn.sendall(data)

    thread = threading.Thread(target=echo_once, daemon=True)
    thread.start()
    cmd = user.command(target, probe.path, ["markers", "3", "1000", "llt", "20", "echo", "127.0.0.1", str(port)])
    assert cmd[:3] == ["qemu-arm", "-cpu", "cortex-a9"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    server.close()
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    # Without the plugin the marker syscall gets ENOSYS: no counts, nothing breaks.
    assert [l.split()[-1] for l in lines if l.startswith("marker")] == ["insns=0"] * 3
    assert any(l.startswith("llt step=3 n=20 insns=0") for l in lines)
    assert "echo ok bytes=64" in lines
    assert lines[-1] == "counting=0 status=0"


# ------------------------------------------------------------------------------- PIL under QEMU
def test_case1_closed_loop_under_qemu_user_equals_native(q7s_build, flight_exe, tmp_path):
    """The whole loop (host_sim over Zenoh to the flight executable) with the Q7S build under
    qemu-arm -cpu cortex-a9: Case 1 in the ideal setting docks with the native run's delta-v to
    1e-6 m/s and the same number of steps. (Cortex-A9 has no fused multiply-add and its libm is
    another build, so the last bits differ: the agreement is not bit for bit.)"""
    from rvd_pil.host_sim.pil import run_pil
    from rvd_pil.host_sim.record import load_run
    from rvd_pil.host_sim.server import ServerConfig

    target, bdir, _, build_error = q7s_build
    assert build_error is None, build_error
    exe = build.find_executable(bdir, build.FLIGHT_EXE)
    ideal = dict(truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True)
    native, _ = run_pil("case1_vbar", **ideal, config=ServerConfig(delay_model="none"), run_dir=tmp_path / "native")
    emulated, run_dir = run_pil("case1_vbar", **ideal, config=ServerConfig(delay_model="none", cmd_timeout_s=60),
                                flight_command=lambda args: user.command(target, exe.path, args),
                                run_dir=tmp_path / "q7s")
    assert native.end == emulated.end == "docked"
    assert emulated.steps == native.steps
    assert abs(emulated.dv_total_mps - native.dv_total_mps) <= 1e-6
    assert emulated.hello.arch == "armv7l" and emulated.hello.cpu_model == "cortex-a9"
    _, steps = load_run(run_dir)
    # Every solve converged under emulation too, or was certified infeasible and recovered (the Case 1
    # rendezvous meets the re-centred keep-out planes at 600-850 m), as natively.
    assert set(steps["guidance_status"].iloc[:-1]) <= {0, 5}
    assert set(steps["solver_status"].iloc[:-1]) <= {0, 2}
