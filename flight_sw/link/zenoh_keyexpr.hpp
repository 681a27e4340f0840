// Key expressions: validation and wildcard matching, for dispatching received samples to the
// subscribers whose key expression includes the sample's key.
//
// Grammar (Zenoh's, restricted to what a client needs): chunks separated by '/', none empty; a
// chunk is "*" (exactly one chunk), "**" (zero or more chunks) or text in which "$*" matches any
// run of characters. '#', '?' and any other '$' are not allowed.
#pragma once

#include <string_view>

namespace rvd::link::zenoh {

// nullptr when `key` is a valid key expression (a concrete key when !allow_wildcards), else
// why not.
const char* check_keyexpr(std::string_view key, bool allow_wildcards);

// True when the concrete `key` belongs to the set that `pattern` denotes.
bool keyexpr_matches(std::string_view pattern, std::string_view key);

}  // namespace rvd::link::zenoh
