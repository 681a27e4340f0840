// The TCP batch layer on real loopback sockets: endpoint parsing, length-prefixed batches split
// and coalesced by TCP, EOF in the middle of a batch, and bounded sends to a peer that never reads.
#include <doctest/doctest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <fstream>
#include <iterator>
#include <thread>
#include <string>
#include <vector>

#include "flight_sw/link/semihosting.hpp"
#include "flight_sw/link/tcp_link.hpp"

using namespace rvd::link;

namespace {

// A listening socket on 127.0.0.1 with a kernel-chosen port.
struct Listener {
  int fd = -1;
  uint16_t port = 0;
  Listener() {
    fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    REQUIRE(::listen(fd, 4) == 0);
    socklen_t len = sizeof a;
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    port = ntohs(a.sin_port);
  }
  ~Listener() { ::close(fd); }
  TcpEndpoint endpoint() const { return {"127.0.0.1", port}; }
};

void write_all(int fd, const std::vector<uint8_t>& b) {
  size_t off = 0;
  while (off < b.size()) {
    const ssize_t n = ::write(fd, b.data() + off, b.size() - off);
    REQUIRE(n > 0);
    off += static_cast<size_t>(n);
  }
}

}  // namespace

TEST_CASE("endpoint parsing accepts Zenoh TCP locators and explains bad ones") {
  TcpEndpoint e;
  REQUIRE(parse_tcp_endpoint("tcp/127.0.0.1:7447", e) == nullptr);
  CHECK(e.host == "127.0.0.1");
  CHECK(e.port == 7447);
  REQUIRE(parse_tcp_endpoint("tcp/[::1]:80", e) == nullptr);
  CHECK(e.host == "::1");
  REQUIRE(parse_tcp_endpoint("tcp/10.0.2.2:7447#iface=eth0", e) == nullptr);
  CHECK(e.host == "10.0.2.2");
  for (const char* bad : {"udp/1.2.3.4:5", "tcp/1.2.3.4", "tcp/:80", "tcp/h:0", "tcp/h:70000", "tcp/h:8x",
                          "tcp/[::1]80", "127.0.0.1:7447"}) {
    CHECK_MESSAGE(parse_tcp_endpoint(bad, e) != nullptr, bad);
  }
  REQUIRE(parse_tcp_endpoint("semihosting//tmp/rvd link", e) == nullptr);
  CHECK(e.semihosting_dir == "/tmp/rvd link");
  CHECK(e.host.empty());
  REQUIRE(parse_tcp_endpoint("tcp/h:1", e) == nullptr);
  CHECK(e.semihosting_dir.empty());
  REQUIRE(parse_tcp_endpoint("semihosting/.", e) == nullptr);  // the emulator's working directory
  CHECK(e.semihosting_dir == ".");
  CHECK_MESSAGE(parse_tcp_endpoint("semihosting/", e) != nullptr, "semihosting/");
}

TEST_CASE("a semihosting endpoint that cannot be opened fails with the reason") {
  // Natively there is no semihosting: the probe says so (on ARM hardware it would catch the SIGILL
  // of AArch64's HLT or the ENOSYS of AArch32's SVC instead of dying). Under qemu-user, which runs
  // these tests for the ARM builds and always offers semihosting, the host's open() fails.
  TcpEndpoint e;
  REQUIRE(parse_tcp_endpoint("semihosting//tmp/rvd-no-such-link", e) == nullptr);
  TcpLink link;
  std::string err;
  CHECK(link.connect(e, -1, &err) == LinkStatus::ConnectFailed);
  CHECK_MESSAGE(err.find("semihosting//tmp/rvd-no-such-link") == 0, err);
#if defined(__aarch64__) || defined(__arm__)
  CHECK_MESSAGE((err.find("No such file") != std::string::npos) == semihosting::available(), err);
#else
  CHECK_FALSE(semihosting::available());
  CHECK_MESSAGE(err.find("semihosting is not available") != std::string::npos, err);
#endif
  CHECK_FALSE(link.is_open());
  const uint8_t* data = nullptr;
  size_t size = 0;
  CHECK(link.receive_batch(data, size, -1, &err) == LinkStatus::NotConnected);
}

// True once thread `tid` of this process sleeps in the kernel (state S in /proc/self/task/<tid>/stat)
// or has ended; false if neither happens within `bound` (a condition, not a pause).
static bool wait_until_sleeping_or_gone(pid_t tid, const std::atomic<bool>& done, std::chrono::seconds bound) {
  const auto until = std::chrono::steady_clock::now() + bound;
  const std::string path = "/proc/self/task/" + std::to_string(tid) + "/stat";
  while (std::chrono::steady_clock::now() < until) {
    if (done) return true;
    std::ifstream in(path);
    std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const size_t paren = stat.rfind(')');  // the command name may hold spaces: the state follows ')'
    if (paren != std::string::npos && paren + 2 < stat.size() && stat[paren + 2] == 'S') return true;
    std::this_thread::yield();
  }
  return false;
}

TEST_CASE("a negative timeout waits without limit for the whole batch") {
  Listener l;
  TcpLink link;
  std::string err;
  REQUIRE(link.connect({"127.0.0.1", l.port}, 1000, &err) == LinkStatus::Ok);
  const int peer = ::accept(l.fd, nullptr, nullptr);
  REQUIRE(peer >= 0);
  // The batch comes in two pieces; the second is sent only once the receiver, holding the first,
  // sleeps in the kernel waiting for more (so the wait is exercised, whatever the machine's load).
  const uint8_t head[] = {3, 0, 'a'};
  const uint8_t tail[] = {'b', 'c'};
  REQUIRE(::send(peer, head, sizeof head, 0) == static_cast<ssize_t>(sizeof head));
  std::atomic<pid_t> receiver_tid{0};
  std::atomic<bool> done{false};
  const uint8_t* data = nullptr;
  size_t size = 0;
  LinkStatus st = LinkStatus::NotConnected;
  std::thread receiver([&] {
    receiver_tid = static_cast<pid_t>(::syscall(SYS_gettid));
    st = link.receive_batch(data, size, -1, &err);
    done = true;
  });
  while (receiver_tid == 0) std::this_thread::yield();
  const bool waited_or_returned = wait_until_sleeping_or_gone(receiver_tid, done, std::chrono::seconds(60));
  const bool returned_early = done;  // before the second piece was sent: it did not wait
  ::send(peer, tail, sizeof tail, 0);
  receiver.join();
  ::close(peer);
  CHECK(waited_or_returned);
  CHECK_FALSE(returned_early);
  REQUIRE(st == LinkStatus::Ok);
  CHECK(std::string(reinterpret_cast<const char*>(data), size) == "abc");
}

TEST_CASE("connect to a closed port fails with a reason") {
  uint16_t port;
  {
    Listener l;  // take a free port, then close it
    port = l.port;
  }
  TcpLink link;
  std::string err;
  CHECK(link.connect({"127.0.0.1", port}, 1000, &err) == LinkStatus::ConnectFailed);
  CHECK(err.find("connect") != std::string::npos);
  CHECK_FALSE(link.is_open());
  CHECK(link.connect({"no-such-host.invalid", 7447}, 1000, &err) == LinkStatus::ConnectFailed);
}

TEST_CASE("batches are cut from the byte stream however TCP splits or joins them") {
  Listener l;
  TcpLink link;
  std::string err;
  REQUIRE(link.connect(l.endpoint(), 1000, &err) == LinkStatus::Ok);
  const int peer = ::accept(l.fd, nullptr, nullptr);
  REQUIRE(peer >= 0);

  const uint8_t* data = nullptr;
  size_t size = 0;
  CHECK(link.receive_batch(data, size, 0, &err) == LinkStatus::Timeout);

  // Two batches (and an empty one) in one write.
  write_all(peer, {0x03, 0x00, 0xaa, 0xbb, 0xcc, 0x00, 0x00, 0x01, 0x00, 0x04});
  REQUIRE(link.receive_batch(data, size, 1000, &err) == LinkStatus::Ok);
  CHECK(std::vector<uint8_t>(data, data + size) == std::vector<uint8_t>{0xaa, 0xbb, 0xcc});
  REQUIRE(link.receive_batch(data, size, 1000, &err) == LinkStatus::Ok);
  CHECK(size == 0);
  REQUIRE(link.receive_batch(data, size, 1000, &err) == LinkStatus::Ok);
  CHECK(std::vector<uint8_t>(data, data + size) == std::vector<uint8_t>{0x04});

  // A maximal batch written in three pieces, the prefix itself split.
  std::vector<uint8_t> big(2 + 65535);
  big[0] = 0xff;
  big[1] = 0xff;
  for (size_t i = 2; i < big.size(); ++i) big[i] = static_cast<uint8_t>(i * 7);
  write_all(peer, {big.begin(), big.begin() + 1});
  CHECK(link.receive_batch(data, size, 20, &err) == LinkStatus::Timeout);
  write_all(peer, {big.begin() + 1, big.begin() + 40000});
  CHECK(link.receive_batch(data, size, 20, &err) == LinkStatus::Timeout);
  write_all(peer, {big.begin() + 40000, big.end()});
  REQUIRE(link.receive_batch(data, size, 1000, &err) == LinkStatus::Ok);
  REQUIRE(size == 65535);
  CHECK(std::equal(data, data + size, big.begin() + 2));

  // Our sends arrive with the little-endian length prefix.
  std::vector<uint8_t> frame = {0, 0, 0x25, 0x01, 0x02};
  REQUIRE(link.send_batch(frame.data(), 3, 1000, &err) == LinkStatus::Ok);
  uint8_t got[5] = {};
  size_t have = 0;
  while (have < 5) {
    const ssize_t n = ::read(peer, got + have, 5 - have);
    REQUIRE(n > 0);
    have += static_cast<size_t>(n);
  }
  CHECK(std::vector<uint8_t>(got, got + 5) == std::vector<uint8_t>{0x03, 0x00, 0x25, 0x01, 0x02});
  std::vector<uint8_t> huge(2 + 70000);
  CHECK(link.send_batch(huge.data(), 70000, 1000, &err) == LinkStatus::MessageTooLarge);

  // EOF in the middle of a batch: the link is lost and says why.
  write_all(peer, {0x10, 0x00, 0x01, 0x02});
  ::close(peer);
  CHECK(link.receive_batch(data, size, 1000, &err) == LinkStatus::LinkLost);
  CHECK(err.find("middle of a batch") != std::string::npos);
  CHECK_FALSE(link.is_open());
  CHECK(link.receive_batch(data, size, 0, &err) == LinkStatus::NotConnected);
}

TEST_CASE("sending to a peer that never reads ends in Timeout or LinkLost, never blocks") {
  Listener l;
  TcpLink link;
  std::string err;
  REQUIRE(link.connect(l.endpoint(), 1000, &err) == LinkStatus::Ok);
  const int peer = ::accept(l.fd, nullptr, nullptr);
  REQUIRE(peer >= 0);
  std::vector<uint8_t> frame(2 + 65535, 0x5a);
  LinkStatus s = LinkStatus::Ok;
  int sent = 0;
  while (s == LinkStatus::Ok && sent < 100000) {
    s = link.send_batch(frame.data(), 65535, 50, &err);
    ++sent;
  }
  CHECK((s == LinkStatus::Timeout || s == LinkStatus::LinkLost));
  CHECK(sent > 1);
  CHECK_FALSE(err.empty());
  ::close(peer);
}
