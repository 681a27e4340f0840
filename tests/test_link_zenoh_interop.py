"""The flight-side C++ Zenoh client against the real eclipse-zenoh (Python), in peer and router mode.

The Python session listens on a free loopback port; the C++ probe (tests/cpp/tools/zenoh_probe.cpp)
connects as a client. Truth comes from the Python side: what it received, its ZenohID, its own
timestamps, and its matching status (which shows that a C++ declaration reached it).
"""

import queue
import time

import pytest

import zenoh  # noqa: E402  (pinned dependency: a missing one is a failure, not a skip)

from support.zenoh_link_harness import Probe, free_port, pattern, python_zenoh, wait_matching  # noqa: E402

MODES = ["peer", "router"]


@pytest.fixture(params=MODES)
def host(request):
    """A Python Zenoh session listening on a free port: (mode, endpoint, session)."""
    port = free_port()
    session = python_zenoh(request.param, port)
    yield request.param, f"tcp/127.0.0.1:{port}", session
    session.close()


def subscribe(session, key):
    """A Python subscriber whose samples land in a queue as (key, payload, encoding)."""
    q = queue.Queue()
    sub = session.declare_subscriber(
        key, lambda s: q.put((str(s.key_expr), s.payload.to_bytes(), str(s.encoding))))
    return sub, q


def test_handshake_adopts_the_smaller_batch_and_names_the_remote(host):
    mode, endpoint, session = host
    with Probe(endpoint, "--batch", "2048") as p:
        o = p.expect("OPEN")
        assert o["status"] == "Ok"
        assert o["batch"] == "2048"                      # min(ours, theirs)
        assert o["sn_mask"] == str(2**28 - 1)            # 32-bit resolution adopted
        assert o["whatami"] == mode
        assert o["remote_zid"] == str(session.zid())     # the ZID as Zenoh itself prints it
        assert o["remote_lease_ms"] == "10000"
        assert o["markers"] == "1"                       # patch 1 echoed: fragment markers


def test_subscribe_and_put_in_both_directions(host):
    mode, endpoint, session = host
    sub, got = subscribe(session, "rvd/test/cmd")
    nav = session.declare_publisher("rvd/test/nav", congestion_control=zenoh.CongestionControl.BLOCK, encoding=zenoh.Encoding.TEXT_PLAIN)
    other = session.declare_publisher("rvd/test/other", congestion_control=zenoh.CongestionControl.BLOCK)
    with Probe(endpoint, "--sub", "rvd/*/nav", "--print-payload", "--encoding", "5") as p:
        assert p.expect("OPEN")["status"] == "Ok"
        wait_matching(nav)
        assert not other.matching_status.matching   # the wildcard does not cover this key

        nav.put(b"state vector k=1")
        s = p.expect("SAMPLE")
        assert s["key"] == "rvd/test/nav"
        assert bytes.fromhex(s["payload"]) == b"state vector k=1"
        assert s["enc"] == "4"                       # text/plain
        assert s["mapping"] == "full"
        assert s["kind"] == "put"

        session.delete("rvd/test/nav")
        d = p.expect("SAMPLE")
        assert (d["key"], d["kind"], d["len"]) == ("rvd/test/nav", "del", "0")

        p.send("put rvd/test/cmd 300")
        assert p.expect("PUT")["status"] == "Ok"
        key, payload, encoding = got.get(timeout=10)
        assert key == "rvd/test/cmd"
        assert payload == pattern(300)
        assert encoding == "application/json"        # encoding id 5 sent by the client
    sub.undeclare()


def test_lockstep_ten_thousand_exchanges_without_loss(host):
    """Python puts k on nav, the C++ side echoes it on cmd, Python waits for each k."""
    mode, endpoint, session = host
    sub, got = subscribe(session, "rvd/test/cmd")
    nav = session.declare_publisher("rvd/test/nav", congestion_control=zenoh.CongestionControl.BLOCK)
    n = 10_000
    with Probe(endpoint, "--sub", "rvd/test/nav", "--echo", "rvd/test/cmd", "--quiet", "--check-seq") as p:
        assert p.expect("OPEN")["status"] == "Ok"
        wait_matching(nav)
        for k in range(n):
            nav.put(k.to_bytes(8, "little"))
            key, payload, _ = got.get(timeout=10)
            assert key == "rvd/test/cmd"
            assert int.from_bytes(payload, "little") == k, f"exchange {k} got {payload!r}"
        # A last exchange as the marker: replies keep their order, so a reply sent twice would
        # arrive before the marker's, and no pause is needed to see it.
        nav.put(n.to_bytes(8, "little"))
        _, payload, _ = got.get(timeout=10)
        assert int.from_bytes(payload, "little") == n, f"a reply arrived twice: {payload!r} before the marker"
        assert got.empty(), "a reply arrived twice"
        st = p.stats()
    assert st["samples_rx"] == n + 1
    assert st["puts_tx"] == n + 1
    assert st["seq_errors"] == 0
    assert st["rx_rejected"] == 0
    assert st["link_losses"] == 0
    sub.undeclare()


@pytest.mark.parametrize("batch,size", [(2048, 70_003), (65535, 100_000)])
def test_payload_larger_than_the_batch_arrives_fragmented_and_reassembled(host, batch, size):
    mode, endpoint, session = host
    data = bytes((i * 131 + 17) % 251 for i in range(size))
    pub = session.declare_publisher("rvd/test/big", congestion_control=zenoh.CongestionControl.BLOCK)
    with Probe(endpoint, "--batch", str(batch), "--sub", "rvd/test/big", "--print-payload") as p:
        o = p.expect("OPEN")
        assert int(o["batch"]) < size
        wait_matching(pub)
        pub.put(data)
        pub.put(b"after")
        s = p.expect("SAMPLE", timeout=20)
        assert int(s["len"]) == size
        assert bytes.fromhex(s["payload"]) == data
        assert bytes.fromhex(p.expect("SAMPLE")["payload"]) == b"after"
        st = p.stats()
    assert st["fragments_rx"] >= size // int(o["batch"])
    assert st["reassembled_rx"] == 1
    assert st["rx_rejected"] == 0


def test_too_large_put_is_rejected_and_the_largest_that_fits_arrives(host):
    mode, endpoint, session = host
    sub, got = subscribe(session, "rvd/test/cmd")
    with Probe(endpoint, "--batch", "2048") as p:
        assert p.expect("OPEN")["status"] == "Ok"
        p.send("put rvd/test/cmd 3000")
        r = p.expect("PUT")
        assert r["status"] == "MessageTooLarge"
        assert "never fragments" in r["error"]
        largest = int(r["max"])
        assert 2000 < largest < 2048
        p.send(f"put rvd/test/cmd {largest + 1}")
        assert p.expect("PUT")["status"] == "MessageTooLarge"
        p.send(f"put rvd/test/cmd {largest}")
        assert p.expect("PUT")["status"] == "Ok"
        key, payload, _ = got.get(timeout=10)
        assert payload == pattern(largest)
        assert p.stats()["link_losses"] == 0          # the rejection did not disturb the link
    sub.undeclare()


def test_timestamps_are_parsed(host):
    """An explicit timestamp arrives intact; a router stamps unstamped puts itself."""
    mode, endpoint, session = host
    pub = session.declare_publisher("rvd/test/nav", congestion_control=zenoh.CongestionControl.BLOCK)
    with Probe(endpoint, "--sub", "rvd/test/nav") as p:
        assert p.expect("OPEN")["status"] == "Ok"
        wait_matching(pub)
        ts = session.new_timestamp()
        session.put("rvd/test/nav", b"stamped", timestamp=ts, congestion_control=zenoh.CongestionControl.BLOCK)
        s = p.expect("SAMPLE")
        assert int(s["ts"]) == int(str(ts.get_time_as_ntp64()))
        assert s["tsid"] == str(ts.get_id())

        pub.put(b"plain")
        s = p.expect("SAMPLE")
        if mode == "router":
            assert s["tsid"] == str(session.zid())
            assert abs((int(s["ts"]) >> 32) - time.time()) < 120   # NTP64: UNIX seconds << 32
        else:
            assert s["ts"] == "-"                                   # peers do not stamp


def test_declared_key_expressions_sender_and_receiver_mapped(host):
    """Puts by our declared id (sender mapping) reach Python under the right key; a subscription
    by declared id makes the router push by that id (receiver mapping, our own table)."""
    mode, endpoint, session = host
    sub, got = subscribe(session, "rvd/test/cmd")
    nav = session.declare_publisher("rvd/test/nav", congestion_control=zenoh.CongestionControl.BLOCK)
    args = ["--declare", "rvd/test/cmd", "--declare", "rvd/test/nav", "--sub", "rvd/test/nav",
            "--echo", "rvd/test/cmd"]
    with Probe(endpoint, *args) as p:
        assert p.expect("OPEN")["status"] == "Ok"
        wait_matching(nav)
        for k in range(5):
            nav.put(bytes([k]) * 10)
            s = p.expect("SAMPLE")
            assert (s["key"], s["mapping"]) == ("rvd/test/nav", "receiver")
            key, payload, _ = got.get(timeout=10)
            assert (key, payload) == ("rvd/test/cmd", bytes([k]) * 10)
        st = p.stats()
    # Both peer and router answer a subscription by id with pushes keyed by that id (M = 0).
    assert st["rx_receiver_mapped"] == 5
    assert st["rx_rejected"] == 0
    sub.undeclare()
