// octofuse: numbers and file bytes in messages.
#pragma once

#include <charconv>
#include <string>
#include <string_view>

namespace octofuse::detail {

/// The shortest text that reads back as v.
inline std::string shortest(double v) {
  char buf[64];
  auto res = std::to_chars(buf, buf + sizeof(buf), v);
  return std::string(buf, res.ptr);
}

/// The shortest text that reads back as the float v.
inline std::string shortest(float v) {
  char buf[64];
  auto res = std::to_chars(buf, buf + sizeof(buf), v);
  return std::string(buf, res.ptr);
}

/// Bytes read from a file, made safe for a message: printable ASCII is kept, any other byte is
/// written as \xNN (so the message is valid UTF-8 whatever the file holds), at most `max` bytes.
inline std::string printable(std::string_view bytes, std::size_t max = 60) {
  static const char* const kHex = "0123456789abcdef";
  std::string out;
  for (std::size_t i = 0; i < bytes.size() && i < max; ++i) {
    const auto c = static_cast<unsigned char>(bytes[i]);
    if (c >= 32 && c < 127) {
      out += static_cast<char>(c);
    } else {
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    }
  }
  if (bytes.size() > max) out += "...";
  return out;
}

}  // namespace octofuse::detail
