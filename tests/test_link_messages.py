"""The link message schema: golden byte vectors, generated code up to date, bad input rejected."""
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from host_sim import messages as msg

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = tomllib.loads((ROOT / "schema" / "golden.toml").read_text())
CLASSES = {"hello": msg.Hello, "nav": msg.Nav, "cmd": msg.Cmd, "telemetry": msg.Telemetry, "bye": msg.Bye}


def _from_values(cls, values):
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def test_generated_codecs_are_up_to_date():
    r = subprocess.run([sys.executable, str(ROOT / "schema" / "generate.py"), "--check"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("name", list(CLASSES))
def test_golden_encode_and_decode(name):
    cls = CLASSES[name]
    expected = bytes.fromhex(GOLDEN[name]["hex"])
    m = _from_values(cls, GOLDEN[name]["values"])
    assert msg.encode(m) == expected
    assert msg.decode(expected) == m
    assert msg.decode(expected, expect=cls) == m
    assert len(expected) == msg.HEADER_SIZE + cls.BODY.size


def test_every_schema_field_is_in_a_golden_vector():
    for name, cls in CLASSES.items():
        assert set(GOLDEN[name]["values"]) == set(msg.field_names(cls)), name


def test_keys_follow_the_run_id():
    assert msg.key("nav", "abc") == "rvd/abc/nav"
    assert msg.key("cmd", "abc") == "rvd/abc/cmd"


NAV = bytes.fromhex(GOLDEN["nav"]["hex"])


@pytest.mark.parametrize(
    "data, reason",
    [
        (b"", "shorter than its header"),
        (NAV[:5], "shorter than its header"),
        (b"XYZ" + NAV[3:], "bad magic"),
        (NAV[:3] + bytes([2]) + NAV[4:], "version 2"),
        (NAV[:4] + bytes([99]) + NAV[5:], "unknown message type 99"),
        (NAV[:-1], "body size"),
        (NAV + b"\0", "body size"),
        (NAV[:6] + (200).to_bytes(2, "little") + NAV[8:], "body size"),
    ],
)
def test_malformed_bytes_are_rejected_with_a_reason(data, reason):
    with pytest.raises(msg.MessageError, match=reason):
        msg.decode(data)


def test_wrong_type_is_rejected_when_a_type_is_expected():
    with pytest.raises(msg.MessageError, match="expected Cmd, got Nav"):
        msg.decode(NAV, expect=msg.Cmd)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nan_and_inf_never_cross_the_wire(bad):
    m = msg.decode(NAV)
    m.position_lvlh_m = (bad, 0.0, 0.0)
    with pytest.raises(msg.MessageError, match="NaN or Inf"):
        msg.encode(m)
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
