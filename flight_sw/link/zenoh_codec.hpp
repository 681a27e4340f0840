// Zenoh 1.x wire codec: pure functions on byte buffers, no I/O, no allocation.
//
// Written from the Zenoh wire summary in flight_sw/link/README.md (section numbers below refer
// to it). Three layers, each with the header byte [F3 F2 F1 | MID]:
//   transport messages (MID 0x00..0x07) inside TCP batches,
//   network messages   (MID 0x19..0x1F) inside Frames (or a reassembled Fragment chain),
//   data messages      (Put/Del/Query/Reply/Err) inside network messages.
// Decoded views (Bytes, std::string_view) point into the caller's buffer: they live as long as it.
// Decoders return nullptr on success or a static string that says what was wrong; they never read
// outside [data, data + size) whatever the input.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>

namespace rvd::link::zenoh {

// ---- constants ------------------------------------------------------------------------------
inline constexpr uint8_t kProtocolVersion = 0x09;  // §4
inline constexpr uint8_t kFlagZ = 0x80;            // an extension chain follows the fixed fields

namespace tmid {  // transport message ids, §4
inline constexpr uint8_t Oam = 0x00, Init = 0x01, Open = 0x02, Close = 0x03, KeepAlive = 0x04,
                         Frame = 0x05, Fragment = 0x06, Join = 0x07;
}
namespace nmid {  // network message ids, §7
inline constexpr uint8_t Interest = 0x19, ResponseFinal = 0x1A, Response = 0x1B, Request = 0x1C,
                         Push = 0x1D, Declare = 0x1E, Oam = 0x1F;
}
namespace dmid {  // data message ids, §8
inline constexpr uint8_t Put = 0x01, Del = 0x02, Query = 0x03, Reply = 0x04, Err = 0x05;
}
namespace declid {  // declaration ids inside a Declare, §7.2
inline constexpr uint8_t KeyExpr = 0x00, UndeclareKeyExpr = 0x01, Subscriber = 0x02,
                         UndeclareSubscriber = 0x03, Queryable = 0x04, UndeclareQueryable = 0x05,
                         Token = 0x06, UndeclareToken = 0x07, Final = 0x1A;
}
namespace whatami {  // 2-bit wire codes, §1
inline constexpr uint8_t Router = 0, Peer = 1, Client = 2;
}
namespace close_reason {  // §4.6
inline constexpr uint8_t Generic = 0, Unsupported = 1, Invalid = 2, MaxTransports = 3, MaxLinks = 4,
                         Expired = 5;
}

// Full extension ids (header & 0x7F) this client reads or writes.
namespace ext {
inline constexpr uint8_t InitPatch = 0x27;      // Z64, §4.1
inline constexpr uint8_t FragmentFirst = 0x02;  // Unit, §4.8 (patch >= 1)
inline constexpr uint8_t FragmentDrop = 0x03;   // Unit, §4.8 (patch >= 1)
inline constexpr uint8_t EncUnit = 0x00, EncZ64 = 0x20, EncZBuf = 0x40, EncReserved = 0x60;
inline constexpr uint8_t Mandatory = 0x10;
}  // namespace ext

constexpr bool is_network_mid(uint8_t header) {
  const uint8_t mid = header & 0x1F;
  return mid >= nmid::Interest && mid <= nmid::Oam;
}

// SN mask for a 2-bit resolution code (00 = 8, 01 = 16, 10 = 32, 11 = 64 bit), §6: the mask keeps
// the SN inside a VLE of the field's byte size.
uint64_t sn_mask(uint8_t resolution_bits);
// True when `next` is newer than `last` in the SN ring (Rust's `precedes`), §6.
bool sn_precedes(uint64_t last, uint64_t next, uint64_t mask);

// ---- byte views and the bounds-checked reader / writer ---------------------------------------
struct Bytes {
  const uint8_t* data = nullptr;
  size_t size = 0;
  std::string_view str() const { return {reinterpret_cast<const char*>(data), size}; }
};

class Reader {
 public:
  Reader(const uint8_t* data, size_t size) : p_(data), end_(data + size) {}
  size_t remaining() const { return static_cast<size_t>(end_ - p_); }
  const uint8_t* position() const { return p_; }
  bool peek(uint8_t& b) const;
  bool u8(uint8_t& v);
  bool u16le(uint16_t& v);
  bool vle(uint64_t& v);                    // at most 9 bytes, §1
  bool vle_max(uint64_t max, uint64_t& v);  // bounded VLE: rejects values above max
  bool raw(size_t n, Bytes& out);
  bool bytes(Bytes& out);                   // VLE length + bytes
  bool string(std::string_view& out);       // VLE length + UTF-8 bytes (not validated)
  Bytes rest();                             // everything left

 private:
  const uint8_t* p_;
  const uint8_t* end_;
};

// Writes into a fixed buffer; after the first write that does not fit, ok() is false for good.
class Writer {
 public:
  Writer(uint8_t* buffer, size_t capacity) : buf_(buffer), cap_(capacity) {}
  bool ok() const { return ok_; }
  size_t size() const { return len_; }
  void u8(uint8_t v);
  void u16le(uint16_t v);
  void vle(uint64_t v);
  void raw(const uint8_t* data, size_t n);
  void bytes(const uint8_t* data, size_t n);  // VLE length + bytes
  void string(std::string_view s);
  // Drops everything written after `size` bytes (and clears the overflow), to retry elsewhere.
  void rewind(size_t size);

 private:
  uint8_t* buf_;
  size_t cap_;
  size_t len_ = 0;
  bool ok_ = true;
};
size_t vle_size(uint64_t v);

// ---- field types ------------------------------------------------------------------------------
struct Zid {  // 1..16 bytes, little-endian u128 with trailing zero bytes trimmed, §1
  uint8_t size = 0;
  uint8_t bytes[16] = {};
};

struct Timestamp {  // §1: NTP64 time + the stamping node's id
  uint64_t ntp64 = 0;
  Zid id;
};

struct Encoding {  // §1: (id << 1) | S, then the schema string when S
  uint32_t id = 0;
  std::string_view schema;
};

struct WireExpr {  // §1, §7.3
  uint16_t scope = 0;           // 0: the key is the suffix
  std::string_view suffix;      // empty when the message had no N flag
  bool sender_mapping = false;  // M flag: scope id from the sender's table (else the receiver's)
};

// One extension of a chain, §2.
struct Extension {
  uint8_t id = 0;  // full id: header & 0x7F (ENC | M | ID)
  uint64_t z64 = 0;
  Bytes zbuf;
  bool mandatory() const { return (id & ext::Mandatory) != 0; }
};
// Reads one extension; `more` tells whether another follows (Z bit).
const char* read_extension(Reader& r, Extension& e, bool& more);
// Skips a whole chain (called after a header with the Z flag).
const char* skip_extensions(Reader& r);

// ---- transport messages -----------------------------------------------------------------------
struct InitMsg {  // InitSyn / InitAck, §4.1-4.2
  bool ack = false;
  uint8_t version = 0;
  uint8_t whatami = 0;
  Zid zid;
  bool has_size = false;      // S flag: resolution and batch size present (else the defaults)
  uint8_t resolution = 0x0A;  // fsn bits 0..1, rid bits 2..3 (default 32/32)
  uint16_t batch_size = 65535;
  Bytes cookie;               // InitAck only
  bool has_patch = false;
  uint64_t patch = 0;
};

struct OpenMsg {  // OpenSyn / OpenAck, §4.3-4.4
  bool ack = false;
  uint64_t lease_ms = 0;  // converted from seconds when the T flag was set
  uint64_t initial_sn = 0;
  Bytes cookie;  // OpenSyn only
};

struct CloseMsg {  // §4.6
  bool whole_session = false;
  uint8_t reason = 0;
};

struct FrameHeader {  // §4.7
  bool reliable = false;
  uint64_t sn = 0;
};

struct FragmentMsg {  // §4.8
  bool reliable = false;
  bool more = false;   // M flag: more pieces follow
  uint64_t sn = 0;
  bool first = false;  // First marker (patch >= 1)
  bool drop = false;   // Drop marker (patch >= 1): discard the partial message
  Bytes body;          // to the end of the batch
};

// ---- data and network messages ----------------------------------------------------------------
struct DataMsg {  // the body of a Push / Request / Response, §8
  uint8_t mid = 0;  // dmid::Put, Del, Query, Err (a Reply is unwrapped to its Put/Del)
  bool has_timestamp = false;
  Timestamp timestamp;
  bool has_encoding = false;
  Encoding encoding;
  Bytes payload;  // Put, Err; Query: the query-body payload when present
  bool has_consolidation = false;
  uint64_t consolidation = 0;   // Query / Reply
  std::string_view parameters;  // Query
};

struct NetworkMsg {
  uint8_t mid = 0;  // nmid::...
  WireExpr wire;    // Push, Request, Response, the declaration of a Declare, a restricted Interest
  bool has_wire = false;
  uint32_t request_id = 0;  // Request, Response, ResponseFinal
  DataMsg data;             // Push, Request, Response
  // Declare
  bool has_interest_id = false;
  uint32_t interest_id = 0;  // Declare (when I) and Interest
  uint8_t decl = 0;          // declid::...
  uint32_t decl_id = 0;      // entity or key-expression id
  // Interest
  uint8_t interest_mode = 0;  // 0 Final, 1 Current, 2 Future, 3 CurrentFuture
  uint8_t interest_options = 0;
};

// Decodes one network message starting at the reader's position.
const char* decode_network(Reader& r, NetworkMsg& m);

// Receives the messages of one batch in order. Views stay valid only during the call.
class BatchHandler {
 public:
  virtual ~BatchHandler() = default;
  virtual void on_init(const InitMsg&) {}
  virtual void on_open(const OpenMsg&) {}
  virtual void on_close(const CloseMsg&) {}
  virtual void on_keep_alive() {}
  // Return false to drop the frame: its network messages are still parsed (to find the frame's
  // end) but not delivered.
  virtual bool on_frame(const FrameHeader&) { return true; }
  virtual void on_network(const NetworkMsg&) {}
  virtual void on_fragment(const FragmentMsg&) {}
  virtual void on_oam() {}
  // Polled between messages: true stops the decoding of the rest of the batch.
  virtual bool stop() const { return false; }
};

// Decodes every transport message of one batch (§3). A Frame's network messages run until the
// batch ends or the next byte's MID is not a network MID. Returns nullptr on success, else the
// first error; the messages before it were delivered. `consumed` (optional) receives how many
// bytes were decoded, which is less than `size` when the handler asked to stop.
const char* decode_batch(const uint8_t* data, size_t size, BatchHandler& h,
                         size_t* consumed = nullptr);

// ---- encoders: each appends one message; false when it did not fit (the writer is spent) ----
bool encode_init_syn(Writer& w, const Zid& zid, uint8_t resolution, uint16_t batch_size,
                     bool with_size, uint64_t patch);
bool encode_open_syn(Writer& w, uint64_t lease_ms, uint64_t initial_sn, Bytes cookie);
// Also the peer-side replies, used by tests to build scripted traffic.
bool encode_init_ack(Writer& w, const Zid& zid, uint8_t whatami, uint8_t resolution,
                     uint16_t batch_size, Bytes cookie);
bool encode_open_ack(Writer& w, uint64_t lease_ms, uint64_t initial_sn);
bool encode_keep_alive(Writer& w);
bool encode_close(Writer& w, bool whole_session, uint8_t reason);
bool encode_frame_header(Writer& w, bool reliable, uint64_t sn);
bool encode_fragment_header(Writer& w, bool reliable, bool more, uint64_t sn, bool first_marker);

// Push(Put): wire expression, optional timestamp and encoding, payload.
struct PutFields {
  const Timestamp* timestamp = nullptr;
  const Encoding* encoding = nullptr;
  const uint8_t* payload = nullptr;
  size_t size = 0;
};
bool encode_push_put(Writer& w, const WireExpr& key, const PutFields& put);
bool encode_declare_keyexpr(Writer& w, uint16_t id, const WireExpr& key);
bool encode_undeclare_keyexpr(Writer& w, uint16_t id);
bool encode_declare_subscriber(Writer& w, uint32_t id, const WireExpr& key);
bool encode_undeclare_subscriber(Writer& w, uint32_t id);
bool encode_declare_final(Writer& w, uint32_t interest_id);
bool encode_response_final(Writer& w, uint32_t request_id);

}  // namespace rvd::link::zenoh
