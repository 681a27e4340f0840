// The run's link key (see link_key.hpp).
#include "flight_sw/app/link_key.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>

#include "flight_sw/link/semihosting.hpp"

namespace rvd::app {
namespace {

// One hex digit without a branch on its value: the same instructions for every key, so that the
// guest's instruction stream (its clock under QEMU -icount) does not depend on the run's key.
// Returns the value, or sets `bad`.
uint8_t hex_digit(char ch, uint32_t& bad) {
  const uint32_t c = static_cast<uint8_t>(ch);
  const uint32_t digit = c - '0', alpha = (c | 0x20u) - 'a';
  const uint32_t is_digit = 0u - static_cast<uint32_t>(digit <= 9u);
  const uint32_t is_alpha = 0u - static_cast<uint32_t>(alpha <= 5u);
  bad |= ~(is_digit | is_alpha) & 1u;
  return static_cast<uint8_t>((digit & is_digit) | ((alpha + 10u) & is_alpha));
}

constexpr size_t kKeyText = 2 * msg::kKeySize;
constexpr const char* kSemihosting = "semihosting/";

}  // namespace

bool parse_link_key(const std::string& text, LinkKey& key) {
  std::string t = text;
  if (!t.empty() && t.back() == '\n') t.pop_back();
  if (t.size() != kKeyText) return false;
  uint32_t bad = 0;
  for (size_t i = 0; i < key.size(); ++i) {
    const uint8_t hi = hex_digit(t[2 * i], bad), lo = hex_digit(t[2 * i + 1], bad);
    key[i] = static_cast<uint8_t>(hi << 4 | lo);
  }
  return bad == 0;
}

bool load_link_key(const std::string& key_file, LinkKey& key, std::string& error) {
  char buf[kKeyText + 2] = {};
  std::string text;
  if (key_file.rfind(kSemihosting, 0) == 0) {
    const std::string path = key_file.substr(std::strlen(kSemihosting));
    const long h = link::semihosting::open(path, false);
    if (h < 0) {
      error = "--key-file " + key_file + ": " + link::semihosting::errno_text();
      return false;
    }
    long got = 0, n = 0;
    while (got < static_cast<long>(sizeof buf) && (n = link::semihosting::read(h, buf + got, sizeof buf - got)) > 0) got += n;
    link::semihosting::close(h);
    text.assign(buf, static_cast<size_t>(got));
  } else if (!key_file.empty()) {
    const int fd = ::open(key_file.c_str(), O_RDONLY | O_NOFOLLOW | O_CLOEXEC);
    if (fd < 0) {
      error = "--key-file " + key_file + ": " + std::strerror(errno);
      return false;
    }
    struct stat st {};
    if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) || st.st_uid != ::geteuid() || (st.st_mode & 077) != 0) {
      ::close(fd);
      error = "--key-file " + key_file + ": must be a regular file of ours that nobody else may read (chmod 600)";
      return false;
    }
    const ssize_t got = ::read(fd, buf, sizeof buf);
    ::close(fd);
    text.assign(buf, got > 0 ? static_cast<size_t>(got) : 0);
  } else if (const char* env = std::getenv(msg::kKeyEnv)) {
    text = env;
    ::unsetenv(msg::kKeyEnv);  // not inherited by anything we might start
  } else {
    error = std::string("no link key: set $") + msg::kKeyEnv + " or give --key-file (never the key itself on the command line)";
    return false;
  }
  std::memset(buf, 0, sizeof buf);
  if (!parse_link_key(text, key)) {
    error = "the link key must be " + std::to_string(kKeyText) + " hex digits";
    return false;
  }
  return true;
}

}  // namespace rvd::app
