// Zenoh wire codec against byte vectors captured from eclipse-zenoh 1.10.2 (layouts: the Zenoh wire
// summary of flight_sw/link/README.md; section numbers refer to it), plus a decoder fuzz.
#include <doctest/doctest.h>

#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "flight_sw/link/zenoh_codec.hpp"
#include "flight_sw/link/zenoh_keyexpr.hpp"

using namespace rvd::link::zenoh;
using Buf = std::vector<uint8_t>;

namespace {

Buf hex(const char* h) {
  Buf out;
  auto nib = [](char c) { return c <= '9' ? c - '0' : (c | 0x20) - 'a' + 10; };
  for (const char* p = h; *p;) {
    if (*p == ' ') {
      ++p;
      continue;
    }
    out.push_back(static_cast<uint8_t>(nib(p[0]) << 4 | nib(p[1])));
    p += 2;
  }
  return out;
}

Buf cat(std::initializer_list<Buf> parts) {
  Buf out;
  for (const Buf& p : parts) out.insert(out.end(), p.begin(), p.end());
  return out;
}

Buf text(const std::string& s) { return Buf(s.begin(), s.end()); }

Buf counting(size_t n, uint8_t start = 0) {
  Buf b(n);
  for (size_t i = 0; i < n; ++i) b[i] = static_cast<uint8_t>(start + i);
  return b;
}

Zid zid_of(const Buf& b) {
  Zid z;
  z.size = static_cast<uint8_t>(b.size());
  std::memcpy(z.bytes, b.data(), b.size());
  return z;
}

// Records everything a batch delivers, copying views (they die with the batch) and checking that
// every view lies inside the batch.
struct Recorder : BatchHandler {
  const uint8_t* lo = nullptr;
  const uint8_t* hi = nullptr;
  bool view_escaped = false;
  std::vector<InitMsg> inits;
  std::vector<OpenMsg> opens;
  std::vector<CloseMsg> closes;
  std::vector<FrameHeader> frames;
  std::vector<NetworkMsg> nets;
  std::vector<std::string> keys, payloads, params;
  std::vector<FragmentMsg> fragments;
  Buf cookie;
  int keep_alives = 0;

  void check(const void* p, size_t n) {
    const auto* b = static_cast<const uint8_t*>(p);
    if (n && (b < lo || b + n > hi)) view_escaped = true;
  }
  void on_init(const InitMsg& m) override {
    check(m.cookie.data, m.cookie.size);
    cookie.assign(m.cookie.data, m.cookie.data + m.cookie.size);
    inits.push_back(m);
  }
  void on_open(const OpenMsg& m) override {
    check(m.cookie.data, m.cookie.size);
    cookie.assign(m.cookie.data, m.cookie.data + m.cookie.size);
    opens.push_back(m);
  }
  void on_close(const CloseMsg& m) override { closes.push_back(m); }
  void on_keep_alive() override { ++keep_alives; }
  bool on_frame(const FrameHeader& f) override {
    frames.push_back(f);
    return true;
  }
  void on_network(const NetworkMsg& m) override {
    check(m.wire.suffix.data(), m.wire.suffix.size());
    check(m.data.payload.data, m.data.payload.size);
    check(m.data.parameters.data(), m.data.parameters.size());
    check(m.data.encoding.schema.data(), m.data.encoding.schema.size());
    keys.emplace_back(m.wire.suffix);
    payloads.emplace_back(m.data.payload.str());
    params.emplace_back(m.data.parameters);
    nets.push_back(m);
  }
  void on_fragment(const FragmentMsg& f) override {
    check(f.body.data, f.body.size);
    fragments.push_back(f);
  }
};

const char* decode(const Buf& b, Recorder& r) {
  r.lo = b.data();
  r.hi = b.data() + b.size();
  return decode_batch(b.data(), b.size(), r);
}

template <typename F>
Buf encoded(F&& f) {
  Buf out(70000);
  Writer w(out.data(), out.size());
  REQUIRE(f(w));
  out.resize(w.size());
  return out;
}

const Buf kZid = hex("e255a8c0 11223344 55667788 99f5b0f5");  // 16 bytes, last non-zero

}  // namespace

TEST_CASE("VLE integers match the notes and round-trip at the edges (§1)") {
  const std::pair<uint64_t, const char*> vectors[] = {
      {0, "00"}, {127, "7f"}, {128, "8001"}, {2000, "d00f"}, {3000, "b817"}};
  for (const auto& [value, bytes] : vectors) {
    CHECK(encoded([&](Writer& w) { w.vle(value); return w.ok(); }) == hex(bytes));
  }
  for (uint64_t v : {uint64_t{1} << 56, (uint64_t{1} << 56) - 1, uint64_t{1} << 63, ~uint64_t{0}}) {
    const Buf b = encoded([&](Writer& w) { w.vle(v); return w.ok(); });
    CHECK(b.size() == vle_size(v));
    CHECK(b.size() <= 9);
    Reader r(b.data(), b.size());
    uint64_t back = 0;
    REQUIRE(r.vle(back));
    CHECK(back == v);
    CHECK(r.remaining() == 0);
  }
  // All-ones in 9 bytes is the largest u64; every strict prefix is truncated.
  const Buf max9 = hex("ffffffffffffffffff");
  uint64_t v = 0;
  Reader r(max9.data(), max9.size());
  REQUIRE(r.vle(v));
  CHECK(v == ~uint64_t{0});
  for (size_t n = 0; n < max9.size(); ++n) {
    Reader t(max9.data(), n);
    CHECK_FALSE(t.vle(v));
  }
  // Bounded fields reject what does not fit their type.
  const Buf big = hex("808004");  // 65536
  Reader b16(big.data(), big.size());
  CHECK_FALSE(b16.vle_max(0xFFFF, v));
}

TEST_CASE("InitSyn, OpenSyn encode to the captured bytes (§4.1, §4.3)") {
  const Zid zid = zid_of(kZid);
  CHECK(encoded([&](Writer& w) { return encode_init_syn(w, zid, 0x0A, 65535, false, 0); }) ==
        cat({hex("0109f2"), kZid}));
  // With sizes and the patch extension: S|Z header, resolution, u16le batch, then Z64 0x27 = 1.
  CHECK(encoded([&](Writer& w) { return encode_init_syn(w, zid, 0x0A, 2048, true, 1); }) ==
        cat({hex("c109f2"), kZid, hex("0a0008 2701")}));

  const Buf cookie = counting(49, 0x40);
  const Buf open_syn = cat({hex("420adcf4c637 31"), cookie});
  CHECK(encoded([&](Writer& w) { return encode_open_syn(w, 10000, 116505180, {cookie.data(), 49}); }) ==
        open_syn);
  Recorder r;
  REQUIRE(decode(open_syn, r) == nullptr);
  REQUIRE(r.opens.size() == 1);
  CHECK_FALSE(r.opens[0].ack);
  CHECK(r.opens[0].lease_ms == 10000);
  CHECK(r.opens[0].initial_sn == 116505180);
  CHECK(r.cookie == cookie);
  // A lease that is not whole seconds goes in milliseconds (T flag clear).
  CHECK(encoded([&](Writer& w) { return encode_open_syn(w, 2500, 5, {cookie.data(), 0}); }) ==
        hex("02c413 05 00"));
}

TEST_CASE("InitAck and OpenAck decode as observed (§4.2, §4.4)") {
  const Buf cookie = counting(49, 1);
  // 0x61: Init|A|S from a peer (whatami 1), 32/32-bit resolution, batch 49152.
  const Buf init_ack = cat({hex("6109f1"), kZid, hex("0a00c0 31"), cookie});
  Recorder r;
  REQUIRE(decode(init_ack, r) == nullptr);
  REQUIRE(r.inits.size() == 1);
  const InitMsg& m = r.inits[0];
  CHECK(m.ack);
  CHECK(m.version == 0x09);
  CHECK(m.whatami == whatami::Peer);
  CHECK(m.zid.size == 16);
  CHECK(std::memcmp(m.zid.bytes, kZid.data(), 16) == 0);
  CHECK(m.has_size);
  CHECK(m.resolution == 0x0A);
  CHECK(m.batch_size == 49152);
  CHECK(r.cookie == cookie);
  CHECK_FALSE(m.has_patch);
  // 0xE1: the same with the Patch extension echoed; an unknown extension before it is skipped.
  const Buf with_patch = cat({hex("e109f0"), kZid, hex("0a00c0 31"), cookie, hex("c5 02 abcd 2701")});
  Recorder p;
  REQUIRE(decode(with_patch, p) == nullptr);
  REQUIRE(p.inits.size() == 1);
  CHECK(p.inits[0].whatami == whatami::Router);
  CHECK(p.inits[0].has_patch);
  CHECK(p.inits[0].patch == 1);
  // Our own encoder for the peer side produces what the decoder reads.
  const Zid zid = zid_of(kZid);
  CHECK(encoded([&](Writer& w) {
          return encode_init_ack(w, zid, whatami::Peer, 0x0A, 49152, {cookie.data(), cookie.size()});
        }) == init_ack);

  const Buf open_ack = hex("620ac1dbd452");
  Recorder o;
  REQUIRE(decode(open_ack, o) == nullptr);
  REQUIRE(o.opens.size() == 1);
  CHECK(o.opens[0].ack);
  CHECK(o.opens[0].lease_ms == 10000);
  CHECK(o.opens[0].initial_sn == 173354433);
  CHECK(encoded([](Writer& w) { return encode_open_ack(w, 10000, 173354433); }) == open_ack);
}

TEST_CASE("KeepAlive and Close (§4.5, §4.6)") {
  CHECK(encoded([](Writer& w) { return encode_keep_alive(w); }) == hex("04"));
  CHECK(encoded([](Writer& w) { return encode_close(w, true, close_reason::Generic); }) == hex("2300"));
  Recorder r;
  REQUIRE(decode(hex("0300"), r) == nullptr);  // what a closing Python session sent
  REQUIRE(r.closes.size() == 1);
  CHECK_FALSE(r.closes[0].whole_session);
  CHECK(r.closes[0].reason == close_reason::Generic);
  Recorder k;
  REQUIRE(decode(hex("04 04"), k) == nullptr);
  CHECK(k.keep_alives == 2);
}

TEST_CASE("Push/Put from the peer: string key, sender mapping, encoding (§7.1)") {
  const Buf payload = counting(100);
  const Buf batch = cat({hex("25 07"), hex("7d 00 09"), text("rvd/state"), hex("41 06 64"), payload});
  Recorder r;
  REQUIRE(decode(batch, r) == nullptr);
  REQUIRE(r.frames.size() == 1);
  CHECK(r.frames[0].reliable);
  CHECK(r.frames[0].sn == 7);
  REQUIRE(r.nets.size() == 1);
  const NetworkMsg& m = r.nets[0];
  CHECK(m.mid == nmid::Push);
  CHECK(m.wire.scope == 0);
  CHECK(m.wire.sender_mapping);
  CHECK(r.keys[0] == "rvd/state");
  CHECK(m.data.mid == dmid::Put);
  CHECK(m.data.has_encoding);
  CHECK(m.data.encoding.id == 3);  // application/octet-stream
  CHECK_FALSE(m.data.has_timestamp);
  CHECK(r.payloads[0] == std::string(payload.begin(), payload.end()));
  CHECK_FALSE(r.view_escaped);
}

TEST_CASE("Push/Put from the client encodes to the captured bytes (§7.1)") {
  const Buf p16 = counting(16), p20 = counting(20, 100);
  PutFields f;
  f.payload = p16.data();
  f.size = p16.size();
  CHECK(encoded([&](Writer& w) { return encode_push_put(w, WireExpr{0, "rvd/cmd", false}, f); }) ==
        cat({hex("3d 00 07"), text("rvd/cmd"), hex("01 10"), p16}));
  Encoding json;
  json.id = 5;
  f.encoding = &json;
  f.payload = p20.data();
  f.size = p20.size();
  CHECK(encoded([&](Writer& w) { return encode_push_put(w, WireExpr{1, {}, true}, f); }) ==
        cat({hex("5d 01 41 0a 14"), p20}));
}

TEST_CASE("Router-stamped Put: timestamp and encoding with schema are parsed (§8.1)") {
  const uint64_t ntp = 0x6B1A2C3D4E5F6071ull;
  Timestamp ts;
  ts.ntp64 = ntp;
  ts.id = zid_of(kZid);
  Encoding enc;
  enc.id = 4;
  enc.schema = "utf-8";
  const Buf payload = text("stamped");
  PutFields f{&ts, &enc, payload.data(), payload.size()};
  const Buf push = encoded([&](Writer& w) { return encode_push_put(w, WireExpr{0, "rvd/x", true}, f); });
  CHECK(push[0] == 0x7d);
  // Put header 0x61 = Put|T|E, as the router sends it.
  CHECK(push[2 + 1 + 5] == 0x61);
  const Buf batch = cat({hex("25 00"), push});
  Recorder r;
  REQUIRE(decode(batch, r) == nullptr);
  REQUIRE(r.nets.size() == 1);
  const DataMsg& d = r.nets[0].data;
  CHECK(d.has_timestamp);
  CHECK(d.timestamp.ntp64 == ntp);
  CHECK(d.timestamp.id.size == 16);
  CHECK(std::memcmp(d.timestamp.id.bytes, kZid.data(), 16) == 0);
  CHECK(d.has_encoding);
  CHECK(d.encoding.id == 4);
  CHECK(d.encoding.schema == "utf-8");
  CHECK(r.payloads[0] == "stamped");
}

TEST_CASE("Declarations: client captures and the router's replies (§7.2)") {
  CHECK(encoded([](Writer& w) { return encode_declare_keyexpr(w, 1, WireExpr{0, "rvd/cmd", false}); }) ==
        cat({hex("1e 20 01 00 07"), text("rvd/cmd")}));
  CHECK(encoded([](Writer& w) { return encode_declare_subscriber(w, 1, WireExpr{0, "rvd/state", false}); }) ==
        cat({hex("1e 22 01 00 09"), text("rvd/state")}));
  // A subscription by our own declared id: M set, no suffix.
  CHECK(encoded([](Writer& w) { return encode_declare_subscriber(w, 3, WireExpr{7, {}, true}); }) ==
        hex("1e 42 03 07"));
  CHECK(encoded([](Writer& w) { return encode_undeclare_subscriber(w, 3); }) == hex("1e 03 03"));
  CHECK(encoded([](Writer& w) { return encode_declare_final(w, 9); }) == hex("3e 09 1a"));

  // Router answer to an Interest: Declare|I|Z (interest 9, QoS ext) + DeclareQueryable|N|M, then
  // DeclareFinal — two network messages in one frame.
  const Buf batch = cat({hex("25 01 be 09 21 08 64 01 00 0c"), text("rvd/q/server"), hex("be 09 21 08 1a")});
  Recorder r;
  REQUIRE(decode(batch, r) == nullptr);
  REQUIRE(r.nets.size() == 2);
  CHECK(r.nets[0].mid == nmid::Declare);
  CHECK(r.nets[0].has_interest_id);
  CHECK(r.nets[0].interest_id == 9);
  CHECK(r.nets[0].decl == declid::Queryable);
  CHECK(r.nets[0].decl_id == 1);
  CHECK(r.nets[0].wire.sender_mapping);
  CHECK(r.keys[0] == "rvd/q/server");
  CHECK(r.nets[1].decl == declid::Final);
  CHECK(r.nets[1].interest_id == 9);

  // DeclareKeyExpr from the remote, then UndeclareSubscriber carrying the 0x5F WireExpr extension.
  const Buf more = cat({hex("25 02 1e 20 05 00 07"), text("rvd/nav"), hex("1e 83 04 5f 04 03 00 ab cd")});
  Recorder k;
  REQUIRE(decode(more, k) == nullptr);
  REQUIRE(k.nets.size() == 2);
  CHECK(k.nets[0].decl == declid::KeyExpr);
  CHECK(k.nets[0].decl_id == 5);
  CHECK(k.keys[0] == "rvd/nav");
  CHECK(k.nets[1].decl == declid::UndeclareSubscriber);
  CHECK(k.nets[1].decl_id == 4);
}

TEST_CASE("Interest, Request, Response and ResponseFinal decode (§7.4-7.6)") {
  Recorder i;
  REQUIRE(decode(cat({hex("25 00 79 09 36 00 08"), text("rvd/q/**")}), i) == nullptr);
  REQUIRE(i.nets.size() == 1);
  CHECK(i.nets[0].mid == nmid::Interest);
  CHECK(i.nets[0].interest_mode == 3);
  CHECK(i.nets[0].interest_id == 9);
  CHECK(i.nets[0].interest_options == 0x36);
  CHECK(i.keys[0] == "rvd/q/**");

  // From the peer: QoS and timeout extensions, Query with consolidation and a body extension.
  Recorder q;
  REQUIRE(decode(cat({hex("25 00 fc 01 00 09"), text("rvd/q/raw"), hex("a1 0d 26 b817 a3 03 43 08 00"),
                      text("PYQUERY")}),
                 q) == nullptr);
  REQUIRE(q.nets.size() == 1);
  CHECK(q.nets[0].mid == nmid::Request);
  CHECK(q.nets[0].request_id == 1);
  CHECK(q.keys[0] == "rvd/q/raw");
  CHECK(q.nets[0].data.mid == dmid::Query);
  CHECK(q.nets[0].data.consolidation == 3);
  CHECK(q.payloads[0] == "PYQUERY");

  // Client get with parameters, target and timeout.
  Recorder g;
  REQUIRE(decode(cat({hex("25 00 bc 01 00 07"), text("rvd/q/*"), hex("b4 01 26 d00f 43 07"), text("a=1;b=2")}),
                 g) == nullptr);
  REQUIRE(g.nets.size() == 1);
  CHECK(g.params[0] == "a=1;b=2");

  // Response + ResponseFinal in one frame (client answer), then the peer's with ResponderId.
  const Buf client = cat({hex("3b 01 00 09"), text("rvd/q/raw"), hex("04 41 08 10"), text("RAWREPLY:PYQUERY"),
                          hex("1a 01")});
  const Buf peer = cat({hex("fb 00 00 0c"), text("rvd/q/server"), hex("43 12 f0"), kZid, hex("07 04 41 08 11"),
                        text("SRVREPLY:RAWQUERY"), hex("1a 00")});
  Recorder r;
  REQUIRE(decode(cat({hex("25 00"), client, hex("25 01"), peer}), r) == nullptr);
  CHECK(r.frames.size() == 2);
  REQUIRE(r.nets.size() == 4);
  CHECK(r.nets[0].mid == nmid::Response);
  CHECK(r.nets[0].data.encoding.id == 4);
  CHECK(r.payloads[0] == "RAWREPLY:PYQUERY");
  CHECK(r.nets[1].mid == nmid::ResponseFinal);
  CHECK(r.nets[1].request_id == 1);
  CHECK(r.payloads[2] == "SRVREPLY:RAWQUERY");
  CHECK(r.nets[3].request_id == 0);
  CHECK(encoded([](Writer& w) { return encode_response_final(w, 1); }) == hex("1a 01"));
}

TEST_CASE("Several transport messages per batch; a frame ends at the next transport MID (§3)") {
  const Buf push_a = cat({hex("3d 00 01"), text("a"), hex("01 01 61")});
  const Buf push_b = cat({hex("3d 00 01"), text("b"), hex("01 01 62")});
  // Best-effort frame with one push, reliable frame with two, a KeepAlive, then a fragment.
  const Buf batch = cat({hex("05 10"), push_a, hex("25 20"), push_b, push_a, hex("04"), hex("e6 21 02"),
                         text("tail")});
  Recorder r;
  REQUIRE(decode(batch, r) == nullptr);
  REQUIRE(r.frames.size() == 2);
  CHECK_FALSE(r.frames[0].reliable);
  CHECK(r.frames[0].sn == 0x10);
  CHECK(r.frames[1].reliable);
  REQUIRE(r.nets.size() == 3);
  CHECK(r.payloads == std::vector<std::string>{"a", "b", "a"});
  CHECK(r.keep_alives == 1);
  REQUIRE(r.fragments.size() == 1);
  const FragmentMsg& f = r.fragments[0];
  CHECK(f.reliable);
  CHECK(f.more);
  CHECK(f.first);
  CHECK_FALSE(f.drop);
  CHECK(f.sn == 0x21);
  CHECK(std::string(f.body.str()) == "tail");
  CHECK(encoded([](Writer& w) { return encode_fragment_header(w, true, true, 0x21, true); }) == hex("e6 21 02"));
}

TEST_CASE("Writer refuses what does not fit and rewinds") {
  uint8_t buf[8];
  Writer w(buf, sizeof buf);
  const Buf p = counting(16);
  PutFields f;
  f.payload = p.data();
  f.size = p.size();
  CHECK_FALSE(encode_push_put(w, WireExpr{0, "k", false}, f));
  CHECK_FALSE(w.ok());
  w.rewind(0);
  CHECK(w.ok());
  CHECK(encode_keep_alive(w));
  CHECK(w.size() == 1);
}

TEST_CASE("SN arithmetic: masks per resolution and the precedes window (§6)") {
  CHECK(sn_mask(0) == 0x7F);
  CHECK(sn_mask(1) == 0x3FFF);
  CHECK(sn_mask(2) == 0x0FFFFFFF);
  CHECK(sn_mask(3) == 0x7FFFFFFFFFFFFFFFull);
  const uint64_t m = sn_mask(2);
  CHECK(sn_precedes(5, 6, m));
  CHECK(sn_precedes(5, 7, m));  // a skipped SN is accepted (Rust skips one before fragments)
  CHECK_FALSE(sn_precedes(5, 5, m));
  CHECK_FALSE(sn_precedes(6, 5, m));
  CHECK(sn_precedes(m, 0, m));  // wrap-around
  CHECK(sn_precedes(m - 1, 3, m));
  CHECK_FALSE(sn_precedes(0, m, m));
  CHECK(sn_precedes(0, m / 2, m));
  CHECK_FALSE(sn_precedes(0, m / 2 + 1, m));
}

TEST_CASE("Key expressions: validation and wildcard matching") {
  for (const char* ok : {"rvd/run1/nav", "a", "rvd/*/nav", "rvd/**", "**", "a/b$*/c", "a/*/**"}) {
    CHECK_MESSAGE(check_keyexpr(ok, true) == nullptr, ok);
  }
  for (const char* bad : {"", "/a", "a/", "a//b", "a/b#", "a?b", "a*", "a/$", "a/**/**", "a/**/*", "$*"}) {
    CHECK_MESSAGE(check_keyexpr(bad, true) != nullptr, bad);
  }
  CHECK(check_keyexpr("rvd/run1/nav", false) == nullptr);
  CHECK(check_keyexpr("rvd/*/nav", false) != nullptr);
  CHECK(check_keyexpr("rvd/n$*", false) != nullptr);

  CHECK(keyexpr_matches("rvd/run1/nav", "rvd/run1/nav"));
  CHECK_FALSE(keyexpr_matches("rvd/run1/nav", "rvd/run1/navx"));
  CHECK(keyexpr_matches("rvd/*/nav", "rvd/run1/nav"));
  CHECK_FALSE(keyexpr_matches("rvd/*/nav", "rvd/a/b/nav"));
  CHECK_FALSE(keyexpr_matches("rvd/*", "rvd"));
  CHECK(keyexpr_matches("rvd/**", "rvd"));
  CHECK(keyexpr_matches("rvd/**", "rvd/a/b/c"));
  CHECK(keyexpr_matches("**", "x/y"));
  CHECK(keyexpr_matches("a/**/c", "a/c"));
  CHECK(keyexpr_matches("a/**/c", "a/b/d/c"));
  CHECK_FALSE(keyexpr_matches("a/**/c", "a/b/d"));
  CHECK(keyexpr_matches("rvd/n$*", "rvd/nav"));
  CHECK(keyexpr_matches("rvd/n$*v", "rvd/nav"));
  CHECK(keyexpr_matches("rvd/$*av", "rvd/nav"));
  CHECK_FALSE(keyexpr_matches("rvd/n$*x", "rvd/nav"));
}

TEST_CASE("Fuzz: random, truncated and bit-flipped batches never escape the buffer") {
  const Buf cookie = counting(49);
  const std::vector<Buf> valid = {
      cat({hex("6109f1"), kZid, hex("0a00c0 31"), cookie}),
      hex("620ac1dbd452"),
      cat({hex("25 07 7d 00 09"), text("rvd/state"), hex("41 06 64"), counting(100)}),
      cat({hex("25 01 be 09 21 08 64 01 00 0c"), text("rvd/q/server"), hex("be 09 21 08 1a")}),
      cat({hex("25 00 fc 01 00 09"), text("rvd/q/raw"), hex("a1 0d 26 b817 a3 03 43 08 00"), text("PYQUERY")}),
      cat({hex("25 00 3b 01 00 09"), text("rvd/q/raw"), hex("04 41 08 10"), text("RAWREPLY:PYQUERY"), hex("1a 01")}),
      cat({hex("25 00 79 09 36 00 08"), text("rvd/q/**")}),
      cat({hex("e6 21 02"), text("tail")}),
  };
  // A strict prefix of a valid batch never decodes cleanly into all of its messages: truncation
  // is detected (a Fragment is the exception: its body runs to the end of whatever batch it is in).
  for (const Buf& v : valid) {
    Recorder full;
    REQUIRE(decode(v, full) == nullptr);
    const size_t messages = full.nets.size() + full.inits.size() + full.opens.size();
    for (size_t n = 1; n < v.size(); ++n) {
      const Buf cut(v.begin(), v.begin() + static_cast<long>(n));
      Recorder r;
      const char* err = decode(cut, r);
      CHECK_FALSE(r.view_escaped);
      if (!full.fragments.empty()) continue;
      const size_t got = r.nets.size() + r.inits.size() + r.opens.size();
      CHECK_FALSE((err == nullptr && got == messages));
    }
  }
  std::mt19937 rng(12345);
  size_t errors = 0, runs = 0;
  for (int round = 0; round < 20000; ++round) {
    Buf b;
    if (round % 2 == 0) {
      b.resize(rng() % 64);
      for (auto& x : b) x = static_cast<uint8_t>(rng());
    } else {
      b = valid[rng() % valid.size()];
      const int flips = 1 + rng() % 4;
      for (int k = 0; k < flips; ++k) b[rng() % b.size()] ^= static_cast<uint8_t>(1u << (rng() % 8));
    }
    Recorder r;
    errors += decode(b, r) != nullptr;
    ++runs;
    REQUIRE_FALSE(r.view_escaped);
  }
  // Random bytes are mostly rejected, and the decoder neither crashed nor read out of bounds.
  CHECK(errors > runs / 4);
}
