"""Shared helpers for the flight-side Zenoh client tests (tests/test_link_zenoh_*.py).

* ``Probe`` runs the C++ client ``zenoh_probe`` (tests/cpp/tools/zenoh_probe.cpp) and reads its
  line protocol (OPEN, SAMPLE, PUT, EVENT, RECONNECTED, STATS, BYE; ``key=value`` fields).
* ``python_zenoh`` opens a real eclipse-zenoh session in ``peer`` or ``router`` mode listening on a
  loopback port: the host side of the link.
* ``RawPeer`` is a scripted Zenoh peer on a plain Python socket, written independently of the C++
  codec from the Zenoh wire summary in flight_sw/link/README.md, for what a real Zenoh never sends on demand
  (malformed bytes, remote key declarations, SN gaps, silence).

The probe binary is taken from $RVD_ZENOH_PROBE, else from build/native (what ``make test`` builds);
$RVD_ZENOH_RUNNER prefixes it (e.g. "qemu-aarch64 -cpu cortex-a53" for a cross-built probe).
"""

from __future__ import annotations

import os
import queue
import re
import shlex
import socket
import struct
import subprocess
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
FIELD = re.compile(r'(\w+)=("(?:[^"]*)"|\S*)')


def probe_path() -> Path:
    env = os.environ.get("RVD_ZENOH_PROBE")
    path = Path(env) if env else REPO / "build" / "native" / "tests" / "cpp" / "zenoh_probe"
    if not path.is_file():
        raise FileNotFoundError(
            f"zenoh_probe not found at {path}: build it (make native, or cmake --build <dir> "
            "--target zenoh_probe) or point RVD_ZENOH_PROBE at it")
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def parse_fields(line: str) -> dict[str, str]:
    return {k: v.strip('"') for k, v in FIELD.findall(line)}


class Probe:
    """The C++ Zenoh client as a subprocess; every wait has a timeout."""

    def __init__(self, endpoint: str, *args: str, runner: str | None = None) -> None:
        runner = os.environ.get("RVD_ZENOH_RUNNER", "") if runner is None else runner
        cmd = shlex.split(runner) + [str(probe_path()), "--connect", endpoint, *args]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, bufsize=1)
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.history: list[str] = []
        self.stderr: str | None = None
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def expect(self, kind: str, timeout: float = 10.0, **match: str) -> dict[str, str]:
        """The next line of this kind (whose fields equal `match`), skipping others."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            try:
                line = self.lines.get(timeout=max(left, 0.0))
            except queue.Empty:
                raise AssertionError(f"no {kind} {match} within {timeout} s; probe said:\n"
                                     + "\n".join(self.history[-30:])) from None
            if line is None:
                raise AssertionError(f"probe exited (rc={self.proc.wait(5)}) before {kind}; "
                                     f"stderr: {self.proc.stderr.read()}\n" + "\n".join(self.history[-30:]))
            self.history.append(line)
            if line.split(" ", 1)[0] == kind:
                fields = parse_fields(line)
                if all(fields.get(k) == v for k, v in match.items()):
                    return fields

    def send(self, command: str) -> None:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def stats(self, timeout: float = 10.0) -> dict[str, int | str]:
        self.send("stats")
        f = self.expect("STATS", timeout)
        return {k: (int(v) if v.lstrip("-").isdigit() else v) for k, v in f.items()}

    def wait_for_stat(self, name: str, at_least: int, timeout: float = 60.0) -> dict[str, int | str]:
        """Poll the probe's counters until `name` reaches `at_least`: a bounded wait on a condition
        (fails after `timeout`), never a pause of a guessed length."""
        deadline = time.monotonic() + timeout
        while True:
            st = self.stats()
            if int(st.get(name, 0)) >= at_least:
                return st
            if time.monotonic() > deadline:
                raise AssertionError(f"{name} = {st.get(name)} < {at_least} after {timeout} s; stats {st}")
            time.sleep(0.05)  # the polling interval; what is awaited is the counter, not the time

    def close(self, timeout: float = 10.0) -> int:
        """Ends the probe (EOF on its stdin); fails if a sanitizer reported anything."""
        if self.proc.poll() is None:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        if self.stderr is None:
            self.stderr = self.proc.stderr.read()
            if "Sanitizer" in self.stderr:
                raise AssertionError("zenoh_probe: " + self.stderr)
        return self.proc.returncode

    def __enter__(self) -> "Probe":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def pattern(n: int) -> bytes:
    """The probe's put payload: byte i = (31 i + 7) mod 256."""
    return bytes((31 * i + 7) & 0xFF for i in range(n))


def python_zenoh(mode: str, port: int, lease_ms: int | None = None):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", f'"{mode}"')
    conf.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{port}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if lease_ms is not None:
        conf.insert_json5("transport/link/tx/lease", str(lease_ms))
    return zenoh.open(conf)


def wait_matching(publisher, timeout: float = 10.0) -> None:
    """Waits until the remote has a subscriber for the publisher's key (it declared it)."""
    deadline = time.monotonic() + timeout
    while not publisher.matching_status.matching:
        if time.monotonic() > deadline:
            raise AssertionError("no matching subscriber declared in time")
        time.sleep(0.002)


# ---- a scripted raw Zenoh peer ----------------------------------------------------------------

def vle(v: int) -> bytes:
    out = bytearray()
    for _ in range(8):
        if v <= 0x7F:
            out.append(v)
            return bytes(out)
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v & 0xFF)
    return bytes(out)


def zstr(s: str | bytes) -> bytes:
    b = s.encode() if isinstance(s, str) else s
    return vle(len(b)) + b


def push_put(key: str | None, payload: bytes, scope: int = 0, sender_mapping: bool = True) -> bytes:
    """Push(Put) network message; key None means no suffix (the scope id alone)."""
    header = 0x1D | (0x20 if key else 0) | (0x40 if sender_mapping else 0)
    return bytes([header]) + vle(scope) + (zstr(key) if key else b"") + b"\x01" + zstr(payload)


def frame(sn: int, *messages: bytes, reliable: bool = True) -> bytes:
    return bytes([0x05 | (0x20 if reliable else 0)]) + vle(sn) + b"".join(messages)


def fragment(sn: int, body: bytes, more: bool, first: bool = False, drop: bool = False) -> bytes:
    exts = []
    if first:
        exts.append(0x02)
    if drop:
        exts.append(0x03)
    header = 0x06 | 0x20 | (0x40 if more else 0) | (0x80 if exts else 0)
    chain = bytes(e | (0x80 if i + 1 < len(exts) else 0) for i, e in enumerate(exts))
    return bytes([header]) + vle(sn) + chain + body


def declare_keyexpr(expr_id: int, key: str) -> bytes:
    return b"\x1e\x20" + vle(expr_id) + b"\x00" + zstr(key)


def undeclare_keyexpr(expr_id: int) -> bytes:
    return b"\x1e\x01" + vle(expr_id)


class RawPeer:
    """Accepts one client at a time on a loopback port and completes the Zenoh handshake itself.

    After ``accept()``, ``send(batch)`` writes length-prefixed batches; ``received`` collects the
    client's batches (read by a background thread) so tests can inspect what the client sent.
    """

    def __init__(self) -> None:
        self.server = socket.socket()
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(4)
        self.port = self.server.getsockname()[1]
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.conn: socket.socket | None = None
        self.received: queue.Queue[bytes | None] = queue.Queue()
        self.initial_sn = 1000
        self.sn = self.be_sn = self.initial_sn

    def accept(self, timeout: float = 10.0) -> socket.socket:
        self.server.settimeout(timeout)
        conn, _ = self.server.accept()
        conn.settimeout(timeout)
        self.conn = conn
        return conn

    def read_batch(self, timeout: float = 10.0) -> bytes:
        self.conn.settimeout(timeout)
        head = self._read_exact(2)
        return self._read_exact(struct.unpack("<H", head)[0])

    def _read_exact(self, n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = self.conn.recv(n - len(buf))
            if not chunk:
                raise ConnectionError("client closed")
            buf += chunk
        return buf

    def send(self, batch: bytes) -> None:
        self.conn.sendall(struct.pack("<H", len(batch)) + batch)

    def next_sn(self, reliable: bool = True) -> int:
        """The next TX SN of a channel (each Frame and each Fragment uses one)."""
        if reliable:
            sn, self.sn = self.sn, self.sn + 1
        else:
            sn, self.be_sn = self.be_sn, self.be_sn + 1
        return sn

    def handshake(self, lease_ms: int = 10000, batch_size: int = 2048, patch: bool = True,
                  whatami: int = 1, version: int = 0x09) -> dict:
        """Answers InitSyn and OpenSyn; returns what the client proposed."""
        init = self.read_batch()
        assert init[0] & 0x1F == 0x01 and not init[0] & 0x20, f"expected InitSyn, got {init.hex()}"
        assert init[1] == 0x09
        zid_len = (init[2] >> 4) + 1
        client = {"whatami": init[2] & 0x03, "zid": init[3:3 + zid_len]}
        if init[0] & 0x40:
            client["resolution"] = init[3 + zid_len]
            client["batch_size"] = struct.unpack("<H", init[4 + zid_len:6 + zid_len])[0]
        cookie = bytes(range(40, 89))
        zid = bytes(range(1, 17))
        header = 0x21 | 0x40 | (0x80 if patch else 0)
        ack = bytes([header, version, 0xF0 | whatami]) + zid + b"\x0a" + struct.pack("<H", batch_size) + zstr(cookie)
        if patch:
            ack += b"\x27\x01"
        self.send(ack)
        open_syn = self.read_batch()
        assert open_syn[0] & 0x1F == 0x02, f"expected OpenSyn, got {open_syn.hex()}"
        assert cookie in open_syn, "the cookie was not echoed"
        if lease_ms % 1000 == 0:
            self.send(b"\x62" + vle(lease_ms // 1000) + vle(self.initial_sn))
        else:
            self.send(b"\x22" + vle(lease_ms) + vle(self.initial_sn))
        self.sn = self.be_sn = self.initial_sn
        threading.Thread(target=self._drain, daemon=True).start()
        return client

    def _drain(self) -> None:
        try:
            while True:
                self.received.put(self.read_batch(timeout=60))
        except (OSError, ConnectionError):
            self.received.put(None)

    def wait_for_bytes(self, needle: bytes, timeout: float = 10.0) -> bytes:
        """The first batch from the client that contains `needle`."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                b = self.received.get(timeout=max(deadline - time.monotonic(), 0.0))
            except queue.Empty:
                raise AssertionError(f"client never sent {needle!r}") from None
            if b is None:
                raise AssertionError("client closed before sending " + repr(needle))
            if needle in b:
                return b

    def close(self) -> None:
        for s in (self.conn, self.server):
            if s is not None:
                try:
                    s.close()
                except OSError:
                    pass

    def __enter__(self) -> "RawPeer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
