"""QEMU system mode: boot a Debian ARM kernel with a tiny initramfs that brings the network up,
runs one program with the arguments from the kernel command line, and powers off. The guest
reaches the host over user networking (10.0.2.2) or, with `semihosting=True`, through ARM
semihosting calls on host files (rvd_pil/qemu/semihosting_link.py joins them to a TCP port): the emulated
CPU stops while such a call waits for the host, so no guest time passes while the host computes,
and no host-timed packet or network-stack timer lands in the guest's instruction stream.

    >>> t = load("rpi3")
    >>> img = image(t)                                  # kernel, dtb, base initramfs (cached)
    >>> r = run(t, exe, ["echo", "10.0.2.2", "5555"])   # boot, run, power off
    >>> r.exit_code, r.output, r.boot_s

The kernel is resolved from its Debian meta package (linux-image-arm64, linux-image-armmp) at
build time, never by a hard-coded ABI suffix. Images are cached under build/qemu-system/ keyed by
the kernel and busybox package versions. With the default `icount=True` the guest clock is driven
by the instruction count (-icount shift=s: one instruction = 2^s ns of guest time, s = 0 except
vexpress-a9, see rvd_pil/qemu/targets.toml) and the RTC by the virtual clock: an instruction-count proxy,
not Cortex-A timing. In-guest times repeat from run to run when nothing host-timed reaches the
guest (a program without I/O, or the semihosting link); over the user network they differ by the
guest kernel's work on packets that arrive at host-dependent instants. The guest is 10.0.2.15/24
and reaches the host's services at 10.0.2.2.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import re
import subprocess
import tarfile
import tempfile
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from . import debian
from .cpio import CpioWriter
from rvd_pil import paths

from .targets import Target

CACHE = paths.build_root() / "qemu-system"
# Debian builds virtio_mmio and virtio_net as modules; insmod has no modules.dep, so the order is
# the dependency order. vexpress-a9 has virtio-mmio transports too (QEMU adds them to its dtb).
NET_MODULES = ("failover", "net_failover", "virtio_mmio", "virtio_net")
GUEST_IP, HOST_IP = "10.0.2.15", "10.0.2.2"
RTC_BASE = "2024-01-01T00:00:00"
MAX_INIT_ARGS = 30  # the kernel passes at most 32 arguments to init
# Static glibc resolves names from /etc/hosts (checked: getaddrinfo("rvd-host") in the guest).
ETC_HOSTS = f"127.0.0.1 localhost\n{HOST_IP} rvd-host\n"

INIT_SCRIPT = f"""#!/bin/busybox sh
# rvd-pil guest init: network up, run /bin/app with the arguments after "--" on the kernel
# command line, report its exit status, power off.
/bin/busybox --install -s /bin
mount -t proc proc /proc
mount -t sysfs sysfs /sys
mount -t devtmpfs devtmpfs /dev 2>/dev/null
for m in {' '.join(NET_MODULES)}; do
  insmod /lib/modules/$m.ko || echo "rvd-init: insmod $m failed"
done
n=0
while [ ! -e /sys/class/net/eth0 ] && [ $n -lt 50 ]; do sleep 0.1; n=$((n+1)); done
ip link set lo up
if [ -e /sys/class/net/eth0 ]; then
  ip addr add {GUEST_IP}/24 dev eth0 && ip link set eth0 up && ip route add default via {HOST_IP}
else
  echo "rvd-init: no eth0"
fi
echo "rvd-init: start"
/bin/app "$@"
echo "rvd-init: exit=$?"
poweroff -f
"""


@dataclass(frozen=True)
class Image:
    kernel: Path
    initrd: Path          # base initramfs: busybox, network modules, /init
    dtb: Path | None
    kernel_version: str   # e.g. 6.1.0-50-arm64


@dataclass(frozen=True)
class SystemRun:
    exit_code: int | None  # the program's exit status; None if it never finished
    output: list[str]      # the program's console lines
    console: str           # everything on the serial console
    boot_s: float | None   # host seconds from QEMU start to the program's start
    wall_s: float          # host seconds from QEMU start to QEMU exit
    qemu_returncode: int | None
    timed_out: bool


def _kernel_package(target: Target, fetch: bool) -> str:
    meta = f"{target.system.kernel_package}:{target.debian_arch}"
    deps = [d.split(":")[0] for d in debian.depends(meta, fetch) if d.startswith("linux-image-")]
    if not deps:
        raise debian.AptError(f"{meta} depends on no linux-image-* package")
    return deps[0]


def image(target: Target, download: bool = True) -> Image | None:
    """Kernel, device tree and base initramfs for `target`, built once per kernel and busybox
    package version. With download=False returns None instead of fetching anything."""
    if target.system is None:
        raise ValueError(f"target {target.name!r} has no QEMU system machine (user mode only)")
    try:
        kernel_deb = debian.download(_kernel_package(target, download), target.debian_arch, download)
        busybox_deb = debian.download("busybox-static", target.debian_arch, download)
    except debian.NotCached:
        return None
    key = hashlib.sha256("\n".join([kernel_deb.name, busybox_deb.name, INIT_SCRIPT, ETC_HOSTS]).encode()).hexdigest()[:12]
    out = CACHE / target.debian_arch / f"{kernel_deb.name.removesuffix('.deb')}-{key}"
    meta = out / "image.json"
    img = _load_image(meta, target) if meta.exists() else None
    if img:
        return img
    with _locked(out):
        if meta.exists() and (img := _load_image(meta, target)):
            return img  # built by another process meanwhile
        kver, files = _extract_kernel(kernel_deb, out, target.system.dtb)
        busybox = _extract_member(busybox_deb, "./bin/busybox")
        initrd = _base_initrd(busybox, files["modules"]).write(out / "initrd-base.cpio")
        meta.write_text(json.dumps({"kernel": files["kernel"].name,
                                    "dtb": files["dtb"].name if files["dtb"] else None,
                                    "initrd": initrd.name, "kernel_version": kver,
                                    "kernel_deb": kernel_deb.name, "busybox_deb": busybox_deb.name}, indent=1))
    return _load_image(meta, target)


@contextmanager
def _locked(directory: Path):
    directory.mkdir(parents=True, exist_ok=True)
    with open(directory.parent / f".{directory.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def _load_image(meta: Path, target: Target) -> Image | None:
    d = json.loads(meta.read_text())
    if (target.system.dtb or None) != (d["dtb"] or None):
        return None
    img = Image(kernel=meta.parent / d["kernel"], initrd=meta.parent / d["initrd"],
                dtb=meta.parent / d["dtb"] if d["dtb"] else None, kernel_version=d["kernel_version"])
    return img if img.kernel.exists() and img.initrd.exists() else None


def _fsys_members(deb: Path):
    """(member, bytes) for each regular file in a .deb's data archive, streamed."""
    proc = subprocess.Popen(["dpkg-deb", "--fsys-tarfile", str(deb)], stdout=subprocess.PIPE)
    try:
        with tarfile.open(fileobj=proc.stdout, mode="r|") as tar:
            for m in tar:
                if m.isfile():
                    yield m, tar.extractfile(m)
    finally:
        proc.stdout.close()
        proc.wait()


def _extract_member(deb: Path, name: str) -> bytes:
    for m, f in _fsys_members(deb):
        if m.name == name:
            return f.read()
    raise debian.AptError(f"{deb.name} has no {name}")


def _extract_kernel(deb: Path, out: Path, dtb_name: str | None) -> tuple[str, dict]:
    kernel = dtb = None
    modules: dict[str, bytes] = {}
    kver = None
    for m, f in _fsys_members(deb):
        base = m.name.rsplit("/", 1)[-1]
        if m.name.startswith("./boot/vmlinuz-"):
            kver = base.removeprefix("vmlinuz-")
            kernel = out / base
            kernel.write_bytes(f.read())
        elif dtb_name and base == dtb_name and m.name.startswith("./usr/lib/linux-image-"):
            dtb = out / base
            dtb.write_bytes(f.read())
        elif base.endswith(".ko") and base[:-3] in NET_MODULES and m.name.startswith("./lib/modules/"):
            modules[base[:-3]] = f.read()
    missing = [n for n in NET_MODULES if n not in modules]
    if kernel is None or (dtb_name and dtb is None) or missing:
        raise debian.AptError(f"{deb.name}: missing kernel, dtb {dtb_name} or modules {missing}")
    return kver, {"kernel": kernel, "dtb": dtb, "modules": modules}


def _base_initrd(busybox: bytes, modules: dict[str, bytes]) -> CpioWriter:
    w = CpioWriter()
    for d in ("bin", "dev", "proc", "sys", "tmp", "etc", "lib", "lib/modules"):
        w.directory(d)
    w.char_device("dev/console", 5, 1)  # the kernel opens it before /init runs
    w.char_device("dev/null", 1, 3)
    w.file("bin/busybox", busybox, executable=True)
    w.symlink("bin/sh", "busybox")
    w.file("init", INIT_SCRIPT.encode(), executable=True)
    w.file("etc/hosts", ETC_HOSTS.encode())
    for name in NET_MODULES:
        w.file(f"lib/modules/{name}.ko", modules[name])
    return w


def program_initrd(img: Image, exe: Path, out: Path) -> Path:
    """The base initramfs followed by an archive holding `exe` as /bin/app."""
    w = CpioWriter()
    w.file("bin/app", Path(exe).read_bytes(), executable=True)
    out.write_bytes(img.initrd.read_bytes() + w.finish())
    return out


def kernel_command_line(target: Target, args: Sequence[str]) -> str:
    """Console and quiet boot, then "--" and the program's arguments (quoted where needed)."""
    if len(args) > MAX_INIT_ARGS:
        raise ValueError(f"at most {MAX_INIT_ARGS} program arguments fit the kernel command line")
    quoted = []
    for a in map(str, args):
        if '"' in a or "\n" in a or a == "":
            raise ValueError(f"argument {a!r}: the kernel command line cannot carry it")
        quoted.append(f'"{a}"' if " " in a else a)
    line = f"console={target.system.console} panic=-1 quiet loglevel=3 -- {' '.join(quoted)}".rstrip()
    if len(line) > 1000:
        raise ValueError("kernel command line longer than 1000 characters")
    return line


def command(target: Target, img: Image, initrd: Path, args: Sequence[str] = (), *, icount: bool = True,
            net: bool = True, semihosting: bool = False, memory: str | None = None) -> list[str]:
    """The QEMU command line. net: user networking (guest 10.0.2.15, host 10.0.2.2).
    semihosting: the guest's programs may open, read and write host files (semihosting.hpp)."""
    s = target.system
    machine = ",".join([s.machine, *s.machine_options])
    cmd = [target.qemu_system, "-M", machine, "-cpu", target.qemu_cpu, "-m", memory or s.memory, "-smp", "1",
           "-display", "none", "-monitor", "none", "-serial", "stdio", "-no-reboot", "-nic", "none",
           "-kernel", str(Path(img.kernel).resolve()), "-initrd", str(Path(initrd).resolve()),
           "-append", kernel_command_line(target, args)]
    if img.dtb:
        cmd += ["-dtb", str(Path(img.dtb).resolve())]
    if net:
        cmd += ["-netdev", "user,id=n0", "-device", "virtio-net-device,netdev=n0"]
    if semihosting:
        cmd += ["-semihosting-config", "enable=on,userspace=on,target=native"]
    if icount:
        cmd += ["-icount", f"shift={s.icount_shift},sleep=off", "-rtc", f"base={RTC_BASE},clock=vm"]
    return cmd + list(s.extra_args)


def run(target: Target, exe: Path | str, args: Sequence[str] = (), *, timeout_s: float = 300,
        icount: bool = True, net: bool = True, img: Image | None = None) -> SystemRun:
    """Boots `target`, runs `exe` with `args` in the guest, returns its output once QEMU exits."""
    img = img or image(target)
    with tempfile.TemporaryDirectory(prefix="rvd-initrd-") as tmp:
        initrd = program_initrd(img, Path(exe), Path(tmp) / "initrd.cpio")
        cmd = command(target, img, initrd, args, icount=icount, net=net)
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT)
        timed_out = threading.Event()

        def kill_on_timeout():
            timed_out.set()
            proc.kill()

        timer = threading.Timer(timeout_s, kill_on_timeout)
        timer.start()
        lines, boot_s = [], None
        try:
            for raw in proc.stdout:
                line = raw.decode(errors="replace").rstrip("\r\n").replace("\r", "")
                lines.append(line)
                if boot_s is None and line.endswith("rvd-init: start"):
                    boot_s = time.monotonic() - t0
            proc.wait()
        finally:
            timer.cancel()
            proc.stdout.close()
        wall = time.monotonic() - t0
    return _parse(lines, boot_s, wall, proc.returncode, timed_out.is_set())


def _parse(lines: list[str], boot_s, wall_s, rc, timed_out) -> SystemRun:
    exit_code, output, inside = None, [], False
    for line in lines:
        if line.endswith("rvd-init: start"):
            inside = True
            continue
        m = re.search(r"rvd-init: exit=(\d+)$", line)
        if m:
            exit_code, inside = int(m.group(1)), False
        elif inside:
            output.append(line)
    return SystemRun(exit_code=exit_code, output=output, console="\n".join(lines), boot_s=boot_s,
                     wall_s=wall_s, qemu_returncode=rc, timed_out=timed_out)
