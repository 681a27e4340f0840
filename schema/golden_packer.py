"""Writes schema/golden.toml: golden byte vectors of the link messages, packed here field by field
from the wire format (struct layouts written out below, hmac/hashlib for the tags), independently of
schema/generate.py and of the codecs it generates (this file imports neither, nor the schema file).

    python schema/golden_packer.py           # rewrite schema/golden.toml
    python schema/golden_packer.py --check   # exit 1 when schema/golden.toml differs from what it packs

Wire format (schema/rvd_messages.toml, flight_sw/link/README.md): little-endian, packed; a 16-byte
header (magic "RVD", version u8, type u8, reserved u8 = 0, body size u16, run nonce u32, sequence
number u32), the body, then the first 16 bytes of HMAC-SHA-256 over header and body under the
sender's direction key. Direction keys and the run nonce are HMACs of the run key over a label with
the run id appended. A change of a message layout must be made here by hand as well: that is the
point of a second, independent statement of the format.
"""
from __future__ import annotations

import hashlib
import hmac
import struct
import sys
from pathlib import Path

OUT = Path(__file__).resolve().parent / "golden.toml"
VERSION = 2
KEY = bytes(range(32))
RUN_ID = "golden-run-7"
LABEL = {"host": b"rvd-pil v2 host->flight ", "flight": b"rvd-pil v2 flight->host "}
LABEL_NONCE = b"rvd-pil v2 run nonce "

# (message, type id, sender, sequence number, [(field, struct code, value)]). Codes are struct's:
# s = fixed-size zero-padded string, B/H/I/Q = u8/u16/u32/u64, d = f64; a count prefix is an array.
MESSAGES = [
    ("hello", 1, "flight", 1, [
        ("arch", "16s", "aarch64"), ("cpu_model", "32s", "cortex-a53"), ("compiler", "48s", "gcc 12.2.0"),
        ("build", "48s", "Release -O2 -static"), ("solver_mode", "B", 1), ("step_clock", "B", 1),
        ("solver_max_iter", "H", 100), ("solver_tol", "d", 1e-8), ("horizon", "3H", [30, 15, 12]),
        ("reserved2", "H", 0), ("period_s", "3d", [30.0, 20.0, 5.0]), ("max_pulse_s", "3d", [1.5, 1.0, 0.25]),
        ("deadline_fraction", "d", 0.5), ("pid", "I", 4242), ("session", "I", 1)]),
    ("nav", 2, "host", 7, [
        ("step", "I", 7), ("flags", "I", 1), ("t_s", "d", 210.0),
        ("position_lvlh_m", "3d", [140.0, -1580.0, 60.0]), ("velocity_lvlh_mps", "3d", [-0.9, -0.32, 0.0]),
        ("q_lvlh_body", "4d", [0.7071067811865476, 0.0, 0.0, -0.7071067811865476]),
        ("omega_body_rad_s", "3d", [0.0, 0.0, 0.004363323129985824])]),
    ("cmd", 3, "flight", 8, [
        ("step", "I", 7), ("phase", "B", 2), ("guidance_status", "B", 1), ("solver_status", "B", 1),
        ("overrun", "B", 1), ("period_s", "d", 20.0), ("dv_cmd_lvlh_mps", "3d", [0.01, -0.02, 0.0]),
        ("dv_alloc_lvlh_mps", "3d", [0.0099, -0.0201, 0.0]),
        ("pulse_s", "6d", [0.2772, 0.0, 0.0, 0.5628, 0.0, 0.0]), ("solve_time_us", "d", 123.5),
        ("step_time_us", "d", 150.25), ("instructions", "Q", 987654321), ("iterations", "H", 17),
        ("reserved", "H", 0), ("overruns", "I", 3), ("primal_residual", "d", 1e-9),
        ("dual_residual", "d", 2e-10), ("objective", "d", -42.5)]),
    ("telemetry", 4, "flight", 9, [
        ("steps", "3I", [60, 15, 63]), ("overruns", "3I", [0, 1, 0]), ("mean_solve_us", "3d", [45.5, 30.25, 12.0]),
        ("max_solve_us", "3d", [90.0, 60.5, 20.75]), ("max_step", "3I", [12, 70, 100]), ("step_clock", "I", 1),
        ("total_instructions", "3Q", [1000000, 2000000, 3000000]), ("peak_heap_bytes", "Q", 524288),
        ("max_rss_kb", "Q", 4096), ("nav_rejected", "I", 2), ("nav_duplicates", "I", 5), ("nav_stale", "I", 1),
        ("nav_future", "I", 2), ("nav_coalesced", "I", 3), ("rx_oversized", "I", 4), ("rx_untagged", "I", 5),
        ("rx_wrong_run", "I", 6), ("rx_bad_tag", "I", 7), ("rx_replayed", "I", 8), ("link_losses", "I", 9),
        ("link_resyncs", "I", 10), ("link_rx_rejected", "I", 11), ("link_rx_unmatched", "I", 12)]),
    ("bye", 5, "flight", 10, [
        ("reason", "B", 1), ("reserved", "3B", [0, 0, 0]), ("last_step", "I", 137),
        ("text", "64s", "docked: 0.08 m from port")]),
    ("obstacles", 16, "host", 11, [
        ("step", "I", 7), ("count", "H", 2), ("sensed", "H", 3), ("t_s", "d", 210.0),
        ("id", "8I", [5, 9] + [0] * 6), ("t_seen_s", "8d", [120.0, 195.5] + [0.0] * 6),
        ("position_lvlh_m", "24d", [-30.0, -800.0, 10.0, -100.0, 0.0, -40.0] + [0.0] * 18),
        ("velocity_lvlh_mps", "24d", [-0.075, -0.005, 0.015, 0.07, -0.16, 0.01] + [0.0] * 18),
        ("semi_axes_m", "24d", [20.0, 20.0, 20.0, 50.0, 30.0, 10.0] + [0.0] * 18),
        ("q_lvlh_body", "32d", [1.0, 0.0, 0.0, 0.0, 0.7071067811865476, 0.0, 0.0, 0.7071067811865476] + [0.0] * 24)]),
    ("obstacle_status", 17, "flight", 12, [
        ("step", "I", 7), ("received", "H", 3), ("held", "H", 2), ("capacity", "H", 4), ("reserved", "H", 0),
        ("dropped_total", "I", 1), ("rejected_total", "I", 2), ("held_id", "8I", [9, 5] + [0] * 6)]),
    ("chaser_attitude", 18, "host", 13, [
        ("step", "I", 7), ("reserved", "I", 0), ("t_s", "d", 14.0),
        ("q_lvlh_chaser", "4d", [0.0, 0.0, 0.0, 1.0]), ("omega_chaser_rad_s", "3d", [0.0, 0.0, -0.0125])]),
    ("torque", 19, "flight", 14, [
        ("step", "I", 7), ("reserved", "I", 0), ("torque_body_nm", "3d", [0.0, 0.0, -0.0043]),
        ("torque_max_nm", "d", 0.0225)]),
    ("config", 10, "flight", 2, [
        ("mass_kg", "d", 20.0), ("thrust_n", "d", 1.0), ("min_impulse_bit_s", "d", 0.01),
        ("horizon", "3H", [30, 15, 12]), ("status", "B", 0), ("pinned", "B", 2),
        ("period_s", "3d", [30.0, 20.0, 5.0]), ("u_max_mps", "3d", [0.1786, 0.1786, 0.0357]),
        ("law", "32s", "fast_mpc_3phase"), ("settings", "512s", "rendezvous.N=30;recovery=off"), ("text", "64s", "")]),
    ("law", 11, "flight", 43, [
        ("step", "I", 42), ("fault", "B", 2), ("n_values", "B", 2), ("reserved", "H", 0), ("faults", "I", 3),
        ("names", "384s", "dv_norm_mps,tgo_s"), ("values", "16d", [0.125, 600.5] + [0.0] * 14)]),
]


def _mac(key: bytes, data: bytes) -> bytes:
    return hmac.new(key, data, hashlib.sha256).digest()


def run_nonce() -> int:
    return struct.unpack("<I", _mac(KEY, LABEL_NONCE + RUN_ID.encode())[:4])[0]


def body(fields) -> bytes:
    out = b""
    for _, code, value in fields:
        if code.endswith("s"):
            out += struct.pack("<" + code, value.encode("utf-8"))  # struct zero-pads to the size
        elif code[0].isdigit():
            out += struct.pack("<" + code, *value)
        else:
            out += struct.pack("<" + code, value)
    return out


def seal(type_id: int, sender: str, seq: int, fields) -> bytes:
    b = body(fields)
    header = b"RVD" + struct.pack("<BBBHII", VERSION, type_id, 0, len(b), run_nonce(), seq)
    key = _mac(KEY, LABEL[sender] + RUN_ID.encode())
    return header + b + _mac(key, header + b)[:16]


def _toml(v) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, str):
        return '"' + v + '"'
    return repr(v)


def render() -> str:
    lines = ["# Golden byte vectors of the rvd-pil link messages, checked by the Python and the C++ tests",
             "# (tests/cpp/test_link_messages.cpp reads the hex lines). Written by schema/golden_packer.py,",
             "# which packs each field from the wire format without the generated codecs; a test re-runs it.",
             "# Every message is sealed as its sender would seal it: under the key and run id below, with",
             "# the sequence number given (`sender` names whose direction key made the tag).",
             "", "[auth]", f'key_hex = "{KEY.hex()}"', f'run_id = "{RUN_ID}"', f"run_nonce = {run_nonce()}"]
    for name, type_id, sender, seq, fields in MESSAGES:
        lines += ["", f"[{name}]", f'hex = "{seal(type_id, sender, seq, fields).hex()}"', f'sender = "{sender}"',
                  f"seq = {seq}", f"[{name}.values]"]
        lines += [f"{field} = {_toml(value)}" for field, _, value in fields]
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    text = render()
    if "--check" in argv:
        if OUT.read_text() != text:
            print(f"{OUT}: differs from what schema/golden_packer.py packs (run it to rewrite)", file=sys.stderr)
            return 1
        return 0
    OUT.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
