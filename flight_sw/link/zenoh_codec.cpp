// Zenoh 1.x wire codec (see zenoh_codec.hpp). Field layouts: flight_sw/link/README.md, Zenoh wire summary §1-§8.
#include "flight_sw/link/zenoh_codec.hpp"

#include <cstring>

namespace rvd::link::zenoh {
namespace {

const char* const kTruncated = "message truncated";
const char* const kBadValue = "field value out of range";

constexpr uint8_t mid_of(uint8_t header) { return header & 0x1F; }
constexpr bool has(uint8_t header, uint8_t flag) { return (header & flag) != 0; }

// Transport / network / data flag bits (the meaning depends on the message, §4, §7, §8).
constexpr uint8_t kF1 = 0x20, kF2 = 0x40;

const char* read_zid_sized(Reader& r, size_t n, Zid& zid) {
  Bytes b;
  if (n == 0 || n > 16) return "ZenohID length outside 1..16";
  if (!r.raw(n, b)) return kTruncated;
  zid = Zid{};
  zid.size = static_cast<uint8_t>(n);
  std::memcpy(zid.bytes, b.data, n);
  return nullptr;
}

const char* read_timestamp(Reader& r, Timestamp& ts) {
  uint64_t n = 0;
  if (!r.vle(ts.ntp64) || !r.vle(n)) return kTruncated;
  return read_zid_sized(r, n, ts.id);
}

const char* read_encoding(Reader& r, Encoding& e) {
  uint64_t v = 0;
  if (!r.vle_max(0xFFFFFFFFull, v)) return kTruncated;
  e.id = static_cast<uint32_t>(v >> 1);
  e.schema = {};
  if ((v & 1) && !r.string(e.schema)) return kTruncated;
  return nullptr;
}

// WireExpr with the N (suffix present) and M (sender mapping) bits taken from the enclosing header.
const char* read_wire_expr(Reader& r, bool named, bool sender_mapping, WireExpr& w) {
  uint64_t scope = 0;
  if (!r.vle_max(0xFFFF, scope)) return kTruncated;
  w.scope = static_cast<uint16_t>(scope);
  w.suffix = {};
  w.sender_mapping = sender_mapping;
  if (named && !r.string(w.suffix)) return kTruncated;
  return nullptr;
}

const char* read_u32(Reader& r, uint32_t& v) {
  uint64_t x = 0;
  if (!r.vle_max(0xFFFFFFFFull, x)) return kTruncated;
  v = static_cast<uint32_t>(x);
  return nullptr;
}

// ---- data messages, §8 ----
const char* decode_put(Reader& r, uint8_t h, DataMsg& d) {
  d.mid = dmid::Put;
  d.has_timestamp = has(h, kF1);
  if (d.has_timestamp) {
    if (const char* e = read_timestamp(r, d.timestamp)) return e;
  }
  d.has_encoding = has(h, kF2);
  if (d.has_encoding) {
    if (const char* e = read_encoding(r, d.encoding)) return e;
  }
  if (has(h, kFlagZ)) {
    if (const char* e = skip_extensions(r)) return e;
  }
  if (!r.bytes(d.payload)) return kTruncated;
  return nullptr;
}

const char* decode_del(Reader& r, uint8_t h, DataMsg& d) {
  d.mid = dmid::Del;
  d.has_timestamp = has(h, kF1);
  if (d.has_timestamp) {
    if (const char* e = read_timestamp(r, d.timestamp)) return e;
  }
  if (has(h, kFlagZ)) return skip_extensions(r);
  return nullptr;
}

const char* decode_put_or_del(Reader& r, DataMsg& d) {
  uint8_t h = 0;
  if (!r.u8(h)) return kTruncated;
  if (mid_of(h) == dmid::Put) return decode_put(r, h, d);
  if (mid_of(h) == dmid::Del) return decode_del(r, h, d);
  return "expected a Put or Del data message";
}

const char* decode_query(Reader& r, uint8_t h, DataMsg& d) {
  d.mid = dmid::Query;
  d.has_consolidation = has(h, kF1);
  if (d.has_consolidation && !r.vle(d.consolidation)) return kTruncated;
  if (has(h, kF2) && !r.string(d.parameters)) return kTruncated;
  bool more = has(h, kFlagZ);
  while (more) {
    Extension x;
    if (const char* e = read_extension(r, x, more)) return e;
    if ((x.id & ~ext::Mandatory) == 0x43) {  // ZBuf, id 3
      // Query body (§8.3): encoding, then the raw payload to the end of the extension.
      Reader body(x.zbuf.data, x.zbuf.size);
      d.has_encoding = true;
      if (const char* e = read_encoding(body, d.encoding)) return e;
      d.payload = body.rest();
    }
  }
  return nullptr;
}

const char* decode_reply(Reader& r, uint8_t h, DataMsg& d) {
  d.has_consolidation = has(h, kF1);
  if (d.has_consolidation && !r.vle(d.consolidation)) return kTruncated;
  if (has(h, kFlagZ)) {
    if (const char* e = skip_extensions(r)) return e;
  }
  return decode_put_or_del(r, d);
}

const char* decode_err(Reader& r, uint8_t h, DataMsg& d) {
  d.mid = dmid::Err;
  d.has_encoding = has(h, kF2);
  if (d.has_encoding) {
    if (const char* e = read_encoding(r, d.encoding)) return e;
  }
  if (has(h, kFlagZ)) {
    if (const char* e = skip_extensions(r)) return e;
  }
  if (!r.bytes(d.payload)) return kTruncated;
  return nullptr;
}

// ---- declarations, §7.2 ----
const char* decode_declaration(Reader& r, NetworkMsg& m) {
  uint8_t h = 0;
  if (!r.u8(h)) return kTruncated;
  m.decl = mid_of(h);
  const bool named = has(h, kF1), mapping = has(h, kF2);
  switch (m.decl) {
    case declid::KeyExpr: {
      uint64_t id = 0;
      if (!r.vle_max(0xFFFF, id)) return kTruncated;
      if (id == 0) return "key expression id 0 is reserved";
      m.decl_id = static_cast<uint32_t>(id);
      // DeclareKeyExpr has no M flag: its scope uses the default (receiver) mapping.
      if (const char* e = read_wire_expr(r, named, false, m.wire)) return e;
      m.has_wire = true;
      break;
    }
    case declid::UndeclareKeyExpr: {
      uint64_t id = 0;
      if (!r.vle_max(0xFFFF, id)) return kTruncated;
      m.decl_id = static_cast<uint32_t>(id);
      break;
    }
    case declid::Subscriber:
    case declid::Queryable:
    case declid::Token:
      if (const char* e = read_u32(r, m.decl_id)) return e;
      if (const char* e = read_wire_expr(r, named, mapping, m.wire)) return e;
      m.has_wire = true;
      break;
    case declid::UndeclareSubscriber:
    case declid::UndeclareQueryable:
    case declid::UndeclareToken:
      if (const char* e = read_u32(r, m.decl_id)) return e;
      break;
    case declid::Final:
      break;
    default:
      return "unknown declaration id";
  }
  if (has(h, kFlagZ)) return skip_extensions(r);
  return nullptr;
}

}  // namespace

// ---- SN arithmetic, §6 ----
uint64_t sn_mask(uint8_t resolution_bits) {
  switch (resolution_bits & 0x03) {
    case 0: return 0x7F;
    case 1: return 0x3FFF;
    case 2: return 0x0FFFFFFF;
    default: return 0x7FFFFFFFFFFFFFFFull;
  }
}

bool sn_precedes(uint64_t last, uint64_t next, uint64_t mask) {
  const uint64_t gap = (next - last) & mask;
  return gap != 0 && gap <= mask / 2;
}

// ---- Reader / Writer ----
bool Reader::peek(uint8_t& b) const {
  if (p_ == end_) return false;
  b = *p_;
  return true;
}

bool Reader::u8(uint8_t& v) {
  if (p_ == end_) return false;
  v = *p_++;
  return true;
}

bool Reader::u16le(uint16_t& v) {
  if (remaining() < 2) return false;
  v = static_cast<uint16_t>(p_[0] | (p_[1] << 8));
  p_ += 2;
  return true;
}

bool Reader::vle(uint64_t& v) {
  uint64_t out = 0;
  for (int i = 0; i < 8; ++i) {
    if (p_ == end_) return false;
    const uint8_t b = *p_++;
    out |= static_cast<uint64_t>(b & 0x7F) << (7 * i);
    if ((b & 0x80) == 0) {
      v = out;
      return true;
    }
  }
  if (p_ == end_) return false;  // the 9th byte carries 8 payload bits
  out |= static_cast<uint64_t>(*p_++) << 56;
  v = out;
  return true;
}

bool Reader::vle_max(uint64_t max, uint64_t& v) { return vle(v) && v <= max; }

bool Reader::raw(size_t n, Bytes& out) {
  if (remaining() < n) return false;
  out = {p_, n};
  p_ += n;
  return true;
}

bool Reader::bytes(Bytes& out) {
  uint64_t n = 0;
  return vle(n) && n <= remaining() && raw(static_cast<size_t>(n), out);
}

bool Reader::string(std::string_view& out) {
  Bytes b;
  if (!bytes(b)) return false;
  out = b.str();
  return true;
}

Bytes Reader::rest() {
  Bytes b{p_, remaining()};
  p_ = end_;
  return b;
}

void Writer::u8(uint8_t v) {
  if (!ok_ || len_ + 1 > cap_) {
    ok_ = false;
    return;
  }
  buf_[len_++] = v;
}

void Writer::u16le(uint16_t v) {
  u8(static_cast<uint8_t>(v & 0xFF));
  u8(static_cast<uint8_t>(v >> 8));
}

void Writer::vle(uint64_t v) {
  for (int i = 0; i < 8; ++i) {
    if (v <= 0x7F) {
      u8(static_cast<uint8_t>(v));
      return;
    }
    u8(static_cast<uint8_t>((v & 0x7F) | 0x80));
    v >>= 7;
  }
  u8(static_cast<uint8_t>(v));
}

void Writer::raw(const uint8_t* data, size_t n) {
  if (!ok_ || n > cap_ - len_) {
    ok_ = false;
    return;
  }
  if (n) std::memcpy(buf_ + len_, data, n);
  len_ += n;
}

void Writer::bytes(const uint8_t* data, size_t n) {
  vle(n);
  raw(data, n);
}

void Writer::string(std::string_view s) {
  bytes(reinterpret_cast<const uint8_t*>(s.data()), s.size());
}

void Writer::rewind(size_t size) {
  if (size <= len_) {
    len_ = size;
    ok_ = true;
  }
}

size_t vle_size(uint64_t v) {
  size_t n = 1;
  while (v > 0x7F && n < 9) {
    v >>= 7;
    ++n;
  }
  return n;
}

// ---- extensions, §2 ----
const char* read_extension(Reader& r, Extension& e, bool& more) {
  uint8_t h = 0;
  if (!r.u8(h)) return kTruncated;
  e = Extension{};
  e.id = h & 0x7F;
  more = has(h, kFlagZ);
  switch (h & 0x60) {
    case ext::EncUnit: return nullptr;
    case ext::EncZ64: return r.vle(e.z64) ? nullptr : kTruncated;
    case ext::EncZBuf: return r.bytes(e.zbuf) ? nullptr : kTruncated;
    default: return "extension with the reserved encoding";
  }
}

const char* skip_extensions(Reader& r) {
  bool more = true;
  while (more) {
    Extension e;
    if (const char* err = read_extension(r, e, more)) return err;
  }
  return nullptr;
}

// ---- network messages, §7 ----
namespace {
// The key expression and the optional extensions that open Push, Request and Response.
const char* read_wire_head(Reader& r, uint8_t h, NetworkMsg& m) {
  if (const char* e = read_wire_expr(r, has(h, kF1), has(h, kF2), m.wire)) return e;
  m.has_wire = true;
  return has(h, kFlagZ) ? skip_extensions(r) : nullptr;
}
}  // namespace

const char* decode_network(Reader& r, NetworkMsg& m) {
  uint8_t h = 0;
  if (!r.u8(h)) return kTruncated;
  m = NetworkMsg{};
  m.mid = mid_of(h);
  switch (m.mid) {
    case nmid::Push: {
      if (const char* e = read_wire_head(r, h, m)) return e;
      return decode_put_or_del(r, m.data);
    }
    case nmid::Request: {
      if (const char* e = read_u32(r, m.request_id)) return e;
      if (const char* e = read_wire_head(r, h, m)) return e;
      uint8_t b = 0;
      if (!r.u8(b)) return kTruncated;
      if (mid_of(b) == dmid::Query) return decode_query(r, b, m.data);
      if (mid_of(b) == dmid::Put) return decode_put(r, b, m.data);  // legacy request bodies
      if (mid_of(b) == dmid::Del) return decode_del(r, b, m.data);
      return "unknown request body";
    }
    case nmid::Response: {
      if (const char* e = read_u32(r, m.request_id)) return e;
      if (const char* e = read_wire_head(r, h, m)) return e;
      uint8_t b = 0;
      if (!r.u8(b)) return kTruncated;
      if (mid_of(b) == dmid::Reply) return decode_reply(r, b, m.data);
      if (mid_of(b) == dmid::Err) return decode_err(r, b, m.data);
      return "unknown response body";
    }
    case nmid::ResponseFinal: {
      if (const char* e = read_u32(r, m.request_id)) return e;
      if (has(h, kFlagZ)) return skip_extensions(r);
      return nullptr;
    }
    case nmid::Declare: {
      m.has_interest_id = has(h, kF1);
      if (m.has_interest_id) {
        if (const char* e = read_u32(r, m.interest_id)) return e;
      }
      if (has(h, kFlagZ)) {
        if (const char* e = skip_extensions(r)) return e;
      }
      return decode_declaration(r, m);
    }
    case nmid::Interest: {
      if (const char* e = read_u32(r, m.interest_id)) return e;
      m.interest_mode = (h >> 5) & 0x03;
      if (m.interest_mode != 0) {
        if (!r.u8(m.interest_options)) return kTruncated;
        if (m.interest_options & 0x10) {  // R: restricted to a key expression
          const bool named = m.interest_options & 0x20, mapping = m.interest_options & 0x40;
          if (const char* e = read_wire_expr(r, named, mapping, m.wire)) return e;
          m.has_wire = true;
        }
      }
      if (has(h, kFlagZ)) return skip_extensions(r);
      return nullptr;
    }
    case nmid::Oam: {
      uint64_t id = 0;
      if (!r.vle(id)) return kTruncated;
      if (has(h, kFlagZ)) {
        if (const char* e = skip_extensions(r)) return e;
      }
      uint64_t v = 0;
      Bytes b;
      switch ((h >> 5) & 0x03) {
        case 0: return nullptr;
        case 1: return r.vle(v) ? nullptr : kTruncated;
        case 2: return r.bytes(b) ? nullptr : kTruncated;
        default: return kBadValue;
      }
    }
    default:
      return "not a network message id";
  }
}

// ---- transport messages, §4 ----
namespace {

const char* decode_init(Reader& r, uint8_t h, InitMsg& m) {
  m = InitMsg{};
  m.ack = has(h, kF1);
  uint8_t zw = 0;
  if (!r.u8(m.version) || !r.u8(zw)) return kTruncated;
  m.whatami = zw & 0x03;
  if (const char* e = read_zid_sized(r, static_cast<size_t>(zw >> 4) + 1, m.zid)) return e;
  m.has_size = has(h, kF2);
  if (m.has_size && (!r.u8(m.resolution) || !r.u16le(m.batch_size))) return kTruncated;
  if (m.ack && !r.bytes(m.cookie)) return kTruncated;
  bool more = has(h, kFlagZ);
  while (more) {
    Extension x;
    if (const char* e = read_extension(r, x, more)) return e;
    if (x.id == ext::InitPatch) {
      m.has_patch = true;
      m.patch = x.z64;
    }
  }
  return nullptr;
}

const char* decode_open(Reader& r, uint8_t h, OpenMsg& m) {
  m = OpenMsg{};
  m.ack = has(h, kF1);
  if (!r.vle(m.lease_ms) || !r.vle(m.initial_sn)) return kTruncated;
  if (has(h, kF2)) {  // lease in seconds
    if (m.lease_ms > UINT64_MAX / 1000) return kBadValue;
    m.lease_ms *= 1000;
  }
  if (!m.ack && !r.bytes(m.cookie)) return kTruncated;
  if (has(h, kFlagZ)) return skip_extensions(r);
  return nullptr;
}

}  // namespace

namespace {
const char* decode_messages(Reader& r, BatchHandler& h);
}

const char* decode_batch(const uint8_t* data, size_t size, BatchHandler& h, size_t* consumed) {
  Reader r(data, size);
  const char* error = decode_messages(r, h);
  if (consumed) *consumed = size - r.remaining();
  return error;
}

namespace {
const char* decode_messages(Reader& r, BatchHandler& h) {
  while (r.remaining() > 0 && !h.stop()) {
    uint8_t hdr = 0;
    r.u8(hdr);
    switch (mid_of(hdr)) {
      case tmid::Oam: {
        uint64_t id = 0, v = 0;
        Bytes b;
        if (!r.vle(id)) return kTruncated;
        if (has(hdr, kFlagZ)) {
          if (const char* e = skip_extensions(r)) return e;
        }
        const uint8_t enc = (hdr >> 5) & 0x03;
        if (enc == 3) return kBadValue;
        if ((enc == 1 && !r.vle(v)) || (enc == 2 && !r.bytes(b))) return kTruncated;
        h.on_oam();
        break;
      }
      case tmid::Init: {
        InitMsg m;
        if (const char* e = decode_init(r, hdr, m)) return e;
        h.on_init(m);
        break;
      }
      case tmid::Open: {
        OpenMsg m;
        if (const char* e = decode_open(r, hdr, m)) return e;
        h.on_open(m);
        break;
      }
      case tmid::Close: {
        CloseMsg m;
        m.whole_session = has(hdr, kF1);
        if (!r.u8(m.reason)) return kTruncated;
        if (has(hdr, kFlagZ)) {
          if (const char* e = skip_extensions(r)) return e;
        }
        h.on_close(m);
        break;
      }
      case tmid::KeepAlive: {
        if (has(hdr, kFlagZ)) {
          if (const char* e = skip_extensions(r)) return e;
        }
        h.on_keep_alive();
        break;
      }
      case tmid::Frame: {
        FrameHeader f;
        f.reliable = has(hdr, kF1);
        if (!r.vle(f.sn)) return kTruncated;
        if (has(hdr, kFlagZ)) {
          if (const char* e = skip_extensions(r)) return e;
        }
        const bool deliver = h.on_frame(f);
        // The frame ends at the batch end or at the first byte that is not a network MID (§3).
        uint8_t next = 0;
        while (r.peek(next) && is_network_mid(next) && !h.stop()) {
          NetworkMsg m;
          if (const char* e = decode_network(r, m)) return e;
          if (deliver) h.on_network(m);
        }
        break;
      }
      case tmid::Fragment: {
        FragmentMsg f;
        f.reliable = has(hdr, kF1);
        f.more = has(hdr, kF2);
        if (!r.vle(f.sn)) return kTruncated;
        bool more = has(hdr, kFlagZ);
        while (more) {
          Extension x;
          if (const char* e = read_extension(r, x, more)) return e;
          if (x.id == ext::FragmentFirst) f.first = true;
          if (x.id == ext::FragmentDrop) f.drop = true;
        }
        f.body = r.rest();  // a Fragment always ends its batch
        h.on_fragment(f);
        break;
      }
      default:
        return "unknown or unsupported transport message id";
    }
  }
  return nullptr;
}
}  // namespace

// ---- encoders ----
namespace {
void write_zid_nibble(Writer& w, const Zid& zid, uint8_t low_bits) {
  w.u8(static_cast<uint8_t>(((zid.size - 1) << 4) | (low_bits & 0x0F)));
  w.raw(zid.bytes, zid.size);
}

void write_wire_expr(Writer& w, const WireExpr& k) {
  w.vle(k.scope);
  if (!k.suffix.empty()) w.string(k.suffix);
}

uint8_t wire_flags(const WireExpr& k) {
  return static_cast<uint8_t>((k.suffix.empty() ? 0 : kF1) | (k.sender_mapping ? kF2 : 0));
}
}  // namespace

bool encode_init_syn(Writer& w, const Zid& zid, uint8_t resolution, uint16_t batch_size,
                     bool with_size, uint64_t patch) {
  if (zid.size == 0 || zid.size > 16) return false;
  w.u8(static_cast<uint8_t>(tmid::Init | (with_size ? kF2 : 0) | (patch ? kFlagZ : 0)));
  w.u8(kProtocolVersion);
  write_zid_nibble(w, zid, whatami::Client);
  if (with_size) {
    w.u8(resolution);
    w.u16le(batch_size);
  }
  if (patch) {
    w.u8(ext::InitPatch);  // Z64, last extension
    w.vle(patch);
  }
  return w.ok();
}

bool encode_init_ack(Writer& w, const Zid& zid, uint8_t wai, uint8_t resolution,
                     uint16_t batch_size, Bytes cookie) {
  if (zid.size == 0 || zid.size > 16) return false;
  w.u8(tmid::Init | kF1 | kF2);
  w.u8(kProtocolVersion);
  write_zid_nibble(w, zid, wai);
  w.u8(resolution);
  w.u16le(batch_size);
  w.bytes(cookie.data, cookie.size);
  return w.ok();
}

bool encode_open_syn(Writer& w, uint64_t lease_ms, uint64_t initial_sn, Bytes cookie) {
  const bool seconds = lease_ms % 1000 == 0;
  w.u8(static_cast<uint8_t>(tmid::Open | (seconds ? kF2 : 0)));
  w.vle(seconds ? lease_ms / 1000 : lease_ms);
  w.vle(initial_sn);
  w.bytes(cookie.data, cookie.size);
  return w.ok();
}

bool encode_open_ack(Writer& w, uint64_t lease_ms, uint64_t initial_sn) {
  const bool seconds = lease_ms % 1000 == 0;
  w.u8(static_cast<uint8_t>(tmid::Open | kF1 | (seconds ? kF2 : 0)));
  w.vle(seconds ? lease_ms / 1000 : lease_ms);
  w.vle(initial_sn);
  return w.ok();
}

bool encode_keep_alive(Writer& w) {
  w.u8(tmid::KeepAlive);
  return w.ok();
}

bool encode_close(Writer& w, bool whole_session, uint8_t reason) {
  w.u8(static_cast<uint8_t>(tmid::Close | (whole_session ? kF1 : 0)));
  w.u8(reason);
  return w.ok();
}

bool encode_frame_header(Writer& w, bool reliable, uint64_t sn) {
  w.u8(static_cast<uint8_t>(tmid::Frame | (reliable ? kF1 : 0)));
  w.vle(sn);
  return w.ok();
}

bool encode_fragment_header(Writer& w, bool reliable, bool more, uint64_t sn, bool first_marker) {
  w.u8(static_cast<uint8_t>(tmid::Fragment | (reliable ? kF1 : 0) | (more ? kF2 : 0) |
                            (first_marker ? kFlagZ : 0)));
  w.vle(sn);
  if (first_marker) w.u8(ext::FragmentFirst);
  return w.ok();
}

bool encode_push_put(Writer& w, const WireExpr& key, const PutFields& put) {
  w.u8(static_cast<uint8_t>(nmid::Push | wire_flags(key)));
  write_wire_expr(w, key);
  w.u8(static_cast<uint8_t>(dmid::Put | (put.timestamp ? kF1 : 0) | (put.encoding ? kF2 : 0)));
  if (put.timestamp) {
    w.vle(put.timestamp->ntp64);
    w.bytes(put.timestamp->id.bytes, put.timestamp->id.size);
  }
  if (put.encoding) {
    const bool schema = !put.encoding->schema.empty();
    w.vle((static_cast<uint64_t>(put.encoding->id) << 1) | (schema ? 1 : 0));
    if (schema) w.string(put.encoding->schema);
  }
  w.bytes(put.payload, put.size);
  return w.ok();
}

bool encode_declare_keyexpr(Writer& w, uint16_t id, const WireExpr& key) {
  if (id == 0) return false;
  w.u8(nmid::Declare);
  w.u8(static_cast<uint8_t>(declid::KeyExpr | (key.suffix.empty() ? 0 : kF1)));
  w.vle(id);
  write_wire_expr(w, key);
  return w.ok();
}

bool encode_undeclare_keyexpr(Writer& w, uint16_t id) {
  w.u8(nmid::Declare);
  w.u8(declid::UndeclareKeyExpr);
  w.vle(id);
  return w.ok();
}

bool encode_declare_subscriber(Writer& w, uint32_t id, const WireExpr& key) {
  w.u8(nmid::Declare);
  w.u8(static_cast<uint8_t>(declid::Subscriber | wire_flags(key)));
  w.vle(id);
  write_wire_expr(w, key);
  return w.ok();
}

bool encode_undeclare_subscriber(Writer& w, uint32_t id) {
  w.u8(nmid::Declare);
  w.u8(declid::UndeclareSubscriber);
  w.vle(id);
  return w.ok();
}

bool encode_declare_final(Writer& w, uint32_t interest_id) {
  w.u8(nmid::Declare | kF1);
  w.vle(interest_id);
  w.u8(declid::Final);
  return w.ok();
}

bool encode_response_final(Writer& w, uint32_t request_id) {
  w.u8(nmid::ResponseFinal);
  w.vle(request_id);
  return w.ok();
}

}  // namespace rvd::link::zenoh
