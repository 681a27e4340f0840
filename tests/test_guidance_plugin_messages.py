"""The configuration and guidance-law messages of the plug-in interface: sealed and opened like every other
message (their golden vectors are checked with all the others in test_link_messages.py); a config from the wrong direction or with NaN is refused."""
import math
import tomllib
from pathlib import Path

import pytest

from rvd_pil.host_sim import messages as msg

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = tomllib.loads((ROOT / "schema" / "golden.toml").read_text())
KEY = bytes.fromhex(GOLDEN["auth"]["key_hex"])
RUN = GOLDEN["auth"]["run_id"]


def _auth(role, last_sent=0):
    a = msg.LinkAuth(KEY, RUN, role)
    a.last_sent = last_sent
    return a


def test_config_keys_and_direction():
    assert msg.key("config", "r1") == "rvd/r1/config" and msg.key("config_echo", "r1") == "rvd/r1/config_echo"
    host_config = _auth("host").seal(msg.Config(mass_kg=20.0, thrust_n=1.0, min_impulse_bit_s=0.01))
    # The flight software opens what the host sealed; the host does not take its own message back.
    assert _auth("flight").open(host_config, expect=msg.Config).mass_kg == 20.0
    with pytest.raises(msg.MessageError) as e:
        _auth("host").open(host_config, expect=msg.Config)
    assert e.value.kind == "bad_tag"
    with pytest.raises(ValueError):
        _auth("host").seal(msg.Config(mass_kg=math.nan))
