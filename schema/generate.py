#!/usr/bin/env python3
"""Generate the C++ and Python codecs of the rvd-pil link messages from schema/rvd_messages.toml.

    python schema/generate.py          write flight_sw/link/messages.hpp and rvd_pil/host_sim/messages.py
    python schema/generate.py --check  exit 1 if either file is not what the schema generates

The schema is the single definition; both outputs are committed so that a cross build needs no
Python, and tests/test_link_messages.py fails when they are stale.
"""
from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCHEMA = ROOT / "schema" / "rvd_messages.toml"
CPP_OUT = ROOT / "flight_sw" / "link" / "messages.hpp"
PY_OUT = ROOT / "rvd_pil" / "host_sim" / "messages.py"

# type -> (size in bytes, C++ type, struct code)
SCALARS = {
    "u8": (1, "uint8_t", "B"),
    "u16": (2, "uint16_t", "H"),
    "u32": (4, "uint32_t", "I"),
    "u64": (8, "uint64_t", "Q"),
    "f64": (8, "double", "d"),
}
HEADER_SIZE = 16  # magic (3), version, type, reserved, body size (u16), run nonce (u32), sequence number (u32)
UNTAGGED_VERSION = 1  # the protocol before message tags: recognised only to count it as untagged


def load_schema(path: Path = SCHEMA) -> dict:
    schema = tomllib.loads(path.read_text())
    auth = schema["auth"]
    if auth["algorithm"] != "HMAC-SHA-256" or not 8 <= auth["tag_size"] <= 32 or auth["key_size"] < 16:
        raise SystemExit("auth: HMAC-SHA-256 with a tag of 8 to 32 bytes and a key of at least 16 bytes")
    if schema["version"] <= UNTAGGED_VERSION:
        raise SystemExit(f"version must be above {UNTAGGED_VERSION}, the untagged protocol")
    ids = set()
    for msg in schema["message"]:
        if msg["id"] in ids:
            raise SystemExit(f"duplicate message id {msg['id']}")
        ids.add(msg["id"])
        names = set()
        for f in msg["fields"]:
            if f["name"] in names:
                raise SystemExit(f"{msg['name']}: duplicate field {f['name']}")
            names.add(f["name"])
            if f["type"] != "str" and f["type"] not in SCALARS:
                raise SystemExit(f"{msg['name']}.{f['name']}: unknown type {f['type']}")
    return schema


def field_size(f: dict) -> int:
    if f["type"] == "str":
        return int(f["size"])
    return SCALARS[f["type"]][0] * int(f.get("count", 1))


def body_size(msg: dict) -> int:
    return sum(field_size(f) for f in msg["fields"])


def camel(name: str) -> str:
    return "".join(p.capitalize() for p in name.split("_"))


def max_message_size(schema: dict) -> int:
    return HEADER_SIZE + max(body_size(m) for m in schema["message"]) + schema["auth"]["tag_size"]


def cpp_string(text: str) -> str:
    assert all(32 <= ord(c) < 127 and c not in '"\\' for c in text), text
    return f'"{text}"'


CPP_AUTH = r"""// Body size of a message type (0 for an unknown one).
inline std::size_t body_size(Type type) {
  switch (type) {
@BODY_CASES@
  }
  return 0;
}

// A run id is 1 to kRunIdMax characters from kRunIdChars: never a wildcard, never a '/'.
inline bool check_run_id(std::string_view run) {
  if (run.empty() || run.size() > kRunIdMax) return false;
  for (char c : run) {
    if (c == '\0' || std::strchr(kRunIdChars, c) == nullptr) return false;
  }
  return true;
}

enum class Role : uint8_t { Host, Flight };

// Message authentication for one end of the link: derives the two direction keys and the run
// nonce from the run's key and id (schema/rvd_messages.toml, [auth]), seals what this end sends
// (run nonce, next sequence number, tag) and opens what it receives. No heap: seal() and open()
// cost one HMAC-SHA-256 over the message each, on prepared key states.
class LinkAuth {
 public:
  LinkAuth() = default;  // no key: seal() and open() answer Error::NoKey
  LinkAuth(const uint8_t* key, std::size_t key_size, std::string_view run_id, Role role) {
    if (key == nullptr || key_size != kKeySize || !check_run_id(run_id)) return;
    const link::HmacSha256 master(key, key_size);
    uint8_t k[link::HmacSha256::kTagSize];
    derive(master, kLabelHostToFlight, run_id, k);
    (role == Role::Host ? tx_ : rx_).set_key(k, sizeof k);
    derive(master, kLabelFlightToHost, run_id, k);
    (role == Role::Host ? rx_ : tx_).set_key(k, sizeof k);
    derive(master, kLabelRunNonce, run_id, k);
    const uint8_t* p = k;
    nonce_ = wire::get<uint32_t>(p);
    std::memset(k, 0, sizeof k);
    keyed_ = true;
  }

  // Fills in the run nonce, the next sequence number and the tag of an encoded message of n bytes.
  Error seal(uint8_t* m, std::size_t n) {
    if (!keyed_ || tx_seq_ == UINT32_MAX) return Error::NoKey;
    if (m == nullptr || n < kHeaderSize + kTagSize) return Error::TooShort;
    ++tx_seq_;
    uint8_t* p = m + 8;
    wire::put<uint32_t>(p, nonce_);
    wire::put<uint32_t>(p, tx_seq_);
    uint8_t tag[link::HmacSha256::kTagSize];
    tx_.mac(m, n - kTagSize, tag);
    std::memcpy(m + n - kTagSize, tag, kTagSize);
    return Error::None;
  }

  // Checks a received message of type `expect`: size, layout, run nonce, tag, then freshness. On
  // None its sequence number is used up (a copy of it is Replayed from then on). Decode it next.
  Error open(const uint8_t* m, std::size_t n, Type expect) {
    if (n > kMaxMessageSize) return Error::Oversized;
    if (m == nullptr || n < 4) return Error::TooShort;
    if (n >= 8 && m[3] == kUntaggedVersion && has_magic(m)) return Error::Untagged;
    Type type;
    const Error e = peek(m, n, type);
    if (e != Error::None) return e;
    if (type != expect) return Error::WrongType;
    const uint8_t* h = m + 6;
    const std::size_t body = body_size(type);
    if (wire::get<uint16_t>(h) != body || n != kHeaderSize + body + kTagSize) return Error::BadSize;
    if (!keyed_) return Error::NoKey;
    const uint32_t nonce = wire::get<uint32_t>(h);
    const uint32_t seq = wire::get<uint32_t>(h);
    if (nonce != nonce_) return Error::WrongRun;
    uint8_t tag[link::HmacSha256::kTagSize];
    rx_.mac(m, n - kTagSize, tag);
    if (!link::equal_constant_time(tag, m + n - kTagSize, kTagSize)) return Error::BadTag;
    if (seq <= rx_seq_) return Error::Replayed;
    rx_seq_ = seq;
    return Error::None;
  }

  bool keyed() const { return keyed_; }
  uint32_t run_nonce() const { return nonce_; }
  uint32_t last_sent() const { return tx_seq_; }
  uint32_t last_received() const { return rx_seq_; }

 private:
  static bool has_magic(const uint8_t* m) { return @MAGIC_TEST@; }
  static void derive(const link::HmacSha256& master, const char* label, std::string_view run,
                     uint8_t out[link::HmacSha256::kTagSize]) {
    master.mac(reinterpret_cast<const uint8_t*>(label), std::strlen(label),
               reinterpret_cast<const uint8_t*>(run.data()), run.size(), out);
  }

  link::HmacSha256 tx_, rx_;
  uint32_t nonce_ = 0, tx_seq_ = 0, rx_seq_ = 0;
  bool keyed_ = false;
};

// A received message: LinkAuth::open() (nonce, tag, freshness), then decode() (layout, finite values).
template <class M> inline Error receive(LinkAuth& auth, const uint8_t* data, std::size_t n, M& m) {
  const Error e = auth.open(data, n, M::kType);
  return e == Error::None ? decode(data, n, m) : e;
}

// encode() then LinkAuth::seal(): the bytes to send. Returns M::kSize, or 0 and `err`.
template <class M> inline std::size_t seal(LinkAuth& auth, const M& m, uint8_t* out, std::size_t cap, Error* err = nullptr) {
  Error e = Error::None;
  std::size_t n = encode(m, out, cap, &e);
  if (n != 0) e = auth.seal(out, n);
  if (err) *err = e;
  return e == Error::None ? n : 0;
}
"""

PY_AUTH = r'''class LinkAuth:
    """Message authentication for one end of the link ("host" or "flight").

    Derives the two direction keys and the run nonce from the run's key and id (schema
    [auth]); seal() numbers and tags what this end sends, open() checks what it receives (size,
    layout, run nonce, tag, freshness, in that order) and decodes it. MessageError.kind says why a
    message was refused. Thread-safe (the host receives on Zenoh's thread and sends on its own).
    """

    def __init__(self, key: bytes, run_id: str, role: str):
        if role not in ("host", "flight"):
            raise ValueError(f"role must be 'host' or 'flight', not {role!r}")
        key = bytes(key)
        if len(key) != KEY_SIZE:
            raise ValueError(f"the link key has {KEY_SIZE} bytes, not {len(key)}")
        run = check_run_id(run_id).encode()

        def derive(label: bytes) -> bytes:
            return hmac.new(key, label + run, hashlib.sha256).digest()

        host_to_flight = hmac.new(derive(LABEL_HOST_TO_FLIGHT), digestmod=hashlib.sha256)
        flight_to_host = hmac.new(derive(LABEL_FLIGHT_TO_HOST), digestmod=hashlib.sha256)
        self._tx, self._rx = (host_to_flight, flight_to_host) if role == "host" else (flight_to_host, host_to_flight)
        self.run_nonce = int.from_bytes(derive(LABEL_RUN_NONCE)[:4], "little")
        self.last_sent = 0
        self.last_received = 0
        self._lock = threading.Lock()

    def _tag(self, mac, data) -> bytes:
        m = mac.copy()
        m.update(data[:-TAG_SIZE])
        return m.digest()[:TAG_SIZE]

    def seal(self, message) -> bytes:
        """encode() with this run's nonce, the next sequence number and the tag."""
        data = bytearray(encode(message))
        with self._lock:
            if self.last_sent >= 0xFFFFFFFF:
                raise MessageError("sequence numbers of this run are spent")
            self.last_sent += 1
            struct.pack_into("<II", data, 8, self.run_nonce, self.last_sent)
            data[-TAG_SIZE:] = self._tag(self._tx, data)
        return bytes(data)

    def open(self, data: bytes, expect=None):
        """The message in `data` if it is this run's, intact and fresh; else MessageError (kind)."""
        data = bytes(data)
        if len(data) > MAX_MESSAGE_SIZE:
            raise MessageError(f"{len(data)} bytes: larger than any rvd message ({MAX_MESSAGE_SIZE})", "oversized")
        if len(data) >= 8 and data[:3] == MAGIC and data[3] == UNTAGGED_VERSION:
            raise MessageError("untagged message (protocol version 1)", "untagged")
        _layout(data, expect)
        nonce, seq = struct.unpack_from("<II", data, 8)
        if nonce != self.run_nonce:
            raise MessageError(f"run nonce {nonce:#010x} is not this run's", "wrong_run")
        if not hmac.compare_digest(self._tag(self._rx, data), data[-TAG_SIZE:]):
            raise MessageError("tag does not check", "bad_tag")
        with self._lock:
            if seq <= self.last_received:
                raise MessageError(f"sequence number {seq} not above {self.last_received}", "replayed")
            self.last_received = seq
        try:
            return decode(data, expect)
        except MessageError as exc:  # authentic, but not a valid message: the sender's fault
            raise MessageError(f"{exc} (authentic message)", "invalid") from None
'''


# ----------------------------------------------------------------------------------------- C++
def gen_cpp(schema: dict) -> str:
    out: list[str] = []
    w = out.append
    auth = schema["auth"]
    keys = schema["keys"]
    w("// GENERATED by schema/generate.py from schema/rvd_messages.toml -- do not edit by hand.")
    w("// The rvd-pil link messages: little-endian, packed, fixed size; a 16-byte header (magic \"RVD\",")
    w("// version, type, reserved, body size, run nonce, sequence number), the body, a 16-byte tag")
    w("// (HMAC-SHA-256 under the sender's direction key, see LinkAuth). Every f64 must be finite.")
    w("#pragma once")
    w("")
    w("#include <array>")
    w("#include <cmath>")
    w("#include <cstddef>")
    w("#include <cstdint>")
    w("#include <cstring>")
    w("#include <string>")
    w("#include <string_view>")
    w("#include <type_traits>")
    w("")
    w('#include "flight_sw/link/sha256.hpp"')
    w("")
    w("namespace rvd::msg {")
    w("")
    w(f"constexpr uint8_t kVersion = {schema['version']};")
    w(f"constexpr uint8_t kUntaggedVersion = {UNTAGGED_VERSION};  // the protocol before tags: counted as untagged")
    w(f"constexpr std::size_t kHeaderSize = {HEADER_SIZE};")
    w(f"constexpr std::size_t kTagSize = {auth['tag_size']};")
    w(f"constexpr std::size_t kKeySize = {auth['key_size']};")
    w(f"constexpr std::size_t kMaxMessageSize = {max_message_size(schema)};  // the largest message, tag included")
    w(f"constexpr const char* kKeyEnv = {cpp_string(auth['key_env'])};  // the key as {2 * auth['key_size']} hex digits")
    w(f"constexpr const char* kLabelHostToFlight = {cpp_string(auth['label_host_to_flight'])};")
    w(f"constexpr const char* kLabelFlightToHost = {cpp_string(auth['label_flight_to_host'])};")
    w(f"constexpr const char* kLabelRunNonce = {cpp_string(auth['label_run_nonce'])};")
    w(f"constexpr std::size_t kRunIdMax = {keys['run_id_max']};")
    w(f"constexpr const char* kRunIdChars = {cpp_string(keys['run_id_chars'])};")
    w("")
    w("enum class Type : uint8_t {")
    for m in schema["message"]:
        w(f"  {camel(m['name'])} = {m['id']},")
    w("};")
    w("")
    w("enum class Error : uint8_t {")
    w("  None = 0,")
    w("  TooShort,        // fewer bytes than a header")
    w("  BadMagic,        // not an rvd message")
    w("  BadVersion,      // another protocol version")
    w("  UnknownType,     // type id not in the schema")
    w("  WrongType,       // a valid message of another type than asked for")
    w("  BadSize,         // body size differs from the schema's")
    w("  NonFinite,       // NaN or Inf in an f64 field")
    w("  BufferTooSmall,  // encode: output buffer too small")
    w("  Oversized,       // more bytes than the largest message")
    w("  Untagged,        // a message of the untagged protocol (version 1)")
    w("  WrongRun,        // another run's nonce")
    w("  BadTag,          // the tag does not check under the sender's key")
    w("  Replayed,        // a sequence number not above the last one accepted")
    w("  NoKey,           // LinkAuth used without a key, or its sequence numbers are spent")
    w("};")
    w("")
    w("inline const char* to_string(Error e) {")
    w("  switch (e) {")
    for name, text in [
        ("None", "ok"),
        ("TooShort", "message shorter than its header"),
        ("BadMagic", "bad magic (not an rvd message)"),
        ("BadVersion", "unsupported protocol version"),
        ("UnknownType", "unknown message type"),
        ("WrongType", "unexpected message type"),
        ("BadSize", "body size does not match the schema"),
        ("NonFinite", "NaN or Inf in a floating-point field"),
        ("BufferTooSmall", "output buffer too small"),
        ("Oversized", "larger than any rvd message"),
        ("Untagged", "untagged message (protocol version 1)"),
        ("WrongRun", "another run's message (run nonce)"),
        ("BadTag", "tag does not check"),
        ("Replayed", "replayed message (old sequence number)"),
        ("NoKey", "no link key (or sequence numbers spent)"),
    ]:
        w(f'    case Error::{name}: return "{text}";')
    w("  }")
    w('  return "unknown error";')
    w("}")
    w("")
    w("namespace wire {")
    w("// Explicit little-endian byte order, independent of the host's.")
    w("template <class T> inline void put(uint8_t*& p, T v) {")
    w("  static_assert(std::is_integral<T>::value, \"integers only\");")
    w("  for (std::size_t i = 0; i < sizeof(T); ++i) *p++ = static_cast<uint8_t>(static_cast<uint64_t>(v) >> (8 * i));")
    w("}")
    w("inline void put(uint8_t*& p, double v) {")
    w("  uint64_t bits;")
    w("  std::memcpy(&bits, &v, 8);")
    w("  put<uint64_t>(p, bits);")
    w("}")
    w("template <class T> inline T get(const uint8_t*& p) {")
    w("  uint64_t v = 0;")
    w("  for (std::size_t i = 0; i < sizeof(T); ++i) v |= static_cast<uint64_t>(*p++) << (8 * i);")
    w("  return static_cast<T>(v);")
    w("}")
    w("template <> inline double get<double>(const uint8_t*& p) {")
    w("  uint64_t bits = get<uint64_t>(p);")
    w("  double v;")
    w("  std::memcpy(&v, &bits, 8);")
    w("  return v;")
    w("}")
    w("// The run nonce and sequence number stay 0 until LinkAuth::seal() fills them in.")
    w("inline void put_header(uint8_t*& p, Type type, uint16_t body) {")
    magic = schema["magic"].encode()
    for b in magic:
        w(f"  *p++ = {b};  // '{chr(b)}'")
    w("  *p++ = kVersion;")
    w("  *p++ = static_cast<uint8_t>(type);")
    w("  *p++ = 0;")
    w("  put<uint16_t>(p, body);")
    w("  put<uint32_t>(p, 0);")
    w("  put<uint32_t>(p, 0);")
    w("}")
    w("}  // namespace wire")
    w("")
    w("// Checks the header of any message; on success sets `type`.")
    w("inline Error peek(const uint8_t* data, std::size_t n, Type& type) {")
    w("  if (data == nullptr || n < kHeaderSize) return Error::TooShort;")
    w("  if (" + " || ".join(f"data[{i}] != {b}" for i, b in enumerate(magic)) + ") return Error::BadMagic;")
    w("  if (data[3] != kVersion) return Error::BadVersion;")
    w("  switch (data[4]) {")
    for m in schema["message"]:
        w(f"    case {m['id']}:")
    w("      break;")
    w("    default:")
    w("      return Error::UnknownType;")
    w("  }")
    w("  type = static_cast<Type>(data[4]);")
    w("  return Error::None;")
    w("}")
    w("")
    for m in schema["message"]:
        cname = camel(m["name"])
        bsize = body_size(m)
        w(f"// {m['doc']}")
        w(f"struct {cname} {{")
        w(f"  static constexpr Type kType = Type::{cname};")
        w(f"  static constexpr std::size_t kBodySize = {bsize};")
        w(f"  static constexpr std::size_t kSize = kHeaderSize + kBodySize + kTagSize;")
        for f in m["fields"]:
            if f["type"] == "str":
                decl = f"std::array<char, {f['size']}> {f['name']}{{}};"
            else:
                ctype = SCALARS[f["type"]][1]
                cnt = int(f.get("count", 1))
                decl = f"std::array<{ctype}, {cnt}> {f['name']}{{}};" if cnt > 1 else f"{ctype} {f['name']} = 0;"
            w(f"  {decl}  // {f['doc']}")
        w("};")
        w("")
        # encode
        w(f"// Writes {cname}::kSize bytes (nonce, sequence number and tag zero: LinkAuth::seal() fills them);")
        w("// returns the size, or 0 and `err` when it cannot.")
        w(f"inline std::size_t encode(const {cname}& m, uint8_t* out, std::size_t cap, Error* err = nullptr) {{")
        w("  Error e = Error::None;")
        w(f"  if (out == nullptr || cap < {cname}::kSize) e = Error::BufferTooSmall;")
        for f in m["fields"]:
            if f["type"] == "f64":
                if int(f.get("count", 1)) > 1:
                    w(f"  for (double v : m.{f['name']}) if (!std::isfinite(v)) e = Error::NonFinite;")
                else:
                    w(f"  if (!std::isfinite(m.{f['name']})) e = Error::NonFinite;")
        w("  if (err) *err = e;")
        w("  if (e != Error::None) return 0;")
        w("  uint8_t* p = out;")
        w(f"  wire::put_header(p, {cname}::kType, {cname}::kBodySize);")
        for f in m["fields"]:
            if f["type"] == "str":
                w(f"  std::memcpy(p, m.{f['name']}.data(), {f['size']});")
                w(f"  p += {f['size']};")
            else:
                ctype = SCALARS[f["type"]][1]
                cast = "" if f["type"] == "f64" else f"<{ctype}>"
                if int(f.get("count", 1)) > 1:
                    w(f"  for (auto v : m.{f['name']}) wire::put{cast}(p, v);")
                else:
                    w(f"  wire::put{cast}(p, m.{f['name']});")
        w("  std::memset(p, 0, kTagSize);")
        w("  p += kTagSize;")
        w("  return static_cast<std::size_t>(p - out);")
        w("}")
        w("")
        # decode
        w(f"// Decodes a whole {m['name']} message; on error `m` is left unchanged. Checks the layout only:")
        w("// a received message must pass LinkAuth::open() first (receive() does both).")
        w(f"inline Error decode(const uint8_t* data, std::size_t n, {cname}& m) {{")
        w("  Type type;")
        w("  Error e = peek(data, n, type);")
        w("  if (e != Error::None) return e;")
        w(f"  if (type != {cname}::kType) return Error::WrongType;")
        w("  const uint8_t* h = data + 6;")
        w(f"  if (wire::get<uint16_t>(h) != {cname}::kBodySize || n != {cname}::kSize) return Error::BadSize;")
        w(f"  {cname} r;")
        w("  const uint8_t* p = data + kHeaderSize;")
        for f in m["fields"]:
            if f["type"] == "str":
                w(f"  std::memcpy(r.{f['name']}.data(), p, {f['size']});")
                w(f"  p += {f['size']};")
            else:
                ctype = SCALARS[f["type"]][1]
                if int(f.get("count", 1)) > 1:
                    w(f"  for (auto& v : r.{f['name']}) v = wire::get<{ctype}>(p);")
                else:
                    w(f"  r.{f['name']} = wire::get<{ctype}>(p);")
        for f in m["fields"]:
            if f["type"] == "f64":
                if int(f.get("count", 1)) > 1:
                    w(f"  for (double v : r.{f['name']}) if (!std::isfinite(v)) return Error::NonFinite;")
                else:
                    w(f"  if (!std::isfinite(r.{f['name']})) return Error::NonFinite;")
        w("  m = r;")
        w("  return Error::None;")
        w("}")
        w("")
    w("// Fixed-size string fields: copy with truncation and zero padding; read up to the first zero.")
    w("template <std::size_t N> inline void set_str(std::array<char, N>& dst, const std::string& s) {")
    w("  dst.fill(0);")
    w("  std::memcpy(dst.data(), s.data(), s.size() < N ? s.size() : N);")
    w("}")
    w("template <std::size_t N> inline std::string get_str(const std::array<char, N>& src) {")
    w("  std::size_t n = 0;")
    w("  while (n < N && src[n] != 0) ++n;")
    w("  return std::string(src.data(), n);")
    w("}")
    w("")
    cases = "\n".join(f"    case Type::{camel(m['name'])}: return {body_size(m)};" for m in schema["message"])
    magic_test = " && ".join(f"m[{i}] == {b}" for i, b in enumerate(schema["magic"].encode()))
    w(CPP_AUTH.replace("@BODY_CASES@", cases).replace("@MAGIC_TEST@", magic_test))
    w("}  // namespace rvd::msg")
    return "\n".join(out) + "\n"


# -------------------------------------------------------------------------------------- Python
def gen_py(schema: dict) -> str:
    out: list[str] = []
    w = out.append
    w('"""The rvd-pil link messages (Python side).')
    w("")
    w("GENERATED by schema/generate.py from schema/rvd_messages.toml -- do not edit by hand.")
    w("Little-endian, packed, fixed size per type: a 16-byte header (magic b'RVD', version, type,")
    w("reserved, body size, run nonce, sequence number), the body, a 16-byte tag (HMAC-SHA-256 under the")
    w("sender's direction key, see LinkAuth). Every float must be finite. Units are in the field names.")
    w('"""')
    w("from __future__ import annotations")
    w("")
    w("import hashlib")
    w("import hmac")
    w("import math")
    w("import struct")
    w("import threading")
    w("from dataclasses import dataclass, field, fields")
    w("")
    auth, keys = schema["auth"], schema["keys"]
    w(f"VERSION = {schema['version']}")
    w(f"UNTAGGED_VERSION = {UNTAGGED_VERSION}  # the protocol before tags: recognised only to count it as untagged")
    w(f"MAGIC = {schema['magic'].encode()!r}")
    w(f"HEADER_SIZE = {HEADER_SIZE}")
    w(f"TAG_SIZE = {auth['tag_size']}")
    w(f"KEY_SIZE = {auth['key_size']}")
    w(f"MAX_MESSAGE_SIZE = {max_message_size(schema)}  # the largest message, tag included")
    w(f"KEY_ENV = {auth['key_env']!r}  # environment variable with the key as {2 * auth['key_size']} hex digits")
    w(f"LABEL_HOST_TO_FLIGHT = {auth['label_host_to_flight'].encode()!r}")
    w(f"LABEL_FLIGHT_TO_HOST = {auth['label_flight_to_host'].encode()!r}")
    w(f"LABEL_RUN_NONCE = {auth['label_run_nonce'].encode()!r}")
    w(f"RUN_ID_MAX = {keys['run_id_max']}")
    w(f"RUN_ID_CHARS = frozenset({keys['run_id_chars']!r})")
    w('_HEADER = struct.Struct("<3sBBBHII")')
    w("KEYS = {")
    for k, v in schema["keys"].items():
        if k.startswith("run_id"):
            continue
        w(f"    {k!r}: {v!r},")
    w("}")
    w("")
    w("")
    w("def check_run_id(run: str) -> str:")
    w('    """`run` if it is a valid run id (1 to RUN_ID_MAX letters, digits, \'_\' or \'-\'), else ValueError."""')
    w("    if not isinstance(run, str) or not 1 <= len(run) <= RUN_ID_MAX or not set(run) <= RUN_ID_CHARS:")
    w("        raise ValueError(f\"run id {run!r}: needs 1 to {RUN_ID_MAX} characters from A-Z a-z 0-9 _ - \"")
    w("                         \"(no wildcards, no '/')\")")
    w("    return run")
    w("")
    w("")
    w("def key(kind: str, run: str) -> str:")
    w('    """Zenoh key expression of a message kind for a run id, e.g. key("nav", "r1") -> "rvd/r1/nav"."""')
    w('    return KEYS[kind].replace("<run>", check_run_id(run))')
    w("")
    w("")
    w("class MessageError(ValueError):")
    w('    """A byte string that is not a valid rvd message, or a message that cannot be encoded.')
    w("")
    w("    `kind` says why, for counting: malformed, oversized, untagged, wrong_run, bad_tag, replayed, or")
    w("    invalid (an authentic message whose content breaks the rules, e.g. NaN: the sender's own fault).")
    w('    """')
    w("")
    w('    def __init__(self, text: str, kind: str = "malformed"):')
    w("        super().__init__(text)")
    w("        self.kind = kind")
    w("")
    w("")
    classes = []
    for m in schema["message"]:
        cname = camel(m["name"])
        classes.append(cname)
        fmt = "<"
        for f in m["fields"]:
            if f["type"] == "str":
                fmt += f"{f['size']}s"
            else:
                cnt = int(f.get("count", 1))
                fmt += (str(cnt) if cnt > 1 else "") + SCALARS[f["type"]][2]
        w("@dataclass")
        w(f"class {cname}:")
        w(f'    """{m["doc"]}"""')
        w("")
        w(f"    TYPE = {m['id']}")
        w(f"    BODY = struct.Struct({fmt!r})")
        for f in m["fields"]:
            cnt = int(f.get("count", 1))
            if f["type"] == "str":
                w(f'    {f["name"]}: str = ""  # {f["doc"]}')
            elif cnt > 1:
                pytype = "float" if f["type"] == "f64" else "int"
                zero = "0.0" if f["type"] == "f64" else "0"
                w(f"    {f['name']}: tuple[{pytype}, ...] = field(default_factory=lambda: ({zero},) * {cnt})  # {f['doc']}")
            else:
                pytype, zero = ("float", "0.0") if f["type"] == "f64" else ("int", "0")
                w(f"    {f['name']}: {pytype} = {zero}  # {f['doc']}")
        w("")
        w("")
    w(f"MESSAGE_TYPES = {{cls.TYPE: cls for cls in ({', '.join(classes)},)}}")
    w("")
    w("# Field layout per class: (name, kind, count) with kind 'str', 'f64' or 'int'.")
    w("_LAYOUT = {")
    for m in schema["message"]:
        items = []
        for f in m["fields"]:
            kind = "str" if f["type"] == "str" else ("f64" if f["type"] == "f64" else "int")
            cnt = int(f["size"]) if f["type"] == "str" else int(f.get("count", 1))
            items.append(f"({f['name']!r}, {kind!r}, {cnt})")
        w(f"    {camel(m['name'])}: ({', '.join(items)},),")
    w("}")
    w("")
    w("")
    w("def encode(msg) -> bytes:")
    w('    """Encode a message object with nonce, sequence number and tag zero (LinkAuth.seal fills them);')
    w('    raises MessageError for NaN/Inf or out-of-range values."""')
    w("    cls = type(msg)")
    w("    if cls not in _LAYOUT:")
    w('        raise MessageError(f"not an rvd message: {cls.__name__}")')
    w("    flat = []")
    w("    for name, kind, count in _LAYOUT[cls]:")
    w("        value = getattr(msg, name)")
    w('        if kind == "str":')
    w('            raw = value.encode("utf-8")')
    w("            if len(raw) > count:")
    w('                raise MessageError(f"{cls.__name__}.{name}: string longer than {count} bytes")')
    w("            flat.append(raw)")
    w("            continue")
    w("        values = tuple(value) if count > 1 else (value,)")
    w("        if len(values) != count:")
    w('            raise MessageError(f"{cls.__name__}.{name}: needs {count} values, got {len(values)}")')
    w('        if kind == "f64" and not all(math.isfinite(v) for v in values):')
    w('            raise MessageError(f"{cls.__name__}.{name}: NaN or Inf is not allowed on the wire")')
    w("        flat.extend(values)")
    w("    try:")
    w("        body = cls.BODY.pack(*flat)")
    w("    except struct.error as exc:")
    w('        raise MessageError(f"{cls.__name__}: {exc}") from None')
    w("    return _HEADER.pack(MAGIC, VERSION, cls.TYPE, 0, len(body), 0, 0) + body + bytes(TAG_SIZE)")
    w("")
    w("")
    w("def _layout(data: bytes, expect=None):")
    w('    """The message class of `data` after checking magic, version, type and sizes (not the fields)."""')
    w("    if len(data) < HEADER_SIZE:")
    w('        raise MessageError(f"message shorter than its header ({len(data)} < {HEADER_SIZE} bytes)")')
    w("    magic, version, type_id, _reserved, size, _nonce, _seq = _HEADER.unpack_from(data)")
    w("    if magic != MAGIC:")
    w('        raise MessageError(f"bad magic {magic!r} (not an rvd message)")')
    w("    if version != VERSION:")
    w('        raise MessageError(f"unsupported protocol version {version} (this side speaks {VERSION})")')
    w("    cls = MESSAGE_TYPES.get(type_id)")
    w("    if cls is None:")
    w('        raise MessageError(f"unknown message type {type_id}")')
    w("    if expect is not None and cls is not expect:")
    w('        raise MessageError(f"expected {expect.__name__}, got {cls.__name__}")')
    w("    if size != cls.BODY.size or len(data) != HEADER_SIZE + cls.BODY.size + TAG_SIZE:")
    w("        raise MessageError(")
    w('            f"{cls.__name__}: body size {size} / {len(data) - HEADER_SIZE - TAG_SIZE} bytes, schema says {cls.BODY.size}"')
    w("        )")
    w("    return cls")
    w("")
    w("")
    w("def decode(data: bytes, expect=None):")
    w('    """Decode one message; raises MessageError saying why when the bytes are not a valid message.')
    w("")
    w("    `expect` (a message class) additionally requires that type. Checks the layout only: a received")
    w("    message must go through LinkAuth.open, which checks its nonce, tag and sequence number first.")
    w('    """')
    w("    data = bytes(data)")
    w("    cls = _layout(data, expect)")
    w("    flat = cls.BODY.unpack_from(data, HEADER_SIZE)")
    w("    kwargs = {}")
    w("    i = 0")
    w("    for name, kind, count in _LAYOUT[cls]:")
    w('        if kind == "str":')
    w('            kwargs[name] = flat[i].rstrip(b"\\0").decode("utf-8", errors="replace")')
    w("            i += 1")
    w("            continue")
    w("        values = flat[i : i + count]")
    w("        i += count")
    w('        if kind == "f64" and not all(math.isfinite(v) for v in values):')
    w('            raise MessageError(f"{cls.__name__}.{name}: NaN or Inf")')
    w("        kwargs[name] = tuple(values) if count > 1 else values[0]")
    w("    return cls(**kwargs)")
    w("")
    w("")
    w("def field_names(cls) -> list[str]:")
    w("    return [f.name for f in fields(cls)]")
    w("")
    w("")
    w(PY_AUTH)
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="fail if the generated files are stale")
    args = ap.parse_args(argv)
    schema = load_schema()
    outputs = {CPP_OUT: gen_cpp(schema), PY_OUT: gen_py(schema)}
    stale = [p for p, text in outputs.items() if not p.exists() or p.read_text() != text]
    if args.check:
        for p in stale:
            print(f"stale: {p.relative_to(ROOT)} (run python schema/generate.py)", file=sys.stderr)
        return 1 if stale else 0
    for p, text in outputs.items():
        p.write_text(text)
        print(f"wrote {p.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
