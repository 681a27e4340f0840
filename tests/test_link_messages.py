"""The link message schema: golden byte vectors (sealed under the golden key), generated code up to
date, message authentication, bad input rejected."""
import ast
import re
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from rvd_pil.host_sim import messages as msg

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = tomllib.loads((ROOT / "schema" / "golden.toml").read_text())
# Every message of the schema, by its schema name (ObstacleStatus -> obstacle_status).
CLASSES = {re.sub(r"(?<!^)(?=[A-Z])", "_", cls.__name__).lower(): cls for cls in msg.MESSAGE_TYPES.values()}
KEY = bytes.fromhex(GOLDEN["auth"]["key_hex"])
RUN = GOLDEN["auth"]["run_id"]
OTHER = {"host": "flight", "flight": "host"}


def _from_values(cls, values):
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def _auth(role, last_sent=0):
    a = msg.LinkAuth(KEY, RUN, role)
    a.last_sent = last_sent
    return a


def test_generated_codecs_are_up_to_date():
    r = subprocess.run([sys.executable, str(ROOT / "schema" / "generate.py"), "--check"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_golden_vectors_are_what_the_independent_packer_packs():
    """schema/golden_packer.py packs every field from the wire format with struct and hmac, without the
    generated codecs: the committed vectors must be exactly its output."""
    r = subprocess.run([sys.executable, str(ROOT / "schema" / "golden_packer.py"), "--check"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    tree = ast.parse((ROOT / "schema" / "golden_packer.py").read_text())
    imports = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names} | \
              {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert imports <= {"__future__", "hashlib", "hmac", "struct", "sys", "pathlib"}, imports


@pytest.mark.parametrize("name", list(CLASSES))
def test_golden_seal_and_open(name):
    cls, g = CLASSES[name], GOLDEN[name]
    expected = bytes.fromhex(g["hex"])
    m = _from_values(cls, g["values"])
    assert _auth(g["sender"], last_sent=g["seq"] - 1).seal(m) == expected
    receiver = _auth(OTHER[g["sender"]])
    assert receiver.run_nonce == GOLDEN["auth"]["run_nonce"]
    assert receiver.open(expected, expect=cls) == m
    assert receiver.last_received == g["seq"]
    # The layout without the tag: encode() leaves nonce, sequence number and tag zero.
    raw = msg.encode(m)
    assert raw[:8] == expected[:8] and raw[8:16] == bytes(8) and raw[-msg.TAG_SIZE:] == bytes(msg.TAG_SIZE)
    assert raw[16:-msg.TAG_SIZE] == expected[16:-msg.TAG_SIZE]
    assert msg.decode(expected) == m
    assert len(expected) == msg.HEADER_SIZE + cls.BODY.size + msg.TAG_SIZE <= msg.MAX_MESSAGE_SIZE


def test_every_schema_message_has_a_golden_vector():
    assert set(GOLDEN) - {"auth"} == set(CLASSES)


def test_every_schema_field_is_in_a_golden_vector():
    for name, cls in CLASSES.items():
        assert set(GOLDEN[name]["values"]) == set(msg.field_names(cls)), name


def test_keys_follow_the_run_id_and_run_ids_are_checked():
    assert msg.key("nav", "abc") == "rvd/abc/nav"
    assert msg.key("cmd", "a-b_C9") == "rvd/a-b_C9/cmd"
    for bad in ["", "*", "**", "a/b", "$*", "r 1", "x" * (msg.RUN_ID_MAX + 1), "rvd/*/bye"]:
        with pytest.raises(ValueError, match="run id"):
            msg.key("nav", bad)
        with pytest.raises(ValueError, match="run id"):
            msg.LinkAuth(KEY, bad, "host")


NAV = bytes.fromhex(GOLDEN["nav"]["hex"])  # sealed by the host, sequence number 7


def _open(data, role="flight", expect=None):
    return _auth(role).open(data, expect=expect)


def test_replays_are_refused_and_refusals_use_up_no_sequence_number():
    flight = _auth("flight")
    flight.open(NAV)
    with pytest.raises(msg.MessageError, match="sequence number 7 not above 7") as e:
        flight.open(NAV)
    assert e.value.kind == "replayed"
    flight = _auth("flight")
    with pytest.raises(msg.MessageError, match="expected Cmd") as e:
        flight.open(NAV, expect=msg.Cmd)     # a genuine message moved to another key
    assert e.value.kind == "malformed" and flight.last_received == 0
    assert flight.open(NAV, expect=msg.Nav).step == 7


@pytest.mark.parametrize("position", range(len(NAV)))
def test_any_flipped_bit_is_refused_by_kind(position):
    for bit in range(8):
        bad = bytearray(NAV)
        bad[position] ^= 1 << bit
        with pytest.raises(msg.MessageError) as e:
            _open(bytes(bad))
        if 8 <= position < 12:
            assert e.value.kind == "wrong_run"
        elif position >= 12:
            assert e.value.kind == "bad_tag"      # sequence number, body and tag are all under the tag


def test_reflected_other_run_other_key_untagged_and_oversized_messages_are_refused():
    cases = [
        (lambda: _open(NAV, role="host"), "bad_tag"),                            # the host's own nav, reflected
        (lambda: msg.LinkAuth(KEY, "golden-run-8", "flight").open(NAV), "wrong_run"),
        (lambda: msg.LinkAuth(bytes(32), RUN, "flight").open(NAV), None),        # other key: nonce or tag
        (lambda: _open(b"RVD\x01\x02\x00\x78\x00" + NAV[16:-16]), "untagged"),  # the tagless protocol
        (lambda: _open(msg.encode(msg.decode(NAV))), "wrong_run"),              # unsealed: zero nonce
        (lambda: _open(NAV + bytes(16 << 20)), "oversized"),                     # 16 MiB
    ]
    for call, kind in cases:
        with pytest.raises(msg.MessageError) as e:
            call()
        if kind is None:
            assert e.value.kind in ("wrong_run", "bad_tag")
        else:
            assert e.value.kind == kind, (kind, str(e.value))


def test_keys_must_have_the_schema_size():
    with pytest.raises(ValueError, match="32 bytes"):
        msg.LinkAuth(bytes(16), RUN, "host")
    with pytest.raises(ValueError, match="role"):
        msg.LinkAuth(KEY, RUN, "attacker")


@pytest.mark.parametrize(
    "data, reason",
    [
        (b"", "shorter than its header"),
        (NAV[:5], "shorter than its header"),
        (b"XYZ" + NAV[3:], "bad magic"),
        (NAV[:3] + bytes([3]) + NAV[4:], "version 3"),
        (NAV[:4] + bytes([99]) + NAV[5:], "unknown message type 99"),
        (NAV[:-1], "body size"),
        (NAV + b"\0", "body size"),
        (NAV[:6] + (200).to_bytes(2, "little") + NAV[8:], "body size"),
    ],
)
def test_malformed_bytes_are_rejected_with_a_reason(data, reason):
    with pytest.raises(msg.MessageError, match=reason):
        msg.decode(data)
    with pytest.raises(msg.MessageError, match=reason) as e:
        _open(data)
    assert e.value.kind == "malformed"


def test_wrong_type_is_rejected_when_a_type_is_expected():
    with pytest.raises(msg.MessageError, match="expected Cmd, got Nav"):
        msg.decode(NAV, expect=msg.Cmd)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nan_and_inf_never_cross_the_wire(bad):
    m = msg.decode(NAV)
    m.position_lvlh_m = (bad, 0.0, 0.0)
    with pytest.raises(msg.MessageError, match="NaN or Inf"):
        msg.encode(m)
    with pytest.raises(msg.MessageError, match="NaN or Inf"):
        _auth("host").seal(m)
    # A NaN smuggled into the bytes is rejected on decode.
    raw = bytearray(NAV)
    offset = msg.HEADER_SIZE + 4 + 4 + 8  # step, flags, t_s, then position x
    raw[offset : offset + 8] = msg.struct.pack("<d", bad)
    with pytest.raises(msg.MessageError, match="position_lvlh_m: NaN or Inf"):
        msg.decode(bytes(raw))


def test_out_of_range_values_are_refused():
    with pytest.raises(msg.MessageError):
        msg.encode(msg.Nav(step=-1))
    with pytest.raises(msg.MessageError, match="longer than 16 bytes"):
        msg.encode(msg.Hello(arch="x" * 17))
    with pytest.raises(msg.MessageError, match="needs 3 values"):
        msg.encode(msg.Nav(position_lvlh_m=(1.0, 2.0)))
