// zenoh_probe: a small command-line Zenoh client built on rvd::link::ZenohSession, driven by the
// Python interop tests (tests/test_link_zenoh_*.py) and by rvd_pil/bench/link_latency.py.
//
//   zenoh_probe --connect tcp/127.0.0.1:7447 [options]
//     --sub KEY           subscribe to KEY (repeatable; wildcards allowed)
//     --declare KEY       declare KEY as a numeric key expression first (repeatable): puts and
//                         subscriptions on exactly KEY then travel by id
//     --echo KEY          put every received payload back on KEY (the lockstep "guidance")
//     --put KEY:N         after opening, put N pattern bytes on KEY and report the status
//     --encoding ID       send puts with this encoding id (default: none, i.e. zenoh/bytes)
//     --lease-ms N        lease announced to the remote (default 10000)
//     --connect-timeout-ms N  TCP connect and handshake reply timeout (default 2000)
//     --batch N           batch size proposed in InitSyn (default 65535)
//     --no-reconnect      report a lost link and stop instead of reconnecting
//     --reconnect-max N   give up after N failed attempts (default 30)
//     --max-reassembled N cap for one fragmented message (default 1 MiB)
//     --rx-stall-ms N     drop the link when a batch stays incomplete this long (default 2000)
//     --print-payload     add the payload in hex to SAMPLE lines
//     --quiet             no SAMPLE lines (the counts are in STATS)
//     --check-seq         payloads are u64 little-endian counters: count gaps and repeats
//     --exit-after N      stop after N received samples
//     --duration-ms N     stop after this long
//   stdin commands, one per line: "put KEY N", "stats", "quit". EOF on stdin also stops.
//   stdout lines: OPEN, SAMPLE, PUT, EVENT, RECONNECTED, STATS, BYE (key=value fields).
#include <poll.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "flight_sw/link/zenoh_session.hpp"

using rvd::link::LinkStatus;
using rvd::link::ZenohSession;

namespace {

struct Options {
  rvd::link::ZenohConfig config;
  std::vector<std::string> subs, declares;
  std::string echo_key;
  std::vector<std::pair<std::string, size_t>> puts;
  rvd::link::PutOptions put_options;
  bool print_payload = false, quiet = false, check_seq = false;
  long exit_after = -1, duration_ms = -1;
};

[[noreturn]] void usage(const char* why) {
  std::fprintf(stderr, "zenoh_probe: %s (see the header of tests/cpp/tools/zenoh_probe.cpp)\n", why);
  std::exit(2);
}

long number(const char* text, const char* what) {
  char* end = nullptr;
  const long v = std::strtol(text, &end, 10);
  if (!end || *end || v < 0) usage(what);
  return v;
}

std::string hex(const uint8_t* p, size_t n) {
  static const char* digits = "0123456789abcdef";
  std::string s(2 * n, '0');
  for (size_t i = 0; i < n; ++i) {
    s[2 * i] = digits[p[i] >> 4];
    s[2 * i + 1] = digits[p[i] & 0xF];
  }
  return s;
}

// A ZenohID as Zenoh prints it: the little-endian u128 in hex, leading zeros dropped.
std::string zid_text(const rvd::link::zenoh::Zid& z) {
  std::string s;
  for (int i = z.size - 1; i >= 0; --i) s += hex(&z.bytes[i], 1);
  const size_t nz = s.find_first_not_of('0');
  return nz == std::string::npos ? "0" : s.substr(nz);
}

std::vector<uint8_t> pattern(size_t n) {
  std::vector<uint8_t> v(n);
  for (size_t i = 0; i < n; ++i) v[i] = static_cast<uint8_t>((i * 31 + 7) & 0xFF);
  return v;
}

Options parse(int argc, char** argv) {
  Options o;
  bool have_endpoint = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> const char* {
      if (i + 1 >= argc) usage(("missing value after " + a).c_str());
      return argv[++i];
    };
    if (a == "--connect") {
      o.config.endpoint = value();
      have_endpoint = true;
    } else if (a == "--sub") {
      o.subs.push_back(value());
    } else if (a == "--declare") {
      o.declares.push_back(value());
    } else if (a == "--echo") {
      o.echo_key = value();
    } else if (a == "--put") {
      const std::string v = value();
      const size_t colon = v.rfind(':');
      if (colon == std::string::npos) usage("--put wants KEY:N");
      o.puts.emplace_back(v.substr(0, colon), number(v.c_str() + colon + 1, "bad --put size"));
    } else if (a == "--encoding") {
      o.put_options.has_encoding = true;
      o.put_options.encoding_id = static_cast<uint32_t>(number(value(), "bad --encoding"));
    } else if (a == "--lease-ms") {
      o.config.lease_ms = static_cast<uint32_t>(number(value(), "bad --lease-ms"));
    } else if (a == "--connect-timeout-ms") {
      o.config.connect_timeout_ms = static_cast<int>(number(value(), "bad --connect-timeout-ms"));
    } else if (a == "--batch") {
      const long b = number(value(), "bad --batch");
      if (b > 65535) usage("--batch must be at most 65535");
      o.config.batch_size = static_cast<uint16_t>(b);
    } else if (a == "--no-reconnect") {
      o.config.reconnect.enabled = false;
    } else if (a == "--reconnect-max") {
      o.config.reconnect.max_attempts = static_cast<int>(number(value(), "bad --reconnect-max"));
    } else if (a == "--max-reassembled") {
      o.config.max_reassembled_bytes = static_cast<size_t>(number(value(), "bad --max-reassembled"));
    } else if (a == "--rx-stall-ms") {
      o.config.rx_stall_ms = static_cast<int>(number(value(), "bad --rx-stall-ms"));
    } else if (a == "--print-payload") {
      o.print_payload = true;
    } else if (a == "--quiet") {
      o.quiet = true;
    } else if (a == "--check-seq") {
      o.check_seq = true;
    } else if (a == "--exit-after") {
      o.exit_after = number(value(), "bad --exit-after");
    } else if (a == "--duration-ms") {
      o.duration_ms = number(value(), "bad --duration-ms");
    } else {
      usage(("unknown option " + a).c_str());
    }
  }
  if (!have_endpoint) usage("--connect ENDPOINT is required");
  return o;
}

void print_open(const char* what, LinkStatus s, const ZenohSession& z) {
  const auto& i = z.link_info();
  if (s != LinkStatus::Ok) {
    std::printf("%s status=%s error=\"%s\"\n", what, to_string(s), z.last_error().c_str());
  } else {
    std::printf("%s status=Ok batch=%u sn_mask=%llu remote_lease_ms=%llu whatami=%s zid=%s "
                "remote_zid=%s markers=%d\n",
                what, i.batch_size, static_cast<unsigned long long>(i.sn_mask),
                static_cast<unsigned long long>(i.remote_lease_ms),
                i.remote_whatami == rvd::link::zenoh::whatami::Router ? "router" : "peer",
                zid_text(i.local_zid).c_str(), zid_text(i.remote_zid).c_str(),
                i.fragment_markers ? 1 : 0);
  }
  std::fflush(stdout);
}

void print_stats(const ZenohSession& z, long seq_errors) {
  const auto& s = z.stats();
  std::printf(
      "STATS connects=%llu reconnects=%llu link_losses=%llu lease_expirations=%llu "
      "batches_rx=%llu batches_tx=%llu frames_rx=%llu frames_tx=%llu fragments_rx=%llu "
      "reassembled_rx=%llu samples_rx=%llu puts_tx=%llu keepalives_rx=%llu keepalives_tx=%llu "
      "rx_sender_mapped=%llu rx_receiver_mapped=%llu rx_rejected=%llu rx_sn_dropped=%llu "
      "rx_oversized=%llu rx_unmatched=%llu resyncs=%llu requests_answered=%llu seq_errors=%ld last_error=\"%s\"\n",
      (unsigned long long)s.connects, (unsigned long long)s.reconnects,
      (unsigned long long)s.link_losses, (unsigned long long)s.lease_expirations,
      (unsigned long long)s.batches_rx, (unsigned long long)s.batches_tx,
      (unsigned long long)s.frames_rx, (unsigned long long)s.frames_tx,
      (unsigned long long)s.fragments_rx, (unsigned long long)s.reassembled_rx,
      (unsigned long long)s.samples_rx, (unsigned long long)s.puts_tx,
      (unsigned long long)s.keepalives_rx, (unsigned long long)s.keepalives_tx,
      (unsigned long long)s.rx_sender_mapped, (unsigned long long)s.rx_receiver_mapped,
      (unsigned long long)s.rx_rejected, (unsigned long long)s.rx_sn_dropped,
      (unsigned long long)s.rx_oversized, (unsigned long long)s.rx_unmatched, (unsigned long long)s.resyncs,
      (unsigned long long)s.requests_answered, seq_errors, z.last_error().c_str());
  std::fflush(stdout);
}

void do_put(ZenohSession& z, const std::string& key, size_t n, const rvd::link::PutOptions& o) {
  const std::vector<uint8_t> data = pattern(n);
  const LinkStatus s = z.put(key, data.data(), data.size(), o);
  std::printf("PUT key=%s len=%zu status=%s max=%zu", key.c_str(), n, to_string(s),
              z.max_put_payload(key, o));
  if (s != LinkStatus::Ok) std::printf(" error=\"%s\"", z.last_error().c_str());
  std::printf("\n");
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  const Options opt = parse(argc, argv);
  ZenohSession z(opt.config);
  long samples = 0, seq_errors = 0;
  uint64_t expected_seq = 0;
  bool have_seq = false;

  for (const std::string& k : opt.declares) {
    if (z.declare_keyexpr(k) != LinkStatus::Ok) usage(("cannot declare " + k).c_str());
  }
  for (const std::string& k : opt.subs) {
    const LinkStatus s = z.declare_subscriber(k, [&](const rvd::link::Sample& smp) {
      ++samples;
      if (opt.check_seq) {
        uint64_t v = 0;
        if (smp.size == 8) std::memcpy(&v, smp.payload, 8);
        if (smp.size != 8 || (have_seq && v != expected_seq)) ++seq_errors;
        expected_seq = v + 1;
        have_seq = true;
      }
      if (!opt.echo_key.empty()) {
        const LinkStatus e = z.put(opt.echo_key, smp.payload, smp.size, opt.put_options);
        if (e != LinkStatus::Ok) {
          std::printf("PUT key=%s len=%zu status=%s error=\"%s\"\n", opt.echo_key.c_str(),
                      smp.size, to_string(e), z.last_error().c_str());
        }
      }
      if (opt.quiet) return;
      const char* mapping = smp.mapping == rvd::link::KeyMapping::FullString ? "full"
                            : smp.mapping == rvd::link::KeyMapping::SenderId ? "sender"
                                                                              : "receiver";
      std::string enc = smp.has_encoding ? std::to_string(smp.encoding.id) : "-";
      std::string ts = smp.has_timestamp ? std::to_string(smp.timestamp.ntp64) : "-";
      std::string tsid = smp.has_timestamp ? zid_text(smp.timestamp.id) : "-";
      std::printf("SAMPLE key=%.*s len=%zu kind=%s mapping=%s enc=%s ts=%s tsid=%s",
                  static_cast<int>(smp.key.size()), smp.key.data(), smp.size,
                  smp.is_delete ? "del" : "put", mapping, enc.c_str(), ts.c_str(), tsid.c_str());
      if (opt.print_payload) std::printf(" payload=%s", hex(smp.payload, smp.size).c_str());
      std::printf("\n");
      std::fflush(stdout);
    });
    if (s != LinkStatus::Ok) usage(("cannot subscribe to " + k + ": " + z.last_error()).c_str());
  }

  const LinkStatus opened = z.open();
  print_open("OPEN", opened, z);
  if (opened != LinkStatus::Ok && !opt.config.reconnect.enabled) return 3;
  for (const auto& [key, n] : opt.puts) do_put(z, key, n, opt.put_options);

  const auto start = std::chrono::steady_clock::now();
  LinkStatus last_event = LinkStatus::Ok;
  uint64_t reconnects = 0;
  std::string line;
  bool running = true;
  while (running) {
    if (opt.exit_after >= 0 && samples >= opt.exit_after) break;
    if (opt.duration_ms >= 0 &&
        std::chrono::steady_clock::now() - start >= std::chrono::milliseconds(opt.duration_ms))
      break;
    const LinkStatus s = z.poll(20);
    if (s != LinkStatus::Ok && s != LinkStatus::Timeout && s != last_event) {
      std::printf("EVENT status=%s error=\"%s\"\n", to_string(s), z.last_error().c_str());
      std::fflush(stdout);
    }
    if (s != LinkStatus::Timeout) last_event = s;
    if (z.stats().reconnects != reconnects) {
      reconnects = z.stats().reconnects;
      print_open("RECONNECTED", LinkStatus::Ok, z);
    }
    if (s == LinkStatus::NotConnected || s == LinkStatus::ReconnectExhausted) break;

    // Commands on stdin (non-blocking).
    pollfd p{0, POLLIN, 0};
    while (running && ::poll(&p, 1, 0) > 0) {
      char buf[4096];
      const ssize_t n = ::read(0, buf, sizeof buf);
      if (n <= 0) {
        running = false;
        break;
      }
      line.append(buf, static_cast<size_t>(n));
      size_t nl;
      while ((nl = line.find('\n')) != std::string::npos) {
        const std::string cmd = line.substr(0, nl);
        line.erase(0, nl + 1);
        char key[1024];
        size_t size = 0;
        if (cmd == "quit") {
          running = false;
        } else if (cmd == "stats") {
          print_stats(z, seq_errors);
        } else if (std::sscanf(cmd.c_str(), "put %1023s %zu", key, &size) == 2) {
          do_put(z, key, size, opt.put_options);
        } else if (!cmd.empty()) {
          std::printf("ERROR unknown command \"%s\"\n", cmd.c_str());
          std::fflush(stdout);
        }
      }
    }
  }
  print_stats(z, seq_errors);
  z.close();
  std::printf("BYE\n");
  std::fflush(stdout);
  return 0;
}
