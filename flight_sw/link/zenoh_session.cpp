// The flight-side Zenoh client session (see zenoh_session.hpp). Section numbers (§) refer to the
// Zenoh wire summary in flight_sw/link/README.md.
#include "flight_sw/link/zenoh_session.hpp"

#include <sys/random.h>
#include <unistd.h>

#include <algorithm>
#include <ctime>
#include <thread>

#include "flight_sw/link/zenoh_keyexpr.hpp"

namespace rvd::link {

using namespace zenoh;

namespace {

constexpr uint8_t kResolution32 = 0x0A;  // fsn 32 bit, request id 32 bit (§4.1)
constexpr uint64_t kPatch = 1;           // asks for First/Drop markers on fragments (§4.8)
constexpr size_t kMaxRemoteKeyExprs = 1024;
constexpr uint16_t kMinBatch = 64;

using Clock = std::chrono::steady_clock;

// Seed for the ZenohIDs and initial SNs: unique, not secret. std::random_device would block in
// getrandom() until the kernel's entropy pool is initialised, seconds on a freshly booted flight
// computer (or an emulated one) without a hardware RNG; GRND_INSECURE never blocks.
uint64_t session_seed() {
  uint64_t seed = 0;
#ifdef GRND_INSECURE
  if (::getrandom(&seed, sizeof seed, GRND_INSECURE) == static_cast<ssize_t>(sizeof seed)) return seed;
#endif
  if (::getrandom(&seed, sizeof seed, GRND_NONBLOCK) == static_cast<ssize_t>(sizeof seed)) return seed;
  timespec t{};  // kernels before 5.6 early in boot: time and pid still tell two sessions apart
  clock_gettime(CLOCK_REALTIME, &t);
  return (static_cast<uint64_t>(t.tv_sec) * 1000000000ull + static_cast<uint64_t>(t.tv_nsec)) ^
         (static_cast<uint64_t>(::getpid()) << 40);
}

// Milliseconds until `t`, rounded up so that a wait never ends just before its deadline.
int ms_until(Clock::time_point t) {
  const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(t - Clock::now()).count();
  if (ns <= 0) return 0;
  const long long ms = (ns + 999999) / 1000000;
  return ms > 1000000000 ? 1000000000 : static_cast<int>(ms);
}

// Collects the replies of one handshake step; stops at the awaited message, a Close or anything
// else (which fails the handshake).
struct HandshakeHandler : BatchHandler {
  explicit HandshakeHandler(bool open_step) : want_open(open_step) {}
  bool want_open;
  bool got = false, got_close = false, unexpected = false;
  InitMsg init;
  OpenMsg open;
  CloseMsg close;
  void on_init(const InitMsg& m) override {
    init = m;
    if (!want_open && m.ack) {
      got = true;
    } else {
      unexpected = true;
    }
  }
  void on_open(const OpenMsg& m) override {
    open = m;
    if (want_open && m.ack) {
      got = true;
    } else {
      unexpected = true;
    }
  }
  void on_close(const CloseMsg& m) override {
    close = m;
    got_close = true;
  }
  bool on_frame(const FrameHeader&) override {
    unexpected = true;
    return false;
  }
  void on_fragment(const FragmentMsg&) override { unexpected = true; }
  bool stop() const override { return got || got_close || unexpected; }
};

}  // namespace

// Routes the messages of a batch received on an open session.
class ZenohSession::Dispatcher : public BatchHandler {
 public:
  explicit Dispatcher(ZenohSession& s) : s_(s) {}
  int parsed = 0;  // transport messages of the batch that decoded (whatever their content)
  void on_oam() override { ++parsed; }
  void on_init(const InitMsg&) override {
    ++parsed;
    s_.reject("Init received on an open session");
  }
  void on_open(const OpenMsg&) override {
    ++parsed;
    s_.reject("Open received on an open session");
  }
  void on_close(const CloseMsg& m) override {
    ++parsed;
    s_.lost(LinkStatus::LinkLost, std::string("remote sent Close(reason ") +
                                      std::to_string(m.reason) +
                                      (m.whole_session ? ", session)" : ", link)"));
  }
  void on_keep_alive() override {
    ++parsed;
    ++s_.stats_.keepalives_rx;
  }
  bool on_frame(const FrameHeader& f) override {
    ++parsed;
    ++s_.stats_.frames_rx;
    Channel& c = f.reliable ? s_.rx_reliable_ : s_.rx_best_effort_;
    if (!sn_precedes(c.last_sn, f.sn, s_.info_.sn_mask)) {  // a duplicate or stale frame (§6)
      ++s_.stats_.rx_sn_dropped;
      return false;
    }
    c.last_sn = f.sn;
    return true;
  }
  void on_network(const NetworkMsg& m) override { s_.handle_network(m); }
  void on_fragment(const FragmentMsg& f) override {
    ++parsed;
    s_.handle_fragment(f);
  }
  bool stop() const override { return s_.state_ != State::Connected; }

 private:
  ZenohSession& s_;
};

ZenohSession::ZenohSession(ZenohConfig config)
    : config_(std::move(config)),
      tx_(TcpLink::kPrefixSize + TcpLink::kMaxBatch),
      rng_(config_.seed ? config_.seed : session_seed()) {
  key_scratch_.reserve(256);
}

ZenohSession::~ZenohSession() {
  in_callback_ = false;
  close();
}

const char* ZenohSession::check_config() const {
  TcpEndpoint ep;
  if (const char* e = parse_tcp_endpoint(config_.endpoint, ep)) return e;
  if (!ep.semihosting_dir.empty() && !config_.untimed)
    return "a semihosting endpoint cannot time out: it needs untimed waits (--untimed-link)";
  if (config_.lease_ms < 10) return "lease_ms must be at least 10 ms";
  if (config_.batch_size < kMinBatch) return "batch_size must be at least 64 bytes";
  if (config_.connect_timeout_ms <= 0 || config_.send_timeout_ms <= 0)
    return "connect_timeout_ms and send_timeout_ms must be positive";
  if (config_.reconnect.first_delay_ms < 0 || config_.reconnect.max_delay_ms < 0 ||
      config_.reconnect.max_attempts < 0)
    return "reconnect delays and max_attempts must not be negative";
  if (config_.resync_after_unparsed < 1 || config_.rx_stall_ms <= 0)
    return "resync_after_unparsed and rx_stall_ms must be positive";
  return nullptr;
}

// ---- connection and handshake (§5) ----------------------------------------------------------

LinkStatus ZenohSession::open() {
  if (in_callback_) return LinkStatus::Busy;
  if (state_ == State::Connected) return LinkStatus::Ok;
  if (const char* e = check_config()) {
    last_error_ = e;
    return LinkStatus::InvalidArgument;
  }
  close_requested_ = false;
  attempts_ = 0;
  next_delay_ms_ = config_.reconnect.first_delay_ms;
  const LinkStatus s = connect_and_handshake();
  if (s == LinkStatus::Ok || state_ == State::Connected) return s;
  if (config_.reconnect.enabled) {
    state_ = State::Reconnecting;
    schedule_retry();
  } else {
    state_ = State::Idle;
  }
  return s;
}

LinkStatus ZenohSession::handshake_receive(BatchHandler& handler, const char* waiting_for,
                                           const uint8_t*& rest, size_t& rest_size) {
  const Clock::time_point deadline =
      Clock::now() + std::chrono::milliseconds(config_.connect_timeout_ms);
  rest = nullptr;
  rest_size = 0;
  while (!handler.stop()) {
    const uint8_t* data = nullptr;
    size_t size = 0;
    std::string err;
    const LinkStatus s = link_.receive_batch(data, size, config_.untimed ? -1 : ms_until(deadline), &err);
    if (s == LinkStatus::Timeout) {
      last_error_ = std::string("no ") + waiting_for + " within " +
                    std::to_string(config_.connect_timeout_ms) + " ms";
      return LinkStatus::HandshakeFailed;
    }
    if (s != LinkStatus::Ok) {
      last_error_ = std::string("waiting for ") + waiting_for + ": " + err;
      return LinkStatus::HandshakeFailed;
    }
    ++stats_.batches_rx;
    stats_.bytes_rx += size;
    size_t used = 0;
    if (const char* e = decode_batch(data, size, handler, &used)) {
      last_error_ = std::string("malformed ") + waiting_for + ": " + e;
      return LinkStatus::HandshakeFailed;
    }
    rest = data + used;
    rest_size = size - used;
  }
  return LinkStatus::Ok;
}

LinkStatus ZenohSession::connect_and_handshake() {
  TcpEndpoint endpoint;
  if (const char* e = parse_tcp_endpoint(config_.endpoint, endpoint)) {
    last_error_ = e;
    return LinkStatus::InvalidArgument;
  }
  std::string err;
  if (link_.connect(endpoint, link_timeout_ms(config_.connect_timeout_ms), &err) != LinkStatus::Ok) {
    last_error_ = err;
    return LinkStatus::ConnectFailed;
  }
  auto fail = [&](const std::string& why) {
    last_error_ = why;
    link_.close();
    return LinkStatus::HandshakeFailed;
  };
  auto refused = [&](const CloseMsg& c) {
    return fail("remote refused the session: Close(reason " + std::to_string(c.reason) + ")");
  };

  // A fresh ZenohID per connection: the remote never resumes a client's session (§9).
  info_ = ZenohLinkInfo{};
  zid_ = Zid{};
  zid_.size = 16;
  for (auto& b : zid_.bytes) b = static_cast<uint8_t>(rng_());
  if (zid_.bytes[15] == 0) zid_.bytes[15] = 1;
  info_.local_zid = zid_;

  // InitSyn: our ZID, 32-bit SNs, the proposed batch size, patch 1 (§4.1).
  Writer w(tx_.data() + TcpLink::kPrefixSize, TcpLink::kMaxBatch);
  encode_init_syn(w, zid_, kResolution32, config_.batch_size, true, kPatch);
  if (link_.send_batch(tx_.data(), w.size(), link_timeout_ms(config_.send_timeout_ms), &err) != LinkStatus::Ok)
    return fail("sending InitSyn: " + err);
  const uint8_t* rest = nullptr;
  size_t rest_size = 0;
  HandshakeHandler init_step(false);
  if (handshake_receive(init_step, "InitAck", rest, rest_size) != LinkStatus::Ok)
    return fail(last_error_);
  if (init_step.got_close) return refused(init_step.close);
  if (!init_step.got) return fail("expected InitAck, received another message");
  const InitMsg& ack = init_step.init;
  if (ack.version != kProtocolVersion)
    return fail("remote speaks protocol version " + std::to_string(ack.version));
  if (ack.whatami != whatami::Router && ack.whatami != whatami::Peer)
    return fail("remote is neither a router nor a peer");

  // Adopt the remote's batch size and SN resolution (§4.2).
  info_.batch_size = std::min<uint16_t>(config_.batch_size, ack.has_size ? ack.batch_size : 65535);
  if (info_.batch_size < kMinBatch)
    return fail("remote batch size " + std::to_string(info_.batch_size) + " is too small");
  info_.sn_mask = sn_mask(ack.has_size ? ack.resolution : kResolution32);
  info_.remote_whatami = ack.whatami;
  info_.remote_zid = ack.zid;
  info_.fragment_markers = ack.has_patch && ack.patch >= 1;
  const uint64_t initial_sn = rng_() & info_.sn_mask;

  // OpenSyn echoes the cookie byte for byte (§4.3); it still lives in the link's buffer.
  Writer w2(tx_.data() + TcpLink::kPrefixSize, TcpLink::kMaxBatch);
  if (!encode_open_syn(w2, config_.lease_ms, initial_sn, ack.cookie))
    return fail("cookie too large for one batch");
  if (link_.send_batch(tx_.data(), w2.size(), link_timeout_ms(config_.send_timeout_ms), &err) != LinkStatus::Ok)
    return fail("sending OpenSyn: " + err);
  HandshakeHandler open_step(true);
  if (handshake_receive(open_step, "OpenAck", rest, rest_size) != LinkStatus::Ok)
    return fail(last_error_);
  if (open_step.got_close) return refused(open_step.close);
  if (!open_step.got) return fail("expected OpenAck, received another message");
  if (open_step.open.lease_ms == 0) return fail("remote announced a zero lease");
  info_.remote_lease_ms = open_step.open.lease_ms;

  // Both RX channels start just before the remote's initial SN, our TX at ours (§6).
  const uint64_t before_first = (open_step.open.initial_sn - 1) & info_.sn_mask;
  for (Channel* c : {&rx_reliable_, &rx_best_effort_}) {
    c->last_sn = before_first;
    c->fragments.active = c->fragments.overflow = c->fragments.skipping = false;
  }
  tx_sn_ = initial_sn;
  remote_keyexprs_.clear();
  state_ = State::Connected;
  last_rx_ = last_tx_ = Clock::now();
  unparsed_in_row_ = 0;
  ++stats_.connects;

  // Declarations first, then whatever followed the OpenAck in its batch.
  const LinkStatus s = send_declarations();
  if (s != LinkStatus::Ok) return s;
  if (rest_size > 0) {
    Dispatcher d(*this);
    if (const char* e = decode_batch(rest, rest_size, d)) reject(e);
  }
  return state_ == State::Connected ? LinkStatus::Ok : LinkStatus::LinkLost;
}

void ZenohSession::schedule_retry() {
  ++attempts_;
  const ReconnectPolicy& p = config_.reconnect;
  if (p.max_attempts > 0 && attempts_ >= p.max_attempts) {
    state_ = State::GaveUp;
    return;
  }
  next_attempt_ = Clock::now() + std::chrono::milliseconds(next_delay_ms_);
  next_delay_ms_ = std::min(std::max(1, next_delay_ms_ * 2), std::max(p.max_delay_ms, 1));
}

LinkStatus ZenohSession::send_declaration(const Writer& w) {
  // A declaration that could not be written leaves the remote's view and ours different: drop
  // the link instead, so that the reconnect re-sends every declaration.
  const LinkStatus s = send_frame(w);
  return s == LinkStatus::Timeout ? lost(LinkStatus::LinkLost, last_error_) : s;
}

LinkStatus ZenohSession::lost(LinkStatus why, const std::string& detail) {
  if (state_ != State::Connected) return why;
  link_.close();
  ++stats_.link_losses;
  if (why == LinkStatus::LeaseExpired) ++stats_.lease_expirations;
  last_error_ = detail;
  remote_keyexprs_.clear();
  if (config_.reconnect.enabled) {
    state_ = State::Reconnecting;
    attempts_ = -1;  // the wait before the first attempt is not a failed attempt
    next_delay_ms_ = config_.reconnect.first_delay_ms;
    schedule_retry();
  } else {
    state_ = State::Idle;
  }
  return why;
}

void ZenohSession::close() {
  if (in_callback_) {
    close_requested_ = true;
    return;
  }
  if (state_ == State::Connected) {
    Writer w(tx_.data() + TcpLink::kPrefixSize, batch_room());
    encode_close(w, true, close_reason::Generic);  // §4.6: `23 00`, then shut the socket
    std::string ignored;
    link_.send_batch(tx_.data(), w.size(), std::min(config_.send_timeout_ms, 200), &ignored);
  }
  link_.close();
  state_ = State::Closed;
  close_requested_ = false;
}

// ---- sending ------------------------------------------------------------------------------

size_t ZenohSession::batch_room() const {
  // Rust counts the u16 length prefix inside the batch size on stream links (its batch buffer of
  // batch_size bytes starts with the length): a 2047-byte batch under a 2048 batch size made
  // eclipse-zenoh 1.10.2 drop the link. So prefix + batch <= batch_size.
  const size_t size = state_ == State::Connected ? info_.batch_size : config_.batch_size;
  return size - TcpLink::kPrefixSize;
}

Writer ZenohSession::frame_writer() {
  Writer w(tx_.data() + TcpLink::kPrefixSize, batch_room());
  encode_frame_header(w, true, tx_sn_);  // reliable: Rust sends its data the same way (§4.7)
  return w;
}

LinkStatus ZenohSession::send_batch(size_t batch_bytes) {
  std::string err;
  const LinkStatus s = link_.send_batch(tx_.data(), batch_bytes, link_timeout_ms(config_.send_timeout_ms), &err);
  if (s == LinkStatus::Ok) {
    last_tx_ = Clock::now();
    ++stats_.batches_tx;
    stats_.bytes_tx += batch_bytes;
    return s;
  }
  if (s == LinkStatus::Timeout) {
    last_error_ = err;
    return s;
  }
  return lost(LinkStatus::LinkLost, err);
}

LinkStatus ZenohSession::send_frame(const Writer& w) {
  const LinkStatus s = send_batch(w.size());
  if (s == LinkStatus::Ok) {
    tx_sn_ = (tx_sn_ + 1) & info_.sn_mask;  // each Frame uses one SN (§6)
    ++stats_.frames_tx;
  }
  return s;
}

WireExpr ZenohSession::wire_for(std::string_view key) const {
  for (const KeyExprEntry& e : own_keyexprs_) {
    if (e.key == key) return WireExpr{e.id, {}, true};  // sender mapping: our own id (§7.3)
  }
  return WireExpr{0, key, false};
}

LinkStatus ZenohSession::send_declarations() {
  // Key expressions before the subscriptions that may use them, packed into as few frames as fit.
  Writer w = frame_writer();
  const size_t header = w.size();
  size_t i = 0, n = own_keyexprs_.size() + subscribers_.size();
  while (i < n) {
    const size_t mark = w.size();
    bool ok;
    if (i < own_keyexprs_.size()) {
      const KeyExprEntry& k = own_keyexprs_[i];
      ok = encode_declare_keyexpr(w, k.id, WireExpr{0, k.key, false});
    } else {
      const Subscriber& sub = subscribers_[i - own_keyexprs_.size()];
      ok = encode_declare_subscriber(w, sub.id, wire_for(sub.key));
    }
    if (ok) {
      ++i;
      continue;
    }
    w.rewind(mark);
    if (mark == header) {  // a single declaration larger than a batch: cannot be sent at all
      last_error_ = "a declaration does not fit one batch";
      return LinkStatus::MessageTooLarge;
    }
    const LinkStatus s = send_declaration(w);
    if (s != LinkStatus::Ok) return s;
    w = frame_writer();
  }
  return w.size() > header ? send_declaration(w) : LinkStatus::Ok;
}

size_t ZenohSession::max_put_payload(std::string_view key, const PutOptions& options) const {
  // Exact for the next put while connected (its SN is known); the worst case before that.
  const uint64_t sn = state_ == State::Connected ? tx_sn_ : sn_mask(kResolution32);
  const WireExpr wire = wire_for(key);
  size_t overhead = 1 + vle_size(sn) + 1 + vle_size(wire.scope) + 1;  // frame, push, put headers
  if (!wire.suffix.empty()) overhead += vle_size(wire.suffix.size()) + wire.suffix.size();
  if (options.has_encoding) overhead += vle_size(static_cast<uint64_t>(options.encoding_id) << 1);
  const size_t room = batch_room();
  if (overhead + 1 >= room) return 0;
  size_t p = room - overhead - 1;
  while (p > 0 && overhead + vle_size(p) + p > room) --p;
  return p;
}

LinkStatus ZenohSession::put(std::string_view key, const uint8_t* data, size_t size,
                             const PutOptions& options) {
  if (state_ != State::Connected) {
    if (state_ == State::Reconnecting) return LinkStatus::Reconnecting;
    return state_ == State::GaveUp ? LinkStatus::ReconnectExhausted : LinkStatus::NotConnected;
  }
  if (const char* e = check_keyexpr(key, false)) {
    last_error_ = e;
    return LinkStatus::InvalidArgument;
  }
  if (!data && size > 0) {
    last_error_ = "put: null payload with a non-zero size";
    return LinkStatus::InvalidArgument;
  }
  Writer w = frame_writer();
  Encoding encoding;
  encoding.id = options.encoding_id;
  PutFields fields;
  fields.encoding = options.has_encoding ? &encoding : nullptr;
  fields.payload = data;
  fields.size = size;
  if (!encode_push_put(w, wire_for(key), fields)) {
    last_error_ = "put of " + std::to_string(size) + " bytes on '" + std::string(key) +
                  "' does not fit one batch (" + std::to_string(info_.batch_size) +
                  " bytes with the length prefix; payload at most " +
                  std::to_string(max_put_payload(key, options)) +
                  "); this client never fragments its sends";
    return LinkStatus::MessageTooLarge;
  }
  const LinkStatus s = send_frame(w);
  if (s == LinkStatus::Ok) ++stats_.puts_tx;
  return s;
}

void ZenohSession::service_keep_alive() {
  const auto interval = std::chrono::milliseconds(std::max<uint32_t>(1, config_.lease_ms / 4));
  if (Clock::now() - last_tx_ < interval) return;
  Writer w(tx_.data() + TcpLink::kPrefixSize, batch_room());
  encode_keep_alive(w);  // §4.5: a lone `04`
  if (send_batch(w.size()) == LinkStatus::Ok) ++stats_.keepalives_tx;
}

// ---- declarations -------------------------------------------------------------------------

LinkStatus ZenohSession::declare_keyexpr(std::string key, uint16_t* id) {
  if (in_callback_) return LinkStatus::Busy;
  if (const char* e = check_keyexpr(key, true)) {
    last_error_ = e;
    return LinkStatus::InvalidArgument;
  }
  for (const KeyExprEntry& e : own_keyexprs_) {
    if (e.key == key) {
      if (id) *id = e.id;
      return LinkStatus::Ok;
    }
  }
  if (own_keyexprs_.size() >= 0xFFFF) {
    last_error_ = "no key expression id left";
    return LinkStatus::InvalidArgument;
  }
  const uint16_t new_id = static_cast<uint16_t>(own_keyexprs_.size() + 1);
  own_keyexprs_.push_back({new_id, std::move(key)});
  if (id) *id = new_id;
  if (state_ != State::Connected) return LinkStatus::Ok;
  Writer w = frame_writer();
  if (!encode_declare_keyexpr(w, new_id, WireExpr{0, own_keyexprs_.back().key, false})) {
    own_keyexprs_.pop_back();
    last_error_ = "key expression too long for one batch";
    return LinkStatus::MessageTooLarge;
  }
  return send_declaration(w);  // kept even when this fails: a reconnect re-declares it
}

LinkStatus ZenohSession::declare_subscriber(std::string key, SampleCallback callback,
                                            uint32_t* id) {
  if (in_callback_) return LinkStatus::Busy;
  if (const char* e = check_keyexpr(key, true)) {
    last_error_ = e;
    return LinkStatus::InvalidArgument;
  }
  if (!callback) {
    last_error_ = "declare_subscriber: empty callback";
    return LinkStatus::InvalidArgument;
  }
  const uint32_t sid = next_subscriber_id_++;
  subscribers_.push_back({sid, std::move(key), std::move(callback)});
  if (id) *id = sid;
  if (state_ != State::Connected) return LinkStatus::Ok;
  Writer w = frame_writer();
  if (!encode_declare_subscriber(w, sid, wire_for(subscribers_.back().key))) {
    subscribers_.pop_back();
    last_error_ = "key expression too long for one batch";
    return LinkStatus::MessageTooLarge;
  }
  return send_declaration(w);
}

LinkStatus ZenohSession::undeclare_subscriber(uint32_t id) {
  if (in_callback_) return LinkStatus::Busy;
  auto it = std::find_if(subscribers_.begin(), subscribers_.end(),
                         [id](const Subscriber& s) { return s.id == id; });
  if (it == subscribers_.end()) {
    last_error_ = "no subscriber with id " + std::to_string(id);
    return LinkStatus::InvalidArgument;
  }
  subscribers_.erase(it);
  if (state_ != State::Connected) return LinkStatus::Ok;
  Writer w = frame_writer();
  encode_undeclare_subscriber(w, id);
  return send_declaration(w);
}

// ---- receiving ----------------------------------------------------------------------------

LinkStatus ZenohSession::poll(int timeout_ms) {
  if (in_callback_) return LinkStatus::Busy;
  const bool unlimited = timeout_ms < 0;
  const Clock::time_point deadline =
      unlimited ? Clock::time_point::max() : Clock::now() + std::chrono::milliseconds(timeout_ms);
  switch (state_) {
    case State::Idle:
    case State::Closed: return LinkStatus::NotConnected;
    case State::GaveUp: return LinkStatus::ReconnectExhausted;
    case State::Reconnecting: {
      if (Clock::now() < next_attempt_) {
        std::this_thread::sleep_for(std::min(next_attempt_, deadline) - Clock::now());
        if (Clock::now() < next_attempt_) return LinkStatus::Reconnecting;
      }
      const LinkStatus s = connect_and_handshake();
      if (state_ != State::Connected) {
        schedule_retry();
        return state_ == State::GaveUp ? LinkStatus::ReconnectExhausted : s;
      }
      ++stats_.reconnects;
      attempts_ = 0;
      if (s != LinkStatus::Ok) return s;
      break;
    }
    case State::Connected: break;
  }

  const auto remote_lease = std::chrono::milliseconds(info_.remote_lease_ms);
  const auto keep_alive = std::chrono::milliseconds(std::max<uint32_t>(1, config_.lease_ms / 4));
  bool got = false;
  for (;;) {
    service_keep_alive();
    if (state_ != State::Connected) return LinkStatus::LinkLost;
    if (got && Clock::now() >= deadline) return LinkStatus::Ok;
    // Wake for the caller's deadline, the remote's lease and our next KeepAlive, whichever first
    // (untimed: only for the caller's deadline).
    int wait = 0;
    if (!got && config_.untimed) {
      wait = unlimited ? -1 : ms_until(deadline);
    } else if (!got) {
      wait = ms_until(std::min({deadline, last_rx_ + remote_lease, last_tx_ + keep_alive}));
    }
    const uint8_t* data = nullptr;
    size_t size = 0;
    std::string err;
    const int stall_ms = config_.untimed ? -1 : config_.rx_stall_ms;
    const LinkStatus s = link_.receive_batch(data, size, wait, &err, stall_ms);
    if (s == LinkStatus::Ok) {
      handle_batch(data, size);
      if (state_ == State::Closed) return LinkStatus::Ok;  // close() requested by a callback
      if (state_ != State::Connected) return LinkStatus::LinkLost;
      got = true;
      continue;
    }
    if (s != LinkStatus::Timeout) return lost(LinkStatus::LinkLost, err);
    const Clock::time_point now = Clock::now();
    if (stall_ms >= 0 && link_.pending_bytes() > 0 &&
        now - link_.pending_since() >= std::chrono::milliseconds(stall_ms)) {  // a batch that never completes
      return resync("a batch stayed incomplete for " + std::to_string(stall_ms) + " ms (" +
                    std::to_string(link_.pending_bytes()) + " bytes pending): corrupted length or stalled peer");
    }
    if (got) return LinkStatus::Ok;
    if (unlimited && config_.untimed) return LinkStatus::Timeout;  // a signal interrupted the wait
    if (!config_.untimed && now - last_rx_ >= remote_lease) {  // checked only after the socket was drained
      return lost(LinkStatus::LeaseExpired, "nothing received from the remote for its lease of " +
                                                std::to_string(info_.remote_lease_ms) + " ms");
    }
    if (now >= deadline) return LinkStatus::Timeout;
  }
}

LinkStatus ZenohSession::poll_until(const std::function<bool()>& done, int timeout_ms) {
  const Clock::time_point deadline =
      Clock::now() + std::chrono::milliseconds(std::max(0, timeout_ms));
  for (;;) {
    if (done()) return LinkStatus::Ok;
    const int left = ms_until(deadline);
    if (left <= 0) return LinkStatus::Timeout;
    const LinkStatus s = poll(left);
    if (done()) return LinkStatus::Ok;
    switch (s) {
      case LinkStatus::NotConnected:
      case LinkStatus::ReconnectExhausted:
      case LinkStatus::Busy:
      case LinkStatus::InvalidArgument: return s;
      default: break;
    }
  }
}

void ZenohSession::reject(const char* what) {
  ++stats_.rx_rejected;
  last_error_ = what;
}

LinkStatus ZenohSession::resync(const std::string& why) {
  if (state_ != State::Connected) return LinkStatus::LinkLost;
  ++stats_.resyncs;
  return lost(LinkStatus::LinkLost, "stream out of step, reconnecting: " + why);
}

void ZenohSession::handle_batch(const uint8_t* data, size_t size) {
  ++stats_.batches_rx;
  stats_.bytes_rx += size;
  Dispatcher d(*this);
  // A malformed message ends its batch (its length is unknown). Normally the TCP framing stays in
  // step; when batch after batch holds not one transport message, it is not: resynchronise.
  const char* e = decode_batch(data, size, d);
  if (e && state_ == State::Connected) reject(e);
  if (d.parsed > 0) {
    last_rx_ = Clock::now();
    unparsed_in_row_ = 0;
  } else if (e && ++unparsed_in_row_ >= config_.resync_after_unparsed) {
    resync(std::to_string(unparsed_in_row_) + " batches in a row without a transport message (last: " + e + ")");
  }
  if (close_requested_) close();
}

bool ZenohSession::resolve_key(const WireExpr& w, std::string_view& key, KeyMapping& mapping) {
  if (w.scope == 0) {
    key = w.suffix;
    mapping = KeyMapping::FullString;
    return !key.empty();
  }
  // §7.3: M = 1 names an id the sender declared, M = 0 one we declared.
  const std::vector<KeyExprEntry>& table = w.sender_mapping ? remote_keyexprs_ : own_keyexprs_;
  for (const KeyExprEntry& e : table) {
    if (e.id != w.scope) continue;
    mapping = w.sender_mapping ? KeyMapping::SenderId : KeyMapping::ReceiverId;
    if (w.suffix.empty()) {
      key = e.key;
    } else {
      key_scratch_.assign(e.key);
      key_scratch_.append(w.suffix);
      key = key_scratch_;
    }
    return true;
  }
  return false;
}

void ZenohSession::handle_network(const NetworkMsg& m) {
  switch (m.mid) {
    case nmid::Push: handle_push(m); return;
    case nmid::Declare: handle_declare(m); return;
    case nmid::Request: {
      // We declare no queryables, but a Request must still end with one ResponseFinal (§9),
      // or the remote's get() would wait for its timeout.
      Writer w = frame_writer();
      encode_response_final(w, m.request_id);
      if (send_frame(w) == LinkStatus::Ok) ++stats_.requests_answered;
      return;
    }
    case nmid::Interest: {
      // A Current interest expects DeclareFinal (§7.4). 1.10.2 sends none to clients; we answer
      // with DeclareFinal only (our subscriptions reach the remote through our own Declares).
      if (m.interest_mode & 0x01) {
        Writer w = frame_writer();
        encode_declare_final(w, m.interest_id);
        if (send_frame(w) == LinkStatus::Ok) ++stats_.interests_answered;
      }
      return;
    }
    default: return;  // Response, ResponseFinal, OAM: nothing for a publisher/subscriber client
  }
}

void ZenohSession::handle_push(const NetworkMsg& m) {
  Sample sample;
  if (!resolve_key(m.wire, sample.key, sample.mapping)) {
    reject(m.wire.scope == 0          ? "Push without a key"
           : m.wire.sender_mapping ? "Push with a key id the remote never declared"
                                   : "Push with a key id we never declared");
    return;
  }
  ++stats_.samples_rx;
  if (sample.mapping == KeyMapping::SenderId) ++stats_.rx_sender_mapped;
  if (sample.mapping == KeyMapping::ReceiverId) ++stats_.rx_receiver_mapped;
  const DataMsg& d = m.data;
  sample.is_delete = d.mid == dmid::Del;
  sample.payload = d.payload.data;
  sample.size = d.payload.size;
  sample.has_timestamp = d.has_timestamp;
  sample.timestamp = d.timestamp;
  sample.has_encoding = d.has_encoding;
  sample.encoding = d.encoding;
  in_callback_ = true;
  bool matched = false;
  for (const Subscriber& sub : subscribers_) {
    if (!keyexpr_matches(sub.key, sample.key)) continue;
    matched = true;
    try {
      sub.callback(sample);
    } catch (...) {  // a throwing callback must not take the link loop down with it
      ++stats_.callback_exceptions;
      last_error_ = "a subscriber callback threw on '" + std::string(sample.key) + "'";
    }
  }
  in_callback_ = false;
  if (!matched) ++stats_.rx_unmatched;  // e.g. a put on a wildcard key that intersects ours
}

void ZenohSession::handle_declare(const NetworkMsg& m) {
  if (m.decl == declid::KeyExpr) {
    std::string_view key;
    KeyMapping mapping;
    if (!resolve_key(m.wire, key, mapping) || check_keyexpr(key, true)) {
      reject("DeclareKeyExpr with an unknown base or an invalid key");
      return;
    }
    const uint16_t id = static_cast<uint16_t>(m.decl_id);
    for (KeyExprEntry& e : remote_keyexprs_) {
      if (e.id == id) {
        e.key.assign(key);
        return;
      }
    }
    if (remote_keyexprs_.size() >= kMaxRemoteKeyExprs) {
      reject("too many key expressions declared by the remote");
      return;
    }
    remote_keyexprs_.push_back({id, std::string(key)});
  } else if (m.decl == declid::UndeclareKeyExpr) {
    remote_keyexprs_.erase(std::remove_if(remote_keyexprs_.begin(), remote_keyexprs_.end(),
                                          [&](const KeyExprEntry& e) { return e.id == m.decl_id; }),
                           remote_keyexprs_.end());
  }
  // Subscriber / queryable / token declarations of the remote: not needed by this client.
}

void ZenohSession::handle_fragment(const FragmentMsg& f) {
  ++stats_.fragments_rx;
  Channel& c = f.reliable ? rx_reliable_ : rx_best_effort_;
  Reassembly& r = c.fragments;
  if (!sn_precedes(c.last_sn, f.sn, info_.sn_mask)) {
    ++stats_.rx_sn_dropped;
    return;
  }
  c.last_sn = f.sn;
  if (f.drop) {  // the sender abandoned the message (§4.8)
    r.active = false;
    return;
  }
  // Pieces of one message carry consecutive SNs; a gap breaks the chain (§6).
  if (r.active && f.sn != r.next_sn) {
    reject("fragment chain broken by an SN gap");
    r.active = false;
    r.skipping = !info_.fragment_markers;
  }
  if (info_.fragment_markers) {
    if (f.first) {
      if (r.active) reject("fragmented message left incomplete");
      r.active = true;
      r.overflow = false;
      r.data.clear();
    } else if (!r.active) {
      return;  // the tail of a message already rejected
    }
  } else {
    if (r.skipping) {
      r.skipping = f.more;
      return;
    }
    if (!r.active) {
      r.active = true;
      r.overflow = false;
      r.data.clear();
    }
  }
  r.next_sn = (f.sn + 1) & info_.sn_mask;
  if (!r.overflow) {
    if (r.data.size() + f.body.size > config_.max_reassembled_bytes) {
      r.overflow = true;
      r.data.clear();
    } else {
      r.data.insert(r.data.end(), f.body.data, f.body.data + f.body.size);
    }
  }
  if (f.more) return;
  r.active = false;
  if (r.overflow) {
    ++stats_.rx_oversized;
    last_error_ = "fragmented message larger than max_reassembled_bytes (" +
                  std::to_string(config_.max_reassembled_bytes) + " bytes), dropped";
    return;
  }
  ++stats_.reassembled_rx;
  Reader rd(r.data.data(), r.data.size());
  NetworkMsg m;
  if (const char* e = decode_network(rd, m)) {
    reject(e);
    return;
  }
  if (rd.remaining() != 0) {
    reject("trailing bytes after a reassembled message");
    return;
  }
  handle_network(m);
}

}  // namespace rvd::link
