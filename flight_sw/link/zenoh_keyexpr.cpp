// Key-expression validation and matching (see zenoh_keyexpr.hpp).
#include "flight_sw/link/zenoh_keyexpr.hpp"

namespace rvd::link::zenoh {
namespace {

// Splits off the first chunk of `s` (up to '/'); `s` keeps the rest without the separator.
std::string_view next_chunk(std::string_view& s) {
  const size_t slash = s.find('/');
  std::string_view chunk = s.substr(0, slash);
  s = slash == std::string_view::npos ? std::string_view{} : s.substr(slash + 1);
  return chunk;
}

// Glob match of one chunk where "$*" stands for any run of characters (possibly empty).
bool chunk_matches(std::string_view pat, std::string_view text) {
  if (pat == "*") return !text.empty();
  size_t p = 0, t = 0, star_p = std::string_view::npos, star_t = 0;
  while (t < text.size()) {
    if (p + 1 < pat.size() && pat[p] == '$' && pat[p + 1] == '*') {
      star_p = p += 2;
      star_t = t;
    } else if (p < pat.size() && pat[p] == text[t]) {
      ++p;
      ++t;
    } else if (star_p != std::string_view::npos) {
      p = star_p;
      t = ++star_t;
    } else {
      return false;
    }
  }
  while (p + 1 < pat.size() && pat[p] == '$' && pat[p + 1] == '*') p += 2;
  return p == pat.size();
}

// Chunk lists: "" is no chunk at all (valid keys never hold an empty chunk).
bool matches(std::string_view pattern, std::string_view key) {
  if (pattern.empty()) return key.empty();
  std::string_view pat_rest = pattern;
  const std::string_view chunk = next_chunk(pat_rest);
  if (chunk == "**") {
    if (matches(pat_rest, key)) return true;  // "**" stands for zero chunks ...
    if (key.empty()) return false;
    std::string_view key_rest = key;
    next_chunk(key_rest);
    return matches(pattern, key_rest);  // ... or swallows one more chunk of the key
  }
  if (key.empty()) return false;
  std::string_view key_rest = key;
  return chunk_matches(chunk, next_chunk(key_rest)) && matches(pat_rest, key_rest);
}

}  // namespace

const char* check_keyexpr(std::string_view key, bool allow_wildcards) {
  if (key.empty()) return "empty key expression";
  if (key.front() == '/' || key.back() == '/') return "key expression starts or ends with '/'";
  std::string_view rest = key, prev;
  do {
    const std::string_view chunk = next_chunk(rest);
    if (chunk.empty()) return "empty chunk ('//') in key expression";
    const bool wild = chunk == "*" || chunk == "**";
    if (wild && !allow_wildcards) return "wildcard in a concrete key";
    if (chunk == "**" && prev == "**") return "non-canonical key expression ('**/**')";
    if (chunk == "*" && prev == "**") return "non-canonical key expression ('**/*': write '*/**')";
    if (!wild) {
      for (size_t i = 0; i < chunk.size(); ++i) {
        const char c = chunk[i];
        if (c == '#' || c == '?') return "'#' and '?' are not allowed in key expressions";
        if (c == '*') return "'*' inside a chunk (use a whole '*' chunk or '$*')";
        if (c == '$') {
          if (i + 1 >= chunk.size() || chunk[i + 1] != '*') return "'$' not followed by '*'";
          if (!allow_wildcards) return "wildcard in a concrete key";
          if (chunk == "$*") return "non-canonical key expression ('$*' chunk: write '*')";
          if (i + 3 < chunk.size() && chunk[i + 2] == '$' && chunk[i + 3] == '*')
            return "non-canonical key expression ('$*$*')";
          ++i;  // skip the '*' of "$*"
        }
      }
    }
    prev = chunk;
  } while (!rest.empty());
  return nullptr;
}

bool keyexpr_matches(std::string_view pattern, std::string_view key) {
  return matches(pattern, key);
}

}  // namespace rvd::link::zenoh
