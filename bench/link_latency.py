"""Round-trip latency of the flight link: nav -> flight side -> cmd through Zenoh on loopback.

The host is a real eclipse-zenoh session (peer or router) listening on a free port. Two echoers
answer every nav message with the same bytes on cmd, measured side by side in one run, in
interleaved blocks so that machine noise hits both alike:

  * the C++ flight client (tests/cpp/tools/zenoh_probe --echo), i.e. rvd::link::ZenohSession
    with a trivial "guidance";
  * a Python eclipse-zenoh client session doing the same (the Rust stack as the reference).

    python -m bench.link_latency [--n 2000] [--mode peer] [--payload 64]
    python -m bench.link_latency --runner "qemu-aarch64 -cpu cortex-a53" --probe build/aarch64/tests/cpp/zenoh_probe

--runner prefixes the probe command (QEMU user mode reaches 127.0.0.1 directly), so the same
measurement covers an emulated flight CPU; the Python reference echoer always runs natively.
Host wall time under QEMU is not target time (see DESIGN.md section 7).
"""

from __future__ import annotations

import argparse
import os
import queue
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from zenoh_link_harness import Probe, free_port, python_zenoh, wait_matching  # noqa: E402


def percentile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(round(q * (len(s) - 1))))]


def python_echoer(endpoint: str, nav: str, cmd: str):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    publisher = session.declare_publisher(cmd)
    subscriber = session.declare_subscriber(nav, lambda s: publisher.put(s.payload))
    return session, subscriber


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=2000, help="exchanges per echoer (default 2000)")
    ap.add_argument("--block", type=int, default=200, help="exchanges per interleaved block")
    ap.add_argument("--warmup", type=int, default=100, help="untimed exchanges per echoer first")
    ap.add_argument("--payload", type=int, default=64, help="nav payload bytes (default 64)")
    ap.add_argument("--mode", choices=["peer", "router"], default="peer", help="host Zenoh mode")
    ap.add_argument("--runner", default="", help='command prefix for the probe, e.g. "qemu-aarch64 -cpu cortex-a53"')
    ap.add_argument("--probe", default=None, help="zenoh_probe binary (default: $RVD_ZENOH_PROBE or build/native)")
    ap.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for one reply")
    args = ap.parse_args(argv)
    if args.probe:
        os.environ["RVD_ZENOH_PROBE"] = args.probe

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    host = python_zenoh(args.mode, port)
    replies = {"cpp": queue.Queue(), "py": queue.Queue()}
    publishers = {}
    for name in replies:
        host.declare_subscriber(f"rvd/bench/{name}/cmd", lambda s, q=replies[name]: q.put(s.payload.to_bytes()))
        publishers[name] = host.declare_publisher(f"rvd/bench/{name}/nav")

    probe = Probe(endpoint, "--sub", "rvd/bench/cpp/nav", "--echo", "rvd/bench/cpp/cmd", "--quiet",
                  "--lease-ms", "30000", runner=args.runner)
    py_session, _py_sub = python_echoer(endpoint, "rvd/bench/py/nav", "rvd/bench/py/cmd")
    rtt_us: dict[str, list[float]] = {"cpp": [], "py": []}
    try:
        if probe.expect("OPEN", timeout=60)["status"] != "Ok":
            print("the probe could not open its session:", probe.history[-1], file=sys.stderr)
            return 1
        for pub in publishers.values():
            wait_matching(pub, timeout=60)

        payload = bytearray(os.urandom(args.payload))

        def exchange(name: str, k: int) -> float:
            payload[:8] = k.to_bytes(8, "little")
            t0 = time.perf_counter_ns()
            publishers[name].put(bytes(payload))
            got = replies[name].get(timeout=args.timeout)
            t1 = time.perf_counter_ns()
            if got[:8] != payload[:8]:
                raise RuntimeError(f"{name}: reply {k} out of order")
            return (t1 - t0) / 1000.0

        k = 0
        for name in rtt_us:
            for _ in range(args.warmup):
                exchange(name, k)
                k += 1
        done = 0
        while done < args.n:
            block = min(args.block, args.n - done)
            for name in rtt_us:
                for _ in range(block):
                    rtt_us[name].append(exchange(name, k))
                    k += 1
            done += block
        stats = probe.stats()
    finally:
        probe.close()
        py_session.close()
        host.close()

    runner = args.runner or "native"
    print(f"Link round trip nav -> echo -> cmd, {args.n} exchanges each, {args.payload} B payload, "
          f"host in {args.mode} mode, loopback TCP; C++ probe runner: {runner}")
    print(f"{'echo side':<34}{'median':>10}{'p99':>10}{'mean':>10}{'max':>10}   [us]")
    rows = {"cpp": "C++ rvd::link::ZenohSession", "py": "Python eclipse-zenoh client"}
    for name, label in rows.items():
        xs = rtt_us[name]
        print(f"{label:<34}{statistics.median(xs):>10.1f}{percentile(xs, 0.99):>10.1f}"
              f"{statistics.fmean(xs):>10.1f}{max(xs):>10.1f}")
    ratio = statistics.median(rtt_us["cpp"]) / statistics.median(rtt_us["py"])
    print(f"median ratio C++ / Python: {ratio:.2f}")
    print(f"C++ side counters: samples {stats['samples_rx']}, puts {stats['puts_tx']}, "
          f"rejected {stats['rx_rejected']}, link losses {stats['link_losses']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
