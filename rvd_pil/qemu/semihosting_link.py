"""Run QEMU with the flight software's Zenoh link going through semihosting: two FIFOs on the host,
joined to the host simulator's TCP endpoint.

    python -m rvd_pil.qemu.semihosting_link --connect 127.0.0.1:7447 --dir /tmp/rvd-link -- qemu-system-... 

QEMU runs in DIR. The guest (flight_sw with --connect semihosting/. --untimed-link) opens
to-guest for reading and from-guest for writing there through semihosting calls, by paths relative
to QEMU's working directory: the guest's command line, and with it everything the guest does, is
the same wherever the FIFOs are (so the QEMU command must use absolute paths). This bridge opens
their other ends, then connects to the host's TCP endpoint and copies bytes both ways, so the host's Zenoh sees an
ordinary TCP client. A semihosting read blocks inside one guest instruction, so the emulated CPU
(and, with -icount, the guest clock) stands still until the host answers: the guest's timeline no
longer depends on how fast the host is, which is what makes in-guest times repeat bit for bit.

Exits with QEMU's exit status; SIGTERM and SIGINT are passed on to QEMU. When the host closes the
TCP connection (or cannot be reached) the guest reads end-of-file, and QEMU gets --grace-s seconds
to power off before the bridge stops it: a guest cannot reconnect through this link, and a host
that died must not leave an emulator behind. When QEMU exits the host sees the connection close.

The run's link key: the bridge takes it from its environment ($RVD_LINK_KEY, where rvd_pil.host_sim.pil
puts it), writes it to DIR/link-key (mode 0600, nobody else can read it) and removes it from what
QEMU inherits. The guest reads it through semihosting (flight option --key-file semihosting/link-key)
before it opens the link; the bridge deletes the file as soon as the guest has opened the FIFOs
(or when QEMU exits). So the key is on no command line: not the host's, not the guest's kernel's.
With --key-only there are no FIFOs: the guest reaches the host over QEMU's user network and only
the key goes through semihosting.
"""
from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

TO_GUEST, FROM_GUEST = "to-guest", "from-guest"
KEY_FILE = "link-key"
GUEST_KEY_ARGS = ["--key-file", f"semihosting/{KEY_FILE}"]  # relative to QEMU's working directory
# A fixed ZenohID for the host session of runs that must repeat bit for bit ("rvdpil"): Zenoh derives
# the initial sequence numbers, which travel in every frame, from the two sessions' ZenohIDs.
HOST_ZENOH_ID = "72766470696c"


def make_fifos(directory: Path) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    for name in (TO_GUEST, FROM_GUEST):
        path = directory / name
        if path.exists():
            path.unlink()
        os.mkfifo(path, 0o600)


def _key_env() -> str:
    from rvd_pil.host_sim.messages import KEY_ENV

    return KEY_ENV


def write_key_file(directory: Path, key_hex: str) -> Path:
    """DIR/link-key with the key, readable by us alone (created 0600, never widened)."""
    path = Path(directory) / KEY_FILE
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        os.write(fd, key_hex.encode() + b"\n")
    finally:
        os.close(fd)
    return path


def remove_key_file(directory: Path) -> None:
    (Path(directory) / KEY_FILE).unlink(missing_ok=True)


def _open_writer(path: Path, alive) -> int | None:
    """Opens a FIFO for writing once its reader (the guest) has opened it; None if QEMU died first."""
    while alive():
        try:
            fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
        except OSError:  # ENXIO: no reader yet
            time.sleep(0.02)
            continue
        os.set_blocking(fd, True)
        return fd
    return None


def _batches(sock: socket.socket):
    """The TCP stream cut into Zenoh batches (u16 little-endian length, then the batch), each with
    its prefix; at the end, whatever incomplete rest there is. Whole batches go to the guest in one
    write each, so the guest's reads do not depend on how the host's bytes were split or queued."""
    buf = b""
    while data := sock.recv(65536):
        buf += data
        while len(buf) >= 2 and len(buf) >= 2 + int.from_bytes(buf[:2], "little"):
            end = 2 + int.from_bytes(buf[:2], "little")
            yield buf[:end]
            buf = buf[end:]
    if buf:
        yield buf


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def bridge(directory: Path, host: str, port: int, alive, log=lambda text: None) -> None:
    """Joins the FIFOs in `directory` to TCP host:port until either side closes."""
    to_guest = _open_writer(directory / TO_GUEST, alive)
    remove_key_file(directory)  # the guest read its key before it opened the link
    if to_guest is None:
        return
    from_guest = os.open(directory / FROM_GUEST, os.O_RDONLY)  # the guest opens it right after
    try:
        sock = socket.create_connection((host, port), timeout=10)
    except OSError as exc:
        log(f"semihosting link: cannot connect to {host}:{port}: {exc}")
        os.close(to_guest)  # the guest reads end-of-file: its link is lost
        os.close(from_guest)
        return
    sock.settimeout(None)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def guest_to_host():
        try:
            while data := os.read(from_guest, 65536):
                sock.sendall(data)
        except OSError:
            pass
        try:
            sock.shutdown(socket.SHUT_WR)
        except OSError:
            pass

    up = threading.Thread(target=guest_to_host, daemon=True)
    up.start()
    try:
        for batch in _batches(sock):
            _write_all(to_guest, batch)
    except OSError:
        pass
    os.close(to_guest)
    up.join(timeout=1.0)


def flight_command(launch, link_dir: Path):
    """A `flight_command` for rvd_pil.host_sim.pil.run_pil: the flight arguments it is given (with
    --connect tcp/127.0.0.1:PORT) become the guest's (--connect semihosting/. --untimed-link),
    `launch(guest_args)` gives the QEMU system-mode command (with semihosting on), and the result
    is this bridge around it."""
    local = "tcp/127.0.0.1:"
    link_dir = Path(link_dir).resolve()

    def command(args):
        ports = [a[len(local):] for a in args if a.startswith(local)]
        if len(ports) != 1:
            raise ValueError(f"expected one --connect {local}PORT in {args}")
        guest = ["semihosting/." if a.startswith(local) else a for a in args] + ["--untimed-link", *GUEST_KEY_ARGS]
        return [sys.executable, "-m", "rvd_pil.qemu.semihosting_link", "--connect", f"127.0.0.1:{ports[0]}",
                "--dir", str(link_dir), "--", *launch(guest)]

    return command


def key_only_command(launch, key_dir: Path, host_ip: str):
    """A `flight_command` for QEMU system mode over its user network (the guest reaches the host at
    `host_ip`): only the link key goes through semihosting, so `launch` must enable it."""
    local = "tcp/127.0.0.1:"
    key_dir = Path(key_dir).resolve()

    def command(args):
        guest = [a.replace(local, f"tcp/{host_ip}:") for a in args] + GUEST_KEY_ARGS
        return [sys.executable, "-m", "rvd_pil.qemu.semihosting_link", "--key-only", "--dir", str(key_dir), "--",
                *launch(guest)]

    return command


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.qemu.semihosting_link", description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", help="the host's TCP endpoint, HOST:PORT (not with --key-only)")
    ap.add_argument("--key-only", action="store_true",
                    help="no FIFOs: only hand the guest its link key (the link runs over QEMU's network)")
    ap.add_argument("--dir", required=True, help="directory for the two FIFOs (created)")
    ap.add_argument("--grace-s", type=float, default=10.0,
                    help="after the host's side closed, seconds QEMU gets to power off (default 10)")
    ap.add_argument("qemu", nargs=argparse.REMAINDER, help="-- then the QEMU command")
    a = ap.parse_args(argv)
    command = a.qemu[1:] if a.qemu[:1] == ["--"] else a.qemu
    if not command:
        ap.error("no QEMU command after --")
    if bool(a.connect) == a.key_only:
        ap.error("give --connect HOST:PORT, or --key-only")
    directory = Path(a.dir)
    directory.mkdir(parents=True, exist_ok=True)
    key = os.environ.pop(_key_env(), None)  # QEMU does not inherit it
    if key:
        write_key_file(directory, key)
    try:
        if a.key_only:
            qemu = subprocess.Popen(command, cwd=directory)
            for sig in (signal.SIGTERM, signal.SIGINT):
                signal.signal(sig, lambda s, f: qemu.send_signal(s))
            rc = qemu.wait()
            return rc if rc >= 0 else 128 - rc
        return _bridged(a, command, directory)
    finally:
        remove_key_file(directory)


def _bridged(a, command, directory: Path) -> int:
    host, _, port = a.connect.rpartition(":")
    make_fifos(directory)
    qemu = subprocess.Popen(command, cwd=directory)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda s, f: qemu.send_signal(s))
    link = threading.Thread(target=bridge, args=(directory, host, int(port), lambda: qemu.poll() is None,
                                                 lambda t: print(t, file=sys.stderr, flush=True)), daemon=True)
    link.start()
    closed_at = None
    while True:
        try:
            rc = qemu.wait(timeout=0.1)
            break
        except subprocess.TimeoutExpired:
            pass
        if closed_at is None and not link.is_alive():
            closed_at = time.monotonic()
        if closed_at is not None and time.monotonic() - closed_at > a.grace_s:
            print(f"semihosting link: the host's side closed and QEMU did not exit within {a.grace_s:g} s: "
                  "stopping it", file=sys.stderr, flush=True)
            qemu.terminate()
            try:
                rc = qemu.wait(timeout=5)
            except subprocess.TimeoutExpired:
                qemu.kill()
                rc = qemu.wait()
            break
    return rc if rc >= 0 else 128 - rc


if __name__ == "__main__":
    sys.exit(main())
