"""The obstacle messages on the Python side: golden byte vectors (schema/golden.toml, assembled
field by field with struct and hmac), authentication, and the host's packing of what the chaser
senses (the nearest 8 when it senses more)."""
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from rvd_pil.host_sim import messages as msg
from rvd_pil.host_sim.obstacles import Obstacle, ObstacleField
from rvd_pil.host_sim.server import obstacles_message

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = tomllib.loads((ROOT / "schema" / "golden.toml").read_text())
KEY = bytes.fromhex(GOLDEN["auth"]["key_hex"])
RUN = GOLDEN["auth"]["run_id"]


def _auth(role, last_sent=0):
    a = msg.LinkAuth(KEY, RUN, role)
    a.last_sent = last_sent
    return a


def test_an_obstacles_message_is_refused_when_flipped_reflected_replayed_or_moved():
    data = bytes.fromhex(GOLDEN["obstacles"]["hex"])
    for position in (20, 300, len(data) - 1):
        bad = bytearray(data)
        bad[position] ^= 0x10
        with pytest.raises(msg.MessageError) as e:
            _auth("flight").open(bytes(bad))
        assert e.value.kind == "bad_tag"
    with pytest.raises(msg.MessageError) as e:
        _auth("host").open(data)  # reflected
    assert e.value.kind == "bad_tag"
    flight = _auth("flight")
    flight.open(data)
    with pytest.raises(msg.MessageError) as e:
        flight.open(data)
    assert e.value.kind == "replayed"
    with pytest.raises(msg.MessageError, match="expected Nav"):
        _auth("flight").open(data, expect=msg.Nav)
    with pytest.raises(msg.MessageError):
        msg.encode(msg.Obstacles(t_s=math.nan))


def test_the_host_packs_the_nearest_eight_of_what_the_chaser_senses_with_their_states():
    n = 0.0011
    # Twelve spheres along +y at 100, 200, ... m; the chaser at the origin.
    obstacles = [Obstacle(id=100 + k, semi_axes_m=(5.0, 6.0, 7.0), position_lvlh_m=(0.0, 100.0 * (12 - k), 0.0),
                          velocity_lvlh_mps=(0.01 * k, 0.0, 0.0), motion="cw") for k in range(12)]
    field = ObstacleField(obstacles, n)
    m = obstacles_message(field, step=3, t_s=50.0, chaser_lvlh_m=np.zeros(3))
    assert (m.step, m.count, m.sensed, m.t_s) == (3, 8, 12, 50.0)
    # Nearest first: ids 111 (100 m), 110, ..., 104.
    assert m.id == tuple(range(111, 103, -1))
    o = obstacles[11]
    np.testing.assert_allclose(m.position_lvlh_m[0:3], o.state(50.0, n)[0:3], rtol=1e-15)
    np.testing.assert_allclose(m.velocity_lvlh_mps[0:3], o.state(50.0, n)[3:6], rtol=1e-15)
    assert m.semi_axes_m[0:3] == (5.0, 6.0, 7.0) and m.q_lvlh_body[0:4] == (1.0, 0.0, 0.0, 0.0)
    assert m.t_seen_s[0] == 50.0
    # It encodes: every slot finite, the message fits the wire.
    assert len(_auth("host").seal(m)) == msg.HEADER_SIZE + msg.Obstacles.BODY.size + msg.TAG_SIZE
