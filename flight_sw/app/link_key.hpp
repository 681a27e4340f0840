// The run's link key (message authentication, see flight_sw/link/README.md): never on the command
// line, where every local user can read it (ps, /proc/PID/cmdline). Taken from, in this order:
//   --key-file semihosting/PATH  a host file read through ARM semihosting (QEMU system mode; the
//                                host side writes it 0600 and removes it once read)
//   --key-file PATH              a regular file of ours that nobody else may read (mode 0600 or
//                                stricter; a symlink is refused)
//   $RVD_LINK_KEY                the environment (readable only by our user), removed once read
// The content is the key as 64 hex digits, optionally followed by a newline.
#pragma once

#include <array>
#include <cstdint>
#include <string>

#include "flight_sw/link/messages.hpp"

namespace rvd::app {

using LinkKey = std::array<uint8_t, msg::kKeySize>;

// Parses 2 x kKeySize hex digits (one trailing newline allowed).
bool parse_link_key(const std::string& text, LinkKey& key);

// Loads the key as described above; false and `error` when there is none or it is unusable.
bool load_link_key(const std::string& key_file, LinkKey& key, std::string& error);

}  // namespace rvd::app
