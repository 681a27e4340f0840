// The flight-side Zenoh client session (client mode, TCP unicast), written from the Zenoh wire
// notes summarised in flight_sw/link/README.md and tested against eclipse-zenoh 1.10.2.
//
// Single-threaded and poll-driven, like zenoh-pico without its background tasks: the application
// calls poll(timeout) (or poll_until), which reads batches, dispatches samples to subscriber
// callbacks, sends a KeepAlive when nothing was sent for lease/4, detects a silent remote, and
// reconnects on the configured schedule. Every call has a timeout and returns a LinkStatus;
// nothing throws across this API and no input from the network can crash it.
//
// Data flow as elsewhere in flight_sw: config -> session (buffers allocated once) -> poll()/put()
// without allocation in the steady state -> stats().
//
// Limits (see flight_sw/link/README.md):
//  * Sends are never fragmented: a put whose encoded message exceeds the negotiated batch size is
//    rejected with MessageTooLarge (max_put_payload() tells the room for a key).
//  * Received fragmented messages are reassembled up to ZenohConfig::max_reassembled_bytes.
//  * A stream that stops parsing (resync_after_unparsed batches in a row without one transport
//    message, or a batch left incomplete for rx_stall_ms) is dropped and reconnected: a resync.
//  * Subscriber callbacks run inside poll(); they may call put(), nothing else on this session
//    (poll, declare, undeclare return Busy; close() is deferred to the end of the callback).
//    An exception thrown by a callback is caught and counted, never propagated.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <string_view>
#include <vector>

#include "flight_sw/link/tcp_link.hpp"
#include "flight_sw/link/zenoh_codec.hpp"

namespace rvd::link {

// After a lost link: wait first_delay_ms, then double the wait up to max_delay_ms between
// attempts; give up after max_attempts consecutive failures (0 = keep trying for ever).
struct ReconnectPolicy {
  bool enabled = true;
  int first_delay_ms = 100;
  int max_delay_ms = 2000;
  int max_attempts = 30;
};

struct ZenohConfig {
  std::string endpoint = "tcp/127.0.0.1:7447";
  uint32_t lease_ms = 10000;       // announced: the remote drops us after this long without traffic
  uint16_t batch_size = 65535;     // proposed; the session uses min(this, the remote's)
  int connect_timeout_ms = 2000;   // TCP connect, and the wait for each handshake reply
  int send_timeout_ms = 2000;      // a batch not written in this time is reported (see TcpLink)
  size_t max_reassembled_bytes = 1u << 20;  // cap for one fragmented message from the remote
  // Corrupted framing: after this many consecutive batches in which not one transport message
  // parses, the byte stream is taken to be out of step and the link is dropped (and reconnected).
  int resync_after_unparsed = 3;
  // A batch whose length prefix has arrived but whose bytes have not all come within this time
  // means a corrupted length (or a stalled peer): the link is dropped. Not applied when untimed.
  int rx_stall_ms = 2000;
  ReconnectPolicy reconnect;
  // Wait for the remote without time limits: connect, handshake and sends take as long as they
  // take, poll(-1) waits until traffic arrives, the remote's lease is not enforced. For QEMU
  // system mode with -icount sleep=off, where the guest clock stands still while the guest waits
  // and a timeout would make QEMU jump the clock to it at once instead of after the time it
  // names; the host-side runner's real-time limit then covers a silent host.
  bool untimed = false;
  // Seed of the ZenohID and the initial sequence numbers; 0 (the default): a fresh random one. A fixed
  // seed makes every byte the flight software sends repeat from run to run, for reproducibility checks
  // (the cycle model's cache simulation sees the link code too); never for flight.
  uint64_t seed = 0;
};

// How the key of a received message was written on the wire (§7.3).
enum class KeyMapping : uint8_t {
  FullString,  // scope 0: the whole key in the message
  SenderId,    // M = 1: an id the remote declared to us
  ReceiverId,  // M = 0: an id we declared to the remote
};

// One received Put or Del. Views are valid only during the callback.
struct Sample {
  std::string_view key;
  const uint8_t* payload = nullptr;
  size_t size = 0;
  bool is_delete = false;
  bool has_timestamp = false;
  zenoh::Timestamp timestamp;  // NTP64 time (UNIX epoch, 32.32 fixed point) + the stamping node
  bool has_encoding = false;   // absent: zenoh/bytes
  zenoh::Encoding encoding;
  KeyMapping mapping = KeyMapping::FullString;
};
using SampleCallback = std::function<void(const Sample&)>;

struct PutOptions {
  bool has_encoding = false;
  uint32_t encoding_id = 0;  // e.g. 3 application/octet-stream, 5 application/json (§1)
};

struct ZenohStats {
  uint64_t connects = 0;          // completed handshakes, the first one included
  uint64_t reconnects = 0;        // completed handshakes after a lost link
  uint64_t link_losses = 0;       // EOF, socket errors, Close from the remote, lease expiry
  uint64_t lease_expirations = 0;
  uint64_t batches_rx = 0, batches_tx = 0;
  uint64_t bytes_rx = 0, bytes_tx = 0;  // batch bytes, length prefixes excluded
  uint64_t frames_rx = 0, frames_tx = 0;
  uint64_t fragments_rx = 0, reassembled_rx = 0;
  uint64_t samples_rx = 0, puts_tx = 0;
  uint64_t keepalives_rx = 0, keepalives_tx = 0;
  uint64_t rx_sender_mapped = 0, rx_receiver_mapped = 0;  // pushes keyed by a declared id
  uint64_t rx_rejected = 0;    // malformed batches, unknown key ids, broken fragment chains, ...
  uint64_t rx_oversized = 0;   // fragmented messages larger than max_reassembled_bytes, dropped
  uint64_t rx_unmatched = 0;   // samples whose key none of our subscriptions includes, dropped
  uint64_t resyncs = 0;        // links dropped because the byte stream no longer parsed (also link_losses)
  uint64_t rx_sn_dropped = 0;  // frames whose SN is not newer than the last one (duplicates)
  uint64_t requests_answered = 0, interests_answered = 0;
  uint64_t callback_exceptions = 0;  // exceptions caught from subscriber callbacks
};

// What the handshake settled (valid while connected).
struct ZenohLinkInfo {
  uint16_t batch_size = 0;
  uint64_t sn_mask = 0;
  uint64_t remote_lease_ms = 0;
  uint8_t remote_whatami = 0;  // zenoh::whatami::Router or Peer
  zenoh::Zid remote_zid;
  zenoh::Zid local_zid;
  bool fragment_markers = false;  // patch >= 1 agreed: fragments carry First/Drop markers
};

class ZenohSession {
 public:
  explicit ZenohSession(ZenohConfig config);
  ~ZenohSession();
  ZenohSession(const ZenohSession&) = delete;
  ZenohSession& operator=(const ZenohSession&) = delete;

  // Connects and performs the handshake once (bounded by connect_timeout_ms twice over), then
  // sends all declarations made so far. When it fails and reconnection is enabled, poll() keeps
  // trying on the schedule.
  LinkStatus open();

  // Declares `key` as a numeric key expression (sender mapping, §7.3). Later puts and
  // subscriptions on exactly this key then use the id instead of the string. Remembered and
  // re-declared after a reconnect. Allowed before open().
  LinkStatus declare_keyexpr(std::string key, uint16_t* id = nullptr);

  // Subscribes to a key expression (wildcards allowed). Remembered and re-declared after a
  // reconnect. Allowed before open().
  LinkStatus declare_subscriber(std::string key, SampleCallback callback, uint32_t* id = nullptr);
  LinkStatus undeclare_subscriber(uint32_t id);

  // Publishes one Put in a reliable frame, sent at once. MessageTooLarge when the encoded message
  // would exceed the negotiated batch size; NotConnected / Reconnecting when there is no link.
  LinkStatus put(std::string_view key, const uint8_t* data, size_t size,
                 const PutOptions& options = {});

  // Waits up to timeout_ms (negative: without limit) for traffic; once something arrived, also handles whatever else is
  // already buffered, then returns Ok. Timeout when nothing arrived. Also sends KeepAlives,
  // detects lease expiry and, when the link is down, makes the next scheduled reconnect attempt
  // (one attempt may take up to 3 x connect_timeout_ms beyond timeout_ms).
  LinkStatus poll(int timeout_ms);

  // poll() until done() is true (Ok) or timeout_ms passed (Timeout). Rides through reconnects
  // when they are enabled; returns early on NotConnected, ReconnectExhausted and Busy.
  LinkStatus poll_until(const std::function<bool()>& done, int timeout_ms);

  // Sends Close (whole session) and shuts the socket. No reconnection until open() again.
  void close();

  bool connected() const { return state_ == State::Connected; }
  const ZenohStats& stats() const { return stats_; }
  const ZenohLinkInfo& link_info() const { return info_; }
  // Description of the latest error or rejected input (empty if none yet).
  const std::string& last_error() const { return last_error_; }
  // Largest payload a put() on `key` can carry in one batch of the negotiated size (or of the
  // proposed size before the first handshake).
  size_t max_put_payload(std::string_view key, const PutOptions& options = {}) const;

 private:
  enum class State { Idle, Connected, Reconnecting, GaveUp, Closed };
  struct KeyExprEntry {
    uint16_t id;
    std::string key;
  };
  struct Subscriber {
    uint32_t id;
    std::string key;
    SampleCallback callback;
  };
  struct Reassembly {  // one per reliability channel
    bool active = false;
    bool overflow = false;  // grew past the cap: drop it when its last piece arrives
    bool skipping = false;  // no markers: skip pieces up to the end of a broken message
    uint64_t next_sn = 0;
    std::vector<uint8_t> data;
  };
  struct Channel {  // receive SN state per reliability
    uint64_t last_sn = 0;
    Reassembly fragments;
  };
  class Dispatcher;
  using Clock = std::chrono::steady_clock;

  LinkStatus connect_and_handshake();
  // Receives batches until `handler` stops; leftover bytes of the last batch (messages after the
  // awaited one) are viewed by rest/rest_size.
  LinkStatus handshake_receive(zenoh::BatchHandler& handler, const char* waiting_for,
                               const uint8_t*& rest, size_t& rest_size);
  LinkStatus send_declarations();
  size_t batch_room() const;                           // batch bytes we may send
  zenoh::Writer frame_writer();                        // a reliable Frame header, next TX SN
  LinkStatus send_frame(const zenoh::Writer& w);       // sends it; the SN is used up on success
  LinkStatus send_declaration(const zenoh::Writer& w);  // send_frame, a stall drops the link
  LinkStatus send_batch(size_t batch_bytes);
  LinkStatus lost(LinkStatus why, const std::string& detail);
  LinkStatus resync(const std::string& why);  // lost() for a stream out of step, counted in resyncs
  void schedule_retry();
  void reject(const char* what);
  void handle_batch(const uint8_t* data, size_t size);
  void handle_network(const zenoh::NetworkMsg& m);
  void handle_push(const zenoh::NetworkMsg& m);
  void handle_declare(const zenoh::NetworkMsg& m);
  void handle_fragment(const zenoh::FragmentMsg& f);
  bool resolve_key(const zenoh::WireExpr& w, std::string_view& key, KeyMapping& mapping);
  zenoh::WireExpr wire_for(std::string_view key) const;
  void service_keep_alive();
  int link_timeout_ms(int configured) const { return config_.untimed ? -1 : configured; }
  const char* check_config() const;

  ZenohConfig config_;
  zenoh::Zid zid_;
  State state_ = State::Idle;
  ZenohStats stats_;
  ZenohLinkInfo info_;
  std::string last_error_;
  TcpLink link_;
  std::vector<uint8_t> tx_;  // length prefix + one batch, allocated once
  std::mt19937_64 rng_;

  // Sequence numbers (§6).
  uint64_t tx_sn_ = 0;
  Channel rx_reliable_, rx_best_effort_;

  // Declarations: ours (re-sent after every reconnect) and the remote's key expressions.
  std::vector<KeyExprEntry> own_keyexprs_;
  std::vector<KeyExprEntry> remote_keyexprs_;
  std::vector<Subscriber> subscribers_;
  uint32_t next_subscriber_id_ = 1;
  std::string key_scratch_;  // key = declared prefix + suffix, reused

  // Timers; last_rx_ moves only for batches that parse (garbage does not hold the lease).
  Clock::time_point last_rx_{}, last_tx_{};
  int unparsed_in_row_ = 0;  // batches in a row in which no transport message parsed
  Clock::time_point next_attempt_{};
  int attempts_ = 0;
  int next_delay_ms_ = 0;

  bool in_callback_ = false;
  bool close_requested_ = false;
};

}  // namespace rvd::link
