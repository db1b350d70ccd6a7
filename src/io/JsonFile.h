#pragma once
// Internal: opening and parsing a JSON file, with the messages the JSON readers share.
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>

#include <nlohmann/json.hpp>

#include "sonoslice/core/Error.h"
#include "sonoslice/io/JsonDepth.h"

namespace sonoslice {

/// The JSON library's message, fit for one line of an error: printable ASCII only. A parse error
/// quotes the bytes it last read, which need not be valid UTF-8 (Python decodes messages as such).
inline std::string json_detail(const nlohmann::json::exception& e) {
  std::string s = e.what();
  for (char& c : s)
    if (c < 0x20 || c > 0x7e) c = '?';
  return s;
}

/// Runs `read`, which reads a parsed document; a JSON library exception it lets escape (a value
/// of the wrong type somewhere a check was missed) becomes an InputError that names the file.
template <typename F>
auto with_json_errors_named(const std::string& where, F read) -> decltype(read()) {
  try {
    return read();
  } catch (const nlohmann::json::exception& e) {
    throw InputError(where + ": " + json_detail(e));
  }
}

/// `input` (text or a stream) parsed, refusing documents nested deeper than kMaxJsonDepth with
/// `Err` "<where>: invalid JSON (nested deeper than 64 levels)"; the JSON library's own errors
/// (syntax, a number beyond double's range such as 1e400) become `Err` "<where>: invalid JSON
/// (<detail>)". Every parser of JSON text in the library goes through it.
template <typename Err = InputError, typename Input>
nlohmann::json parse_json(Input&& input, const std::string& where) {
  const auto depth_limit = [&where](int depth, nlohmann::json::parse_event_t, nlohmann::json&) {
    if (depth > kMaxJsonDepth)
      throw Err(where + ": invalid JSON (nested deeper than " + std::to_string(kMaxJsonDepth) +
                " levels)");
    return true;
  };
  try {
    return nlohmann::json::parse(std::forward<Input>(input), depth_limit);
  } catch (const nlohmann::json::exception& e) {
    throw Err(where + ": invalid JSON (" + json_detail(e) + ")");
  }
}

/// Whether a failure to open the file names the system's reason.
enum class OpenErrorReason { Omit, Append };

/// `path` opened for reading, which errors call `what` (e.g. "poses"): FileError
/// "cannot open <what> '<path>'" when it cannot be opened (followed by ": " and strerror(errno)
/// with OpenErrorReason::Append) or ": it is a directory" (which an ifstream would open).
inline std::ifstream open_text_file(const std::string& path, const std::string& what,
                                    OpenErrorReason reason = OpenErrorReason::Omit) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec))
    throw FileError("cannot open " + what + " '" + path + "': it is a directory");
  std::ifstream in(path);
  if (!in) {
    const int err = errno;
    std::string message = "cannot open " + what + " '" + path + "'";
    if (reason == OpenErrorReason::Append) message += std::string(": ") + std::strerror(err);
    throw FileError(message);
  }
  return in;
}

/// The JSON document in `path` (open_text_file's errors), or FileError
/// "<what> '<path>': invalid JSON (<detail>)" when it does not parse.
inline nlohmann::json read_json_file(const std::string& path, const std::string& what,
                                     OpenErrorReason reason = OpenErrorReason::Omit) {
  std::ifstream in = open_text_file(path, what, reason);
  return parse_json<FileError>(in, what + " '" + path + "'");
}

}  // namespace sonoslice
