"""Run integrity: what another local user's Zenoh session can do to a PIL run, and faults that end
cleanly and say so.

Each attack runs a whole Case 1 (CW truth, no noise, impulsive) against the native flight
executable while a separate eclipse-zenoh session, which learns the endpoint and the run id from
the flight process's command line as `ps` would show it, publishes forgeries on the run's keys.
The run must dock with its own commands (steps and delta-v equal to the undisturbed in-process
closed loop), and every forgery must be counted, on the side it reached, in the flight software's
telemetry and in the run record's events. To count exactly, the host's per-step hook waits (bounded)
until the attacker has reacted to the step and the host has seen all it sent so far.

Also here: a deliberately broken flight build whose commands break the declared limits (recorded
flight faults, never applied, no traceback), the host killed with SIGKILL (the flight process leaves
within its documented bound, the record says the host died), run ids that could be wildcards, and
three runs of `rvd-run case1_vbar --truth cw --ideal` that give the same record.
"""
from __future__ import annotations

import json
import math
import os
import queue
import random
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from rvd_pil import flight_sw
from support.flight_reference import flight_params
from rvd_pil.host_sim import messages as msg
from rvd_pil.host_sim.pil import find_flight_executable, run_pil
from rvd_pil.host_sim.record import HOST_DIED, TIMING_COLUMNS, load_events, load_run, record_digest
from rvd_pil.host_sim.server import ServerConfig

REPO = Path(__file__).resolve().parents[1]
IDEAL = dict(truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True)
WAIT_S = 10.0  # bound of every wait on a condition below


def wait_until(predicate, what: str, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout} s: {what}")
        time.sleep(0.0005)


@pytest.fixture(scope="module")
def reference():
    params = flight_params()
    case = flight_sw.dissertation_case(1)
    ref = flight_sw.run_closed_loop(params, case["x0"], case["q_lvlh_body"], case["omega_body_rad_s"])
    assert ref.docked
    return params, ref


def untagged(m) -> bytes:
    """The message as the tagless protocol (version 1, 8-byte header) wrote it."""
    body = msg.encode(m)[msg.HEADER_SIZE:-msg.TAG_SIZE]
    return msg.MAGIC + bytes([msg.UNTAGGED_VERSION, type(m).TYPE, 0]) + struct.pack("<H", len(body)) + body


def forged(m, copy_header_from: bytes | None = None, rng=random) -> bytes:
    """A version-2 message with a made-up tag: the nonce (and the next sequence number) copied from
    a genuine message when given (then only the tag is wrong), else made up too."""
    raw = bytearray(msg.encode(m))
    if copy_header_from is not None:
        nonce, seq = struct.unpack_from("<II", copy_header_from, 8)
        struct.pack_into("<II", raw, 8, nonce, seq + 1)
    else:
        struct.pack_into("<II", raw, 8, rng.getrandbits(32), rng.getrandbits(32))
    raw[-msg.TAG_SIZE:] = rng.randbytes(msg.TAG_SIZE)
    return bytes(raw)


def with_step(genuine: bytes, step: int) -> bytes:
    raw = bytearray(genuine)
    struct.pack_into("<I", raw, msg.HEADER_SIZE, step)
    return bytes(raw)


class Attacker:
    """Another user's eclipse-zenoh session (client mode) aimed at a running PIL run.

    It reads the flight process's command line (/proc/PID/cmdline: what `ps` shows), connects to
    the host's endpoint found there, watches the run's genuine traffic and calls `react(self, kind,
    payload, step)` for every genuine nav or cmd it sees; `react` returns the forgeries to publish
    as (key suffix, bytes, expected kind) triples, the key suffix after "rvd/" with <run> for the
    run id. `sent` counts them by (side that hears it, kind); `reacted[kind]` is the last step it
    reacted to."""

    def __init__(self, flight_pid: int, react):
        args = Path(f"/proc/{flight_pid}/cmdline").read_bytes().split(b"\0")
        self.cmdline = b" ".join(args).decode()
        self.endpoint = args[args.index(b"--connect") + 1].decode()
        self.run = args[args.index(b"--run") + 1].decode()
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([self.endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.react = react
        self.sent: dict[tuple[str, str], int] = {}
        self.reacted = {"nav": -1, "cmd": -1}
        self.lock = threading.Lock()
        # Forgeries go out from a thread of our own: a put from inside a Zenoh callback (its receive
        # thread) may block on its own congestion control.
        self.seen: "queue.Queue[tuple[str, bytes] | None]" = queue.Queue()
        self.worker = threading.Thread(target=self._work, daemon=True)
        self.worker.start()
        self.subs = [self.session.declare_subscriber(f"rvd/{self.run}/{kind}",
                                                     lambda s, kind=kind: self.seen.put((kind, s.payload.to_bytes())),
                                                     allowed_origin=zenoh.Locality.REMOTE)  # not our own forgeries
                     for kind in ("nav", "cmd")]
        # Declared last: once the host knows this one, it knows the two above (one link, in order).
        self.ready_key = f"attacker/{self.run}/ready"
        self.subs.append(self.session.declare_subscriber(self.ready_key, lambda s: None))

    def wait_until_heard_by(self, host_session) -> None:
        """Returns once the host routes the run's traffic to us too."""
        pub = host_session.declare_publisher(self.ready_key, allowed_destination=zenoh.Locality.REMOTE)
        wait_until(lambda: pub.matching_status.matching, "the host knowing the attacker's subscriptions")
        pub.undeclare()

    def _work(self) -> None:
        while (item := self.seen.get()) is not None:
            kind, payload = item
            step = struct.unpack_from("<I", payload, msg.HEADER_SIZE)[0]
            for key, data, expected in self.react(self, kind, payload, step):
                # BLOCK: a 16 MiB put is 256 fragments; the default (DROP) may lose it when queues fill.
                self.session.put("rvd/" + key.replace("<run>", self.run), data,
                                 congestion_control=zenoh.CongestionControl.BLOCK)
                sides = {"cmd": ("host",), "nav": ("flight",), "bye": ("host", "flight")}[key.rsplit("/", 1)[1]]
                with self.lock:
                    for side in sides:
                        self.sent[(side, expected)] = self.sent.get((side, expected), 0) + 1
            self.reacted[kind] = step

    def count(self, side: str, kind: str | None = None) -> int:
        with self.lock:
            return sum(v for (s, k), v in self.sent.items() if s == side and kind in (None, k))

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()
        self.seen.put(None)
        self.worker.join(WAIT_S)
        self.session.close()


def attacked_run(tmp_path, reference, react, name: str, config: ServerConfig | None = None):
    """Case 1 with an Attacker reacting to every step; returns (summary, run_dir, attacker)."""
    params, _ = reference
    holder = {}

    def on_started(server, proc):
        wait_until(lambda: Path(f"/proc/{proc.pid}/cmdline").read_bytes(), "the flight process to start")
        holder["attacker"] = attacker = Attacker(proc.pid, react)
        attacker.wait_until_heard_by(server.link.session)  # before nav 0: it sees every step
        # What reaches the flight software travels through the host's Zenoh runtime, which forwards
        # the attacker's puts on the same link as its own navs and bye. A tap on the host's session
        # counts the flight-bound forgeries once they are there: waiting for it before the host goes
        # on orders every forgery before the next nav and before the bye that ends the run, so the
        # flight's final telemetry has heard them all, however loaded the machine.
        tapped = [0]

        def tap(sample):
            if str(sample.key_expr).rsplit("/", 1)[1] in ("nav", "bye"):
                with attacker.lock:
                    tapped[0] += 1
        holder["tap"] = server.link.session.declare_subscriber("rvd/**", tap, allowed_origin=zenoh.Locality.REMOTE)
        assert attacker.run == server.cfg.run_id and str(server.cfg.endpoint) == attacker.endpoint
        assert server.cfg.link_key.hex() not in attacker.cmdline  # the key is not on the command line

        def on_step(k, summary, cmd):
            # Bounded waits on conditions: the attacker has reacted to this step's nav and cmd, and
            # everything it sent that the host hears has been dropped and counted there.
            wait_until(lambda: attacker.reacted["nav"] >= k and attacker.reacted["cmd"] >= k,
                       f"the attacker reacting to step {k}")
            wait_until(lambda: server.link.discarded_total() >= attacker.count("host"),
                       f"the host counting the forgeries up to step {k}: sent {attacker.sent}, "
                       f"counted {server.link.discarded}")
            wait_until(lambda: tapped[0] >= attacker.count("flight"),
                       f"the host's runtime holding the flight-bound forgeries up to step {k}")
        server.on_step = on_step

    try:
        summary, run_dir = run_pil("case1_vbar", **IDEAL,
                                   sim_options={"cw_mean_motion_rad_s": params.mean_motion_rad_s()},
                                   config=config or ServerConfig(delay_model="none"), run_dir=tmp_path / name,
                                   on_started=on_started)
    finally:
        if "tap" in holder:
            holder["tap"].undeclare()
        if "attacker" in holder:
            holder["attacker"].close()
    return summary, run_dir, holder["attacker"]


def assert_undisturbed(summary, reference):
    _, ref = reference
    assert summary.end == "docked", summary.end
    assert summary.steps == ref.steps
    assert summary.dv_total_mps == pytest.approx(ref.total["dv_mps"], abs=1e-9)
    for phase in ("rendezvous", "approach", "docking"):
        assert summary.dv_per_phase_mps[phase] == pytest.approx(ref.phases[phase]["dv_mps"], abs=1e-9)
    assert summary.invalid_commands == 0


def host_rejection_events(run_dir) -> dict[str, int]:
    """The record's rejected_message events, counted by kind."""
    events = load_events(run_dir)
    out: dict[str, int] = {}
    for d in events[events["kind"] == "rejected_message"]["detail"]:
        kind = d.split(":", 1)[0]
        out[kind] = out.get(kind, 0) + 1
    return out


def flight_event_counts(run_dir) -> dict[str, int]:
    """What the flight software reported dropping, summed over the record's flight_discarded events."""
    events = load_events(run_dir)
    total: dict[str, int] = {}
    for detail in events[events["kind"] == "flight_discarded"]["detail"]:
        for part in detail.split(", "):
            name, plus = part.split(" +")
            total[name] = total.get(name, 0) + int(plus)
    return total


def assert_host_counted(summary, run_dir, attacker) -> None:
    """Every forgery the host heard is counted by kind: summary, meta and (up to 50 a kind) events."""
    sent = {k: attacker.count("host", k) for k in {k for s, k in attacker.sent if s == "host"}}
    assert {k: summary.discarded[k] for k in sent} == sent
    assert summary.rejected_messages == sum(sent.values())
    assert host_rejection_events(run_dir) == {k: min(n, 50) for k, n in sent.items() if n}
    meta, _ = load_run(run_dir)
    assert meta["host_discarded"] == summary.discarded and meta["rejected_messages"] == sum(sent.values())


FLIGHT_FIELD = {"untagged": "rx_untagged", "wrong_run": "rx_wrong_run", "bad_tag": "rx_bad_tag",
                "replayed": "rx_replayed", "oversized": "rx_oversized", "malformed": "nav_rejected",
                "unmatched": "link_rx_unmatched"}


def assert_flight_counted(summary, run_dir, attacker) -> None:
    """Every forgery the flight software heard is counted by kind in its telemetry and the events."""
    sent = {k: attacker.count("flight", k) for k in {k for s, k in attacker.sent if s == "flight"}}
    reported = {k: getattr(summary.telemetry, FLIGHT_FIELD[k]) for k in sent}
    assert reported == sent
    events = flight_event_counts(run_dir)
    assert {k: events.get(FLIGHT_FIELD[k], 0) for k in sent} == sent
    assert summary.telemetry.nav_future == summary.telemetry.nav_coalesced == 0


# ---- the attacks ----------------------------------------------------------------------------------

def test_forged_commands_for_the_next_step_are_dropped_and_the_run_docks_with_its_own(tmp_path, reference):
    rng = random.Random(1)

    def react(attacker, kind, genuine, step):
        if kind != "cmd" or genuine[msg.HEADER_SIZE + 4] == 4:  # nothing after the docked cmd: the run ends
            return []
        cmd = msg.Cmd(step=step + 1, phase=1, period_s=30.0, pulse_s=(30.0, 0.0, 0.0, 0.0, 30.0, 0.0))
        out = [("<run>/cmd", untagged(cmd), "untagged"),                       # the tagless protocol
               ("<run>/cmd", forged(cmd, rng=rng), "wrong_run"),               # made-up nonce and tag
               ("<run>/cmd", forged(cmd, copy_header_from=genuine, rng=rng), "bad_tag"),
               ("<run>/cmd", with_step(genuine, step + 1), "bad_tag"),          # the genuine one, edited
               ("<run>/cmd", genuine, "replayed")]                              # the genuine one again
        if step == 3:
            out.append(("<run>/cmd", bytes(16 << 20), "oversized"))            # 16 MiB
        return out

    summary, run_dir, attacker = attacked_run(tmp_path, reference, react, "forged_cmd")
    assert_undisturbed(summary, reference)
    assert attacker.count("host", "bad_tag") == 2 * (summary.steps - 1)  # every step but the docked one
    assert attacker.count("host", "oversized") == 1
    assert_host_counted(summary, run_dir, attacker)
    assert summary.stale_commands == summary.future_commands == 0


def test_forged_navs_do_not_change_the_flight_softwares_commands(tmp_path, reference):
    rng = random.Random(2)
    at_port = msg.Nav(step=0, t_s=0.0, position_lvlh_m=(0.0, -1.0, 0.0), velocity_lvlh_mps=(0.0, 0.0, 0.0),
                      q_lvlh_body=(0.7071067811865476, 0.0, 0.0, -0.7071067811865476))

    def react(attacker, kind, genuine, step):
        if kind != "nav":
            return []
        at_port.step, at_port.t_s = step, 0.0
        out = [("<run>/nav", untagged(at_port), "untagged"),
               ("<run>/nav", forged(at_port, copy_header_from=genuine, rng=rng), "bad_tag"),
               ("<run>/nav", forged(at_port, rng=rng), "wrong_run"),
               ("<run>/nav", with_step(genuine, step + 1), "bad_tag"),
               ("<run>/nav", genuine, "replayed")]
        if step == 5:
            out += [("<run>/nav", genuine, "replayed")] * 500                   # a flood of copies
            out.append(("<run>/nav", bytes(16 << 20), "oversized"))            # fragmented, above the cap
        return out

    summary, run_dir, attacker = attacked_run(tmp_path, reference, react, "forged_nav")
    assert_undisturbed(summary, reference)
    assert attacker.count("flight", "replayed") == summary.steps + 500
    assert_flight_counted(summary, run_dir, attacker)
    assert summary.rejected_messages == 0  # the host does not subscribe to nav


def test_forged_bye_even_on_a_wildcard_key_does_not_end_the_run(tmp_path, reference):
    rng = random.Random(3)

    def react(attacker, kind, genuine, step):
        if kind != "nav" or step % 10:
            return []
        bye = msg.Bye(reason=0, last_step=step, text="flight software ended the run")
        return [("<run>/bye", untagged(bye), "untagged"),
                ("<run>/bye", forged(bye, copy_header_from=genuine, rng=rng), "bad_tag"),
                ("<run>/bye", forged(bye, rng=rng), "wrong_run")]

    def react_wildcard(attacker, kind, genuine, step):
        out = react(attacker, kind, genuine, step)
        if out:  # and the same on rvd/*/bye
            out.append(("*/bye", untagged(msg.Bye(reason=0, last_step=step, text="bye")), "untagged_wildcard"))
        return out

    summary, run_dir, attacker = attacked_run(tmp_path, reference, react_wildcard, "forged_bye")
    assert_undisturbed(summary, reference)
    n = attacker.count("flight", "untagged_wildcard")
    assert n == len(range(0, summary.steps, 10))
    # The host's subscriber takes a put on rvd/*/bye like one on its own key; the flight's client
    # counts it among the samples no subscription of its own includes.
    assert summary.discarded["untagged"] == attacker.count("host", "untagged") + n
    assert summary.telemetry.link_rx_unmatched == n and summary.telemetry.rx_untagged == attacker.count("flight", "untagged")
    for kind in ("bad_tag", "wrong_run"):
        assert summary.discarded[kind] == attacker.count("host", kind)
        assert getattr(summary.telemetry, FLIGHT_FIELD[kind]) == attacker.count("flight", kind)
    assert host_rejection_events(run_dir)["untagged"] == summary.discarded["untagged"]
    assert flight_event_counts(run_dir)["link_rx_unmatched"] == n
    assert not summary.end.startswith("flight software ended the run")


def test_a_nav_for_step_0xffffffff_does_not_wedge_the_flight_software(tmp_path, reference):
    rng = random.Random(4)

    def react(attacker, kind, genuine, step):
        if kind != "nav" or step != 2:
            return []
        return [("<run>/nav", with_step(genuine, 0xFFFFFFFF), "bad_tag"),
                ("<run>/nav", forged(msg.Nav(step=0xFFFFFFFF, q_lvlh_body=(1.0, 0.0, 0.0, 0.0)),
                                     copy_header_from=genuine, rng=rng), "bad_tag"),
                ("<run>/nav", untagged(msg.Nav(step=0xFFFFFFFF, q_lvlh_body=(1.0, 0.0, 0.0, 0.0))), "untagged")]

    summary, run_dir, attacker = attacked_run(tmp_path, reference, react, "wedge")
    assert_undisturbed(summary, reference)  # docked, not "flight software lost"
    assert_flight_counted(summary, run_dir, attacker)
    assert summary.telemetry.nav_stale == 0 and summary.nav_resends == 0  # no genuine nav was refused as old


def test_wildcard_puts_and_wildcard_run_ids_are_refused(tmp_path, reference, flight_exe):
    def react(attacker, kind, genuine, step):
        if kind != "nav" or step != 4:
            return []
        return [("*/nav", genuine, "unmatched"),                                # a genuine nav, re-put on rvd/*/nav
                ("*/nav", untagged(msg.Nav(step=step + 1, q_lvlh_body=(1.0, 0.0, 0.0, 0.0))), "unmatched")]

    summary, run_dir, attacker = attacked_run(tmp_path, reference, react, "wildcard")
    assert_undisturbed(summary, reference)
    assert_flight_counted(summary, run_dir, attacker)
    # Run ids: the flight software refuses to start on one that is not a plain name (it would
    # subscribe to other runs' keys), and so does the host.
    for bad in ("*", "**", "", "a/b", "r$*"):
        r = subprocess.run([str(flight_exe), "--run", bad], env={**os.environ, msg.KEY_ENV: "11" * 32},
                           capture_output=True, text=True, timeout=WAIT_S)
        assert r.returncode == 2 and "A-Z a-z 0-9 _ -" in r.stderr, (bad, r.stderr)
        with pytest.raises(ValueError, match="run id"):
            run_pil("case1_vbar", **IDEAL, config=ServerConfig(run_id=bad or "-x-" * 30), run_dir=tmp_path / "never")
    # Without a key, or with one that is not 64 hex digits, it does not start either.
    env = {k: v for k, v in os.environ.items() if k != msg.KEY_ENV}
    for extra in ({}, {msg.KEY_ENV: "abc"}):
        r = subprocess.run([str(flight_exe), "--run", "r1"], env={**env, **extra}, capture_output=True, text=True,
                           timeout=WAIT_S)
        assert r.returncode == 2 and "link key" in r.stderr, r.stderr


# ---- a broken flight build: its commands break the declared limits ---------------------------------

@pytest.fixture(scope="module")
def faulty_exe() -> Path:
    """rvd_flight_sw_faulty: the flight executable built with --fault (built by `make build`)."""
    try:
        return find_flight_executable(name="rvd_flight_sw_faulty")
    except FileNotFoundError as exc:
        pytest.fail(str(exc))


@pytest.mark.parametrize("fault, why", [
    ("zero-period", "period_s 0.0 s is not the declared period 30.0 s"),
    ("wrong-period", "period_s 7.0 s is not the declared period 30.0 s"),
    ("negative-pulse", "pulse_s[2] = -0.5 s is negative"),
    ("oversized-pulse", "pulse_s[0] = 30.0 s is longer than the declared"),
    ("nan", "NaN or Inf"),
])
def test_invalid_commands_are_recorded_flight_faults_and_never_applied(tmp_path, reference, faulty_exe, fault, why):
    params, ref = reference
    summary, run_dir = run_pil("case1_vbar", **IDEAL, sim_options={"cw_mean_motion_rad_s": params.mean_motion_rad_s()},
                               flight_exe=str(faulty_exe), flight_args=["--fault", f"{fault}@5"],
                               config=ServerConfig(delay_model="none"), run_dir=tmp_path / fault)
    assert summary.end.startswith("flight fault: invalid command for step 5: "), summary.end
    assert why in summary.end and summary.invalid_commands == 1
    meta, steps = load_run(run_dir)
    assert meta["status"] == "finished" and meta["invalid_commands"] == 1 and meta["end"] == summary.end
    # Steps 0-4 are the genuine closed loop; step 5 is recorded with its state and no command applied.
    assert list(steps["step"]) == list(range(6))
    truth = steps[[f"truth_{c}" for c in ("x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps")]].to_numpy()
    assert truth == pytest.approx(ref.x[:6], abs=1e-9)
    assert steps["pulse_applied_px_s"].iloc[:5].notna().all() and math.isnan(steps["pulse_applied_px_s"].iloc[5])
    events = load_events(run_dir)
    faults = list(events[events["kind"] == "flight_fault"]["detail"])
    assert len(faults) == 1 and "not applied" in faults[0] and why in faults[0]
    assert "host_error" not in set(events["kind"])  # a recorded fault, not a traceback


def test_commands_for_a_step_never_asked_for_are_counted_and_ignored(tmp_path, reference, faulty_exe):
    params, _ = reference
    summary, run_dir = run_pil("case1_vbar", **IDEAL, sim_options={"cw_mean_motion_rad_s": params.mean_motion_rad_s()},
                               flight_exe=str(faulty_exe), flight_args=["--fault", "future-step@5"],
                               config=ServerConfig(delay_model="none", cmd_timeout_s=0.5, nav_retries=2),
                               run_dir=tmp_path / "future")
    # Every answer to nav 5 (the first and two resends) claims step 1000000: none is applied.
    assert summary.end == "flight software lost" and summary.steps == 5
    assert summary.future_commands == 3 and summary.invalid_commands == 0
    events = load_events(run_dir)
    assert (events["kind"] == "future_cmd").sum() == 3
    assert load_run(run_dir)[0]["future_commands"] == 3


# ---- the host dies: the flight software leaves, the record says so -------------------------------------

HOST_THAT_HANGS_AT_STEP_25 = """
import sys, threading
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.server import ServerConfig

def on_started(server, proc):
    def on_step(k, summary, cmd):
        if k == 25:
            print("AT_STEP_25", flush=True)
            threading.Event().wait()   # killed here
    server.on_step = on_step

run_pil("case1_vbar", truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True,
        config=ServerConfig(delay_model="none"), run_dir=sys.argv[1], on_started=on_started)
"""
# The flight software's documented bound after it loses its host (flight_sw/link/README.md): 4 s of
# failed reconnects plus at most one attempt in progress (3 x 2 s).
HOST_LOSS_BOUND_S = 10.0


def test_host_killed_with_sigkill_the_flight_software_leaves_and_the_record_says_the_host_died(tmp_path):
    from rvd_pil.host_sim.record import _process_start_ticks

    run_dir = tmp_path / "killed"
    host = subprocess.Popen([sys.executable, "-c", HOST_THAT_HANGS_AT_STEP_25, str(run_dir)], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: "queue.Queue[str | None]" = queue.Queue()
    threading.Thread(target=lambda: [lines.put(l) for l in host.stdout] + [lines.put(None)], daemon=True).start()
    try:
        assert lines.get(timeout=60) == "AT_STEP_25\n", host.stderr.read()
        flight_pid = json.loads((run_dir / "meta.json").read_text())["flight_pid"]
        assert _process_start_ticks(flight_pid) is not None
        host.send_signal(signal.SIGKILL)
        host.wait(WAIT_S)
    finally:
        if host.poll() is None:
            host.kill()
            host.wait()
    # The flight process (now an orphan) must be gone within its bound (plus scheduling slack on a
    # loaded machine); its own log says why and after how long.
    wait_until(lambda: _process_start_ticks(flight_pid) is None, "the flight process to exit",
               timeout=HOST_LOSS_BOUND_S + 5)
    log = (run_dir / "flight_sw.log").read_text()
    assert "exit: host lost (link down)" in log and "(limit 4.0 s)" in log, log[-2000:]
    meta, steps = load_run(run_dir)
    assert meta["status"] == HOST_DIED and "ended without closing the record" in meta["host_died"]["reason"]
    assert len(steps) == 26 and meta["host_died"]["steps_recorded"] == 26
    assert json.loads((run_dir / "meta.json").read_text())["status"] == HOST_DIED  # marked on disk too


# ---- the exact reference repeats bit for bit ------------------------------------------------------------

def test_rvd_run_ideal_three_times_gives_the_same_record(tmp_path):
    dirs = [tmp_path / f"run{i}" for i in range(3)]
    for d in dirs:
        r = subprocess.run([sys.executable, "-m", "rvd_pil.host_sim.cli", "case1_vbar", "--truth", "cw", "--ideal", "-q",
                            "--out", str(d)], cwd=REPO, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stdout + r.stderr
        assert "delay_model" not in r.stdout.split("depends on this host's speed:", 1)[1].splitlines()[0]
    assert len({record_digest(d) for d in dirs}) == 1
    metas, steps = zip(*(load_run(d) for d in dirs))
    assert all(m["delay_model"] == "none" and "delay_model" not in m["host_speed_dependent"] for m in metas)
    assert len({m["dv_total_mps"] for m in metas}) == 1  # the same double, not just close
    keep = [c for c in steps[0].columns if c not in TIMING_COLUMNS]
    csvs = [s[keep].to_csv(index=False) for s in steps]
    assert csvs[0] == csvs[1] == csvs[2]
    assert (steps[0]["delay_s"].iloc[:-1] == 0).all()  # the last (docked) step applies nothing


def test_flight_software_stopped_and_continued_the_run_is_unchanged(tmp_path, reference):
    """SIGSTOP the flight process after step 10; the host's wait for cmd 11 times out and it resends
    nav 11, at which point (an event, not a delay) the flight process is continued. Both navs 11 are
    then waiting for it: one is answered, the other overtaken (coalesced) or answered again from the
    cache (duplicate). The run is the undisturbed one."""
    params, _ = reference
    state = {}

    def on_started(server, proc):
        state["proc"] = proc

        def on_step(k, summary, cmd):
            if k == 10:
                proc.send_signal(signal.SIGSTOP)
                state["stopped"] = True
        server.on_step = on_step

    def resend_continues(k, attempt):
        if attempt == 1 and state.get("stopped") and "continued" not in state:
            state["proc"].send_signal(signal.SIGCONT)
            state["continued"] = k
        return False  # nothing is dropped

    summary, run_dir = run_pil("case1_vbar", **IDEAL, sim_options={"cw_mean_motion_rad_s": params.mean_motion_rad_s()},
                               config=ServerConfig(delay_model="none", cmd_timeout_s=0.3, nav_retries=3,
                                                   drop_nav=resend_continues),
                               run_dir=tmp_path / "stopped", on_started=on_started)
    assert state["continued"] == 11
    assert_undisturbed(summary, reference)
    t = summary.telemetry
    assert summary.nav_resends >= 1
    assert t.nav_coalesced + t.nav_duplicates == summary.nav_resends
