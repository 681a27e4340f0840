"""The semihosting link: the bridge between two host FIFOs and a TCP endpoint
(rvd_pil/qemu/semihosting_link.py), and Case 1 through it in QEMU system mode, where the guest clock stands
still while the host computes, so that two runs give the same in-guest solve times at every step.

The system-mode part needs the ARM kernels and busybox (downloads that belong to `make pil`):
skipped until `python -m rvd_pil.qemu prepare` has run, or set RVD_QEMU_FETCH=1 to let the test fetch them.
"""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading

import numpy as np
import pytest

from rvd_pil import flight_sw
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.record import load_run
from rvd_pil.host_sim.server import ServerConfig
from rvd_pil.qemu import build, semihosting_link, system
from support.flight_reference import flight_params
from support.system_mode import system_mode_or_skip

pytestmark = pytest.mark.qemu


@pytest.fixture
def echo_server():
    """Echoes what it receives until the test asks it to hang up."""
    server = socket.create_server(("127.0.0.1", 0))
    hang_up = threading.Event()

    def serve():
        conn, _ = server.accept()
        with conn:
            conn.settimeout(0.05)
            while not hang_up.is_set():
                try:
                    data = conn.recv(4096)
                except socket.timeout:
                    continue
                if not data:
                    break
                conn.sendall(data)

    threading.Thread(target=serve, daemon=True).start()
    yield server.getsockname()[1], hang_up
    server.close()


def test_bridge_joins_the_fifos_to_tcp_and_passes_end_of_file_on(tmp_path, echo_server):
    port, hang_up = echo_server
    semihosting_link.make_fifos(tmp_path)
    bridge = threading.Thread(target=semihosting_link.bridge, args=(tmp_path, "127.0.0.1", port, lambda: True),
                              daemon=True)
    bridge.start()
    # The guest's side, in the guest's order: to-guest for reading, then from-guest for writing.
    to_guest = os.open(tmp_path / semihosting_link.TO_GUEST, os.O_RDONLY)
    from_guest = os.open(tmp_path / semihosting_link.FROM_GUEST, os.O_WRONLY)
    # Zenoh batches (u16 little-endian length, then the batch), more than one pipe or TCP read's worth
    message = b"".join(len(b).to_bytes(2, "little") + b for b in (bytes([i]) * (7 * i + 1) for i in range(200)))
    os.write(from_guest, message)
    echoed = b""
    while len(echoed) < len(message):
        echoed += os.read(to_guest, 65536)
    assert echoed == message
    hang_up.set()  # the host closes the connection: the guest reads end-of-file
    assert os.read(to_guest, 1) == b""
    os.close(from_guest)
    bridge.join(timeout=5)
    assert not bridge.is_alive()
    os.close(to_guest)


def test_bridge_hands_the_guest_whole_batches_however_tcp_splits_them():
    host, bridge_end = socket.socketpair()
    batches = [len(b).to_bytes(2, "little") + b for b in (b"nav", b"", bytes(range(256)) * 3, b"cmd")]
    stream = b"".join(batches) + b"\x05\x00ab"  # and an incomplete one at the end
    for i in range(0, len(stream), 5):  # in 5-byte pieces
        host.sendall(stream[i:i + 5])
    host.close()
    assert list(semihosting_link._batches(bridge_end)) == batches + [b"\x05\x00ab"]
    bridge_end.close()


def test_bridge_exits_with_the_emulator_and_its_status(tmp_path):
    # The "emulator" never opens the FIFOs: the bridge must not wait for them after it is gone.
    proc = subprocess.run([sys.executable, "-m", "rvd_pil.qemu.semihosting_link", "--connect", "127.0.0.1:9",
                           "--dir", str(tmp_path / "link"), "--", sys.executable, "-c", "raise SystemExit(3)"],
                          timeout=30)
    assert proc.returncode == 3
    assert (tmp_path / "link" / semihosting_link.TO_GUEST).exists()
    with pytest.raises(ValueError, match="one --connect"):
        semihosting_link.flight_command(lambda a: ["qemu"], tmp_path)(["--connect", "tcp/10.0.2.2:7447"])


def test_bridge_stops_an_emulator_that_outlives_the_host(tmp_path):
    """The host accepts and hangs up at once (as a host that died would): the "emulator" (a child
    that opens the FIFOs like a guest, then never exits by itself) is stopped after the grace time."""
    server = socket.create_server(("127.0.0.1", 0))
    threading.Thread(target=lambda: server.accept()[0].close(), daemon=True).start()
    link = tmp_path / "link"
    guest = ("import os, time, sys; d = sys.argv[1]; "
             "r = os.open(d + '/to-guest', os.O_RDONLY); w = os.open(d + '/from-guest', os.O_WRONLY); "
             "assert os.read(r, 1) == b''; time.sleep(120)")
    proc = subprocess.run([sys.executable, "-m", "rvd_pil.qemu.semihosting_link", "--connect",
                           f"127.0.0.1:{server.getsockname()[1]}", "--dir", str(link), "--grace-s", "0.5", "--",
                           sys.executable, "-c", guest, str(link)], capture_output=True, text=True, timeout=60)
    server.close()
    assert proc.returncode == 128 + 15, proc.stderr  # terminated by the bridge
    assert "did not exit within 0.5 s" in proc.stderr


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rpi3", "q7s"])
def test_system_mode_in_guest_solve_times_repeat_bit_for_bit(tmp_path, name):
    target, img = system_mode_or_skip(name)
    exe = build.cross_build(target).path
    initrd = system.program_initrd(img, exe, tmp_path / "initrd.cpio")
    params = flight_params()
    case = flight_sw.dissertation_case(1)
    ref = flight_sw.run_closed_loop(params, case["x0"], case["q_lvlh_body"], case["omega_body_rad_s"])
    command = semihosting_link.flight_command(
        lambda args: system.command(target, img, initrd, args, net=False, semihosting=True), tmp_path / "link")
    runs = []
    for rep in (1, 2):
        summary, run_dir = run_pil("case1_vbar", truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True,
                                   sim_options={"cw_mean_motion_rad_s": params.mean_motion_rad_s()},
                                   config=ServerConfig(delay_model="none", run_id="semihosting-check",
                                                       zenoh_id=semihosting_link.HOST_ZENOH_ID, zenoh_lease_ms=60000),
                                   run_dir=tmp_path / f"run{rep}", flight_command=command,
                                   flight_args=["--pmu-instructions"])
        assert summary.end == "docked", summary.end
        # the same closed loop as in process: the link changes nothing but the timing
        assert summary.steps == ref.steps
        assert summary.dv_total_mps == pytest.approx(ref.total["dv_mps"], abs=1e-6)
        runs.append(load_run(run_dir)[1])
    a, b = (r["solve_time_us"].to_numpy() for r in runs)
    assert len(a) == len(b) == ref.steps
    assert (a[:-1] > 0).all()  # every step but the docked one solved a QP on the guest clock
    np.testing.assert_array_equal(a, b)  # bit for bit, not approximately
    np.testing.assert_array_equal(runs[0]["instructions"].to_numpy(), runs[1]["instructions"].to_numpy())


def test_the_link_key_reaches_the_guest_as_a_0600_file_and_never_its_command_line(tmp_path):
    """The bridge writes $RVD_LINK_KEY to DIR/link-key (0600), keeps it out of QEMU's environment,
    and removes the file once the guest opened the link (here: a stand-in guest that reads the key
    and reports what it saw, then opens the FIFOs the way the flight software does)."""
    from rvd_pil.host_sim.messages import KEY_ENV

    server = socket.create_server(("127.0.0.1", 0))
    threading.Thread(target=lambda: server.accept()[0].close(), daemon=True).start()
    link = tmp_path / "link"
    key = "ab" * 32
    guest = ("import os, stat, sys, json; d = sys.argv[1]; st = os.stat(d + '/link-key'); "
             "k = open(d + '/link-key').read().strip(); "
             f"print(json.dumps({{'mode': stat.S_IMODE(st.st_mode), 'key_ok': k == {key!r}, "
             f"'env': {KEY_ENV!r} in os.environ, 'argv_has_key': {key!r} in ' '.join(sys.argv)}}), flush=True); "
             "r = os.open(d + '/to-guest', os.O_RDONLY); w = os.open(d + '/from-guest', os.O_WRONLY); "
             "print(json.dumps({'key_file_left': os.path.exists(d + '/link-key')}), flush=True); "
             "assert os.read(r, 1) == b''")
    # The guest's arguments as flight_command builds them carry the key file's name, not the key.
    args = semihosting_link.flight_command(lambda a: ["qemu", *a], link)(["--connect", "tcp/127.0.0.1:7447", "--run", "r"])
    assert semihosting_link.GUEST_KEY_ARGS == args[-2:] and key not in " ".join(args)
    proc = subprocess.run([sys.executable, "-m", "rvd_pil.qemu.semihosting_link", "--connect",
                           f"127.0.0.1:{server.getsockname()[1]}", "--dir", str(link), "--grace-s", "5", "--",
                           sys.executable, "-c", guest, str(link)],
                          env={**os.environ, KEY_ENV: key}, capture_output=True, text=True, timeout=60)
    server.close()
    seen, after = (json.loads(line) for line in proc.stdout.splitlines()[:2])
    assert proc.returncode == 0, proc.stderr
    assert seen == {"mode": 0o600, "key_ok": True, "env": False, "argv_has_key": False}
    # Gone once the guest has opened the link: the bridge removes it before it opens from-guest,
    # and the guest's open of from-guest for writing returns only once the bridge has done so.
    assert after == {"key_file_left": False} and not (link / semihosting_link.KEY_FILE).exists()
