"""Faults on the flight-side Zenoh link: the host restarting or freezing, a silent or hostile peer.

Real eclipse-zenoh where it can produce the fault (restart, freeze, idle link); a scripted raw peer
on a Python socket (tests/support/zenoh_link_harness.py) for what Zenoh never sends on demand: malformed
bytes, remote key declarations, SN gaps, fragment markers, refusals and silence.
"""

import random
import select
import signal
import subprocess
import sys
import textwrap

import pytest

import zenoh  # noqa: E402  (pinned dependency: a missing one is a failure, not a skip)

from support.zenoh_link_harness import (  # noqa: E402
    REPO, Probe, RawPeer, declare_keyexpr, fragment, frame, free_port, push_put, python_zenoh,
    undeclare_keyexpr, vle, wait_matching, zstr)


def lockstep(session_pub, replies, ks, timeout=10.0):
    for k in ks:
        session_pub.put(k.to_bytes(8, "little"))
        payload = replies.get(timeout=timeout)
        assert int.from_bytes(payload, "little") == k


# ---- real Zenoh ------------------------------------------------------------------------------

@pytest.mark.parametrize("mode", ["peer", "router"])
def test_host_restart_is_detected_then_reconnected_redeclared_and_resumed(mode):
    import queue

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    args = ["--declare", "rvd/test/cmd", "--sub", "rvd/test/nav", "--echo", "rvd/test/cmd", "--quiet"]
    first = python_zenoh(mode, port)
    try:
        with Probe(endpoint, *args) as p:
            replies = queue.Queue()
            first.declare_subscriber("rvd/test/cmd", lambda s: replies.put(s.payload.to_bytes()))
            nav = first.declare_publisher("rvd/test/nav", congestion_control=zenoh.CongestionControl.BLOCK)
            assert p.expect("OPEN")["status"] == "Ok"
            wait_matching(nav)
            lockstep(nav, replies, range(200))

            first.close()
            lost = p.expect("EVENT")
            assert lost["status"] == "LinkLost"
            assert "Close" in lost["error"] or "closed" in lost["error"]

            second = python_zenoh(mode, port)
            try:
                replies2 = queue.Queue()
                second.declare_subscriber("rvd/test/cmd", lambda s: replies2.put(s.payload.to_bytes()))
                nav2 = second.declare_publisher("rvd/test/nav", congestion_control=zenoh.CongestionControl.BLOCK)
                wait_matching(nav2, timeout=30)          # the subscriber was declared again
                assert p.expect("RECONNECTED", timeout=30)["remote_zid"] == str(second.zid())
                # The echo goes out by the re-declared key id: it only arrives if that was redone too.
                lockstep(nav2, replies2, range(200, 400))
                st = p.stats()
            finally:
                second.close()
    finally:
        if not first.is_closed():
            first.close()
    assert st["reconnects"] == 1
    assert st["link_losses"] == 1
    assert st["samples_rx"] == 400


def test_frozen_host_is_detected_by_lease_expiry_and_reconnected_after():
    """SIGSTOP the Python host (lease 1 s): TCP stays open, nothing arrives, the lease expires."""
    port = free_port()
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(REPO / 'tests')!r})
        from support.zenoh_link_harness import python_zenoh
        s = python_zenoh("peer", {port}, lease_ms=1000)
        print("READY", flush=True)
        sys.stdin.read()
        s.close()
    """)
    host = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert select.select([host.stdout], [], [], 60)[0], "the Python host did not start"
        assert host.stdout.readline().strip() == "READY"
        with Probe(f"tcp/127.0.0.1:{port}", "--sub", "rvd/test/nav",
                   "--connect-timeout-ms", "500") as p:
            o = p.expect("OPEN")
            assert o["status"] == "Ok"
            assert o["remote_lease_ms"] == "1000"
            host.send_signal(signal.SIGSTOP)
            ev = p.expect("EVENT", timeout=15)
            assert ev["status"] == "LeaseExpired"
            host.send_signal(signal.SIGCONT)
            p.expect("RECONNECTED", timeout=30)
            st = p.stats()
        assert st["lease_expirations"] == 1
        assert st["reconnects"] >= 1
    finally:
        host.send_signal(signal.SIGCONT)
        host.stdin.close()
        try:
            host.wait(10)
        except subprocess.TimeoutExpired:
            host.kill()
            host.wait()


def test_keepalives_hold_an_idle_link_open():
    """With a 1 s announced lease and no traffic, only our KeepAlives keep Zenoh from dropping us."""
    port = free_port()
    session = python_zenoh("peer", port)
    try:
        with Probe(f"tcp/127.0.0.1:{port}", "--lease-ms", "1000", "--sub", "rvd/test/nav") as p:
            assert p.expect("OPEN")["status"] == "Ok"
            # Idle until 12 KeepAlives went out (one per lease/4 of silence: three leases), however
            # long the machine takes for that; a lost link would show as an EVENT and a link loss.
            st = p.wait_for_stat("keepalives_tx", 12)
            assert not [line for line in p.history if line.startswith("EVENT")]
        assert st["link_losses"] == 0
        assert st["samples_rx"] == 0             # nothing but KeepAlives kept the link
    finally:
        session.close()


# ---- scripted raw peer --------------------------------------------------------------------------

def open_raw(peer, *probe_args, **handshake):
    p = Probe(peer.endpoint, "--sub", "rvd/test/nav", "--print-payload", *probe_args)
    try:
        peer.accept()
        peer.handshake(**handshake)
        o = p.expect("OPEN")
        assert o["status"] == "Ok"
        o["declarations"] = peer.wait_for_bytes(b"rvd/test/nav")  # our declarations arrived
    except BaseException:
        p.close()
        raise
    return p, o


def batches_until_closed(peer):
    """Everything the client sent after what tests already consumed, up to its disconnect."""
    out = []
    while (b := peer.received.get(timeout=10)) is not None:
        out.append(b)
    return out


def test_malformed_batches_are_rejected_counted_and_survived():
    with RawPeer() as peer:
        p, _ = open_raw(peer)
        with p:
            good_push = push_put("rvd/test/nav", b"x")
            bad = [
                bytes([0x3F, 0xFF, 0x00]),                                    # not a transport MID
                frame(peer.next_sn(), good_push[:-1]),                        # truncated payload
                frame(peer.next_sn(), push_put(None, b"x", 9, sender_mapping=False)),  # id we never declared
                frame(peer.next_sn(), push_put(None, b"x", 4, sender_mapping=True)),   # id never declared to us
                bytes([0x07, 0x01]),                                          # Join: multicast only
                frame(peer.next_sn(), b"\x3d\x00" + zstr("rvd/test/nav") + b"\x09"),  # no Put/Del body
                frame(peer.next_sn(), b"\xbd\x00" + zstr("rvd/test/nav") + b"\x60"),  # reserved ext encoding
                frame(peer.next_sn(), b"\x3d" + vle(70000) + b"\x00\x01\x00"),  # scope beyond u16
                fragment(peer.next_sn(), b"\x99\x99", more=False, first=True),  # reassembles to garbage
                bytes([0x01, 0x09]),                                          # Init on an open session, cut
            ]
            first_of_gap = fragment(peer.next_sn(), good_push[:5], more=True, first=True)
            peer.next_sn()                                                    # skip one: gap in the chain
            gap = [first_of_gap, fragment(peer.next_sn(), good_push[5:], more=False)]
            for b in bad + gap:
                peer.send(b)
            peer.send(frame(peer.next_sn(), push_put("rvd/test/nav", b"still alive")))
            s = p.expect("SAMPLE", payload=b"still alive".hex())
            assert s["key"] == "rvd/test/nav"
            st = p.stats()
        assert st["rx_rejected"] == len(bad) + 1
        assert st["samples_rx"] == 1
        assert st["link_losses"] == 0


def test_fuzzed_network_messages_and_transport_bytes_never_crash_the_client():
    """600 random or bit-flipped batches. No fuzzed byte carries the Close, Frame or Fragment MID in
    its low five bits, so the fuzz can neither end the link nor move the SN window; a final valid
    push then proves the same session is still in step."""
    rng = random.Random(20240607)
    forbidden = {0x03, 0x05, 0x06}

    def clean(body):
        return not any(b & 0x1F in forbidden for b in body)

    def random_bytes(n):
        out = bytearray()
        while len(out) < n:
            b = rng.randrange(256)
            if b & 0x1F not in forbidden:
                out.append(b)
        return bytes(out)

    with RawPeer() as peer:
        p = Probe(peer.endpoint, "--sub", "rvd/zz/nav", "--print-payload")
        with p:
            peer.accept()
            peer.handshake()
            assert p.expect("OPEN")["status"] == "Ok"
            peer.wait_for_bytes(b"rvd/zz/nav")
            valid = [push_put("rvd/zz/nav", b"payload"), declare_keyexpr(7, "rvd/xyz"),
                     b"\x79\x09\x36\x00" + zstr("rvd/q/**")]  # Push, DeclareKeyExpr, Interest
            assert all(clean(v) for v in valid)
            for i in range(600):
                kind = i % 3
                if kind == 0:    # random bytes after a network MID, inside a numbered frame
                    body = bytes([0x19 + rng.randrange(7)]) + random_bytes(rng.randrange(1, 60))
                    batch = frame(peer.next_sn(), body)
                elif kind == 1:  # a valid network message with flipped bits
                    while True:
                        body = bytearray(rng.choice(valid))
                        for _ in range(rng.randrange(1, 4)):
                            body[rng.randrange(len(body))] ^= 1 << rng.randrange(8)
                        if clean(body):
                            break
                    batch = frame(peer.next_sn(), bytes(body))
                else:            # random transport-level bytes
                    batch = random_bytes(rng.randrange(1, 40))
                peer.send(batch)
            peer.send(frame(peer.next_sn(), push_put("rvd/zz/nav", b"after the storm")))
            p.expect("SAMPLE", timeout=20, payload=b"after the storm".hex())
            st = p.stats()
        assert st["link_losses"] == 0
        assert st["rx_sn_dropped"] == 0
        assert st["rx_rejected"] > 300           # most fuzzed batches are malformed, and counted
        assert p.proc.returncode == 0


def test_remote_declared_and_own_declared_key_ids():
    with RawPeer() as peer:
        p, o = open_raw(peer, "--declare", "rvd/test/nav")
        with p:
            # Our DeclareKeyExpr(1, "rvd/test/nav"), then DeclareSubscriber(1) by that id (M = 1).
            assert b"\x1e\x20\x01\x00\x0crvd/test/nav\x1e\x42\x01\x01" in o["declarations"]
            # Sender mapping: the peer declares 5 -> "rvd/test" and pushes by 5 + suffix.
            peer.send(frame(peer.next_sn(), declare_keyexpr(5, "rvd/test"),
                            push_put("/nav", b"by remote id", 5, sender_mapping=True)))
            s = p.expect("SAMPLE")
            assert (s["key"], s["mapping"], s["payload"]) == ("rvd/test/nav", "sender", b"by remote id".hex())
            # Receiver mapping: our own id 1, no suffix.
            peer.send(frame(peer.next_sn(), push_put(None, b"by our id", 1, sender_mapping=False)))
            s = p.expect("SAMPLE")
            assert (s["key"], s["mapping"], s["payload"]) == ("rvd/test/nav", "receiver", b"by our id".hex())
            # After UndeclareKeyExpr the id no longer resolves.
            peer.send(frame(peer.next_sn(), undeclare_keyexpr(5),
                            push_put("/nav", b"stale", 5, sender_mapping=True)))
            peer.send(frame(peer.next_sn(), push_put("rvd/test/nav", b"end")))
            p.expect("SAMPLE", payload=b"end".hex())
            st = p.stats()
        assert b"\x23\x00" in batches_until_closed(peer)   # close(): Close(session, GENERIC)
        assert st["rx_sender_mapped"] == 1
        assert st["rx_receiver_mapped"] == 1
        assert st["rx_rejected"] == 1


@pytest.mark.parametrize("markers", [True, False])
def test_mixed_reliability_batches_duplicates_and_fragment_chains(markers):
    with RawPeer() as peer:
        p, o = open_raw(peer, patch=markers)
        assert o["markers"] == ("1" if markers else "0")
        with p:
            # Best-effort and reliable frames alternating in one batch (§3), then a KeepAlive.
            peer.send(frame(peer.next_sn(False), push_put("rvd/test/nav", b"a"), reliable=False)
                      + frame(peer.next_sn(), push_put("rvd/test/nav", b"b"), push_put("rvd/test/nav", b"c"))
                      + frame(peer.next_sn(False), push_put("rvd/test/nav", b"d"), reliable=False)
                      + b"\x04")
            assert [p.expect("SAMPLE")["payload"] for _ in range(4)] == [x.hex() for x in (b"a", b"b", b"c", b"d")]
            # A duplicate (old SN) is dropped.
            peer.send(frame(peer.sn - 1, push_put("rvd/test/nav", b"dup")))
            # A fragmented message, one SN skipped before it as Rust does; pieces of 7 bytes.
            big = bytes(range(256)) * 4
            msg = push_put("rvd/test/nav", big)
            pieces = [msg[i:i + 300] for i in range(0, len(msg), 300)]
            peer.next_sn()
            for i, piece in enumerate(pieces):
                peer.send(fragment(peer.next_sn(), piece, more=i + 1 < len(pieces), first=markers and i == 0))
            assert p.expect("SAMPLE")["payload"] == big.hex()
            rejected = 0
            if markers:
                # Drop marker: the partial message is discarded without complaint.
                peer.send(fragment(peer.next_sn(), pieces[0], more=True, first=True))
                peer.send(fragment(peer.next_sn(), b"", more=False, drop=True))
            # An SN gap inside a chain breaks it.
            peer.send(fragment(peer.next_sn(), pieces[0], more=True, first=markers))
            peer.next_sn()
            for i, piece in enumerate(pieces[1:], start=1):
                peer.send(fragment(peer.next_sn(), piece, more=i + 1 < len(pieces)))
            rejected += 1
            peer.send(frame(peer.next_sn(), push_put("rvd/test/nav", b"z")))
            assert p.expect("SAMPLE")["payload"] == b"z".hex()
            st = p.stats()
        assert st["rx_sn_dropped"] == 1
        assert st["reassembled_rx"] == 1
        assert st["rx_rejected"] == rejected
        assert st["samples_rx"] == 6


def test_silent_remote_expires_its_lease_while_we_keep_ours_alive():
    with RawPeer() as peer:
        p = Probe(peer.endpoint, "--sub", "rvd/test/nav", "--lease-ms", "400", "--no-reconnect")
        with p:
            peer.accept()
            peer.handshake(lease_ms=600)          # ms, not whole seconds: T flag clear
            assert p.expect("OPEN")["remote_lease_ms"] == "600"
            ev = p.expect("EVENT", timeout=10)
            assert ev["status"] == "LeaseExpired"
            assert "600 ms" in ev["error"]
            st = p.expect("STATS")                # without reconnection the probe stops here
        keepalives = 0
        while not peer.received.empty():
            b = peer.received.get()
            keepalives += b == b"\x04"
        assert keepalives >= 2                    # every 100 ms (lease/4) while nothing else was sent
        assert st["lease_expirations"] == "1"


def refuse(peer, answer):
    peer.accept()
    peer.read_batch()                             # the InitSyn
    if answer is not None:
        peer.send(answer)


@pytest.mark.parametrize("answer,expected", [
    (b"\x03\x02", "Close(reason 2)"),
    (b"\x61\x08\xf1" + bytes(range(1, 17)) + b"\x0a\x00\x08\x01\x00", "protocol version 8"),
    (b"\xff\xee", "malformed InitAck"),
    (None, "no InitAck within 300 ms"),
])
def test_handshake_refusals_are_reported(answer, expected):
    with RawPeer() as peer, Probe(peer.endpoint, "--no-reconnect", "--connect-timeout-ms", "300") as p:
        refuse(peer, answer)
        o = p.expect("OPEN")
        assert o["status"] == "HandshakeFailed"
        assert expected in o["error"]
        assert p.close() == 3


def test_reconnect_schedule_is_bounded():
    port = free_port()                            # nobody listens there
    with Probe(f"tcp/127.0.0.1:{port}", "--reconnect-max", "3") as p:
        assert p.expect("OPEN")["status"] == "ConnectFailed"
        gave_up = p.expect("EVENT", timeout=10, status="ReconnectExhausted")
        assert "connect" in gave_up["error"]      # the third attempt failed like the others
        assert p.expect("STATS")["connects"] == "0"
        p.expect("BYE", timeout=10)
        # open() and the first retry report ConnectFailed; the second retry ends the schedule.
        assert len([line for line in p.history if "status=ConnectFailed" in line]) == 2


# ---- corrupted streams: resynchronised by reconnecting ------------------------------------------

def _resynced_and_back(peer, p, lost):
    """After the client dropped a corrupted stream: it reconnects, and the new session works."""
    assert lost["status"] == "LinkLost" and "stream out of step" in lost["error"], lost
    batches_until_closed(peer)                       # the first connection's traffic, to its end
    peer.accept()
    peer.handshake()
    p.expect("RECONNECTED", timeout=10)
    peer.wait_for_bytes(b"rvd/test/nav")             # the subscriber was declared again
    peer.send(frame(peer.next_sn(), push_put("rvd/test/nav", b"in step again")))
    p.expect("SAMPLE", payload=b"in step again".hex())
    return p.stats()


def test_batches_that_never_parse_make_the_client_resynchronise():
    with RawPeer() as peer:
        p, _ = open_raw(peer)
        with p:
            for junk in (b"\x3f\xff\x00", b"\x1f\x1f\x1f\x1f", b"\xff" * 40):  # no transport message at all
                peer.send(junk)
            st = _resynced_and_back(peer, p, p.expect("EVENT", timeout=10))
        assert st["resyncs"] == 1 and st["link_losses"] == 1 and st["reconnects"] == 1
        assert st["rx_rejected"] == 3


def test_a_corrupted_length_prefix_is_detected_by_the_stall_limit_and_resynchronised():
    """A stray byte shifts the framing: the next length prefix is read one byte off and announces a
    batch that never completes; with the peer silent the stall limit ends it, not the lease."""
    with RawPeer() as peer:
        p, _ = open_raw(peer, "--rx-stall-ms", "300")
        with p:
            peer.conn.sendall(b"\x07")                    # outside any batch
            peer.send(frame(peer.next_sn(), push_put("rvd/test/nav", b"lost in the shift")))
            lost = p.expect("EVENT", timeout=10)
            assert "incomplete for 300 ms" in lost["error"], lost
            st = _resynced_and_back(peer, p, lost)
        assert st["resyncs"] == 1 and st["lease_expirations"] == 0
        assert st["samples_rx"] == 1                       # only the one after the resync


def test_random_byte_stream_after_a_good_handshake_ends_in_a_resync_not_a_hang():
    rng = random.Random(4242)
    with RawPeer() as peer:
        p, _ = open_raw(peer, "--rx-stall-ms", "500")
        with p:
            peer.conn.sendall(bytes(rng.randrange(256) for _ in range(5000)))  # no framing at all
            st = _resynced_and_back(peer, p, p.expect("EVENT", timeout=15))
        assert st["resyncs"] == 1


def test_a_fragmented_message_above_the_cap_is_counted_as_oversized():
    with RawPeer() as peer:
        p, _ = open_raw(peer, "--max-reassembled", "4096")
        with p:
            msg = push_put("rvd/test/nav", bytes(20000))
            pieces = [msg[i:i + 1500] for i in range(0, len(msg), 1500)]
            for i, piece in enumerate(pieces):
                peer.send(fragment(peer.next_sn(), piece, more=i + 1 < len(pieces), first=i == 0))
            peer.send(frame(peer.next_sn(), push_put("rvd/test/nav", b"small")))
            p.expect("SAMPLE", payload=b"small".hex())
            st = p.stats()
        assert st["rx_oversized"] == 1 and st["rx_rejected"] == 0 and st["link_losses"] == 0
