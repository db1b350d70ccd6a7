#pragma once
// Shared by the libFuzzer harnesses (fuzz/README.md): the input as a file with the extension the
// parser dispatches on, and the rule for what counts as a finding.
//
// A sonoslice::Error (InputError, FileError, ResourceError, ...) is the expected answer to bad
// input. Anything else escaping the library is a finding and aborts: a crash or sanitizer report
// of course, but also a foreign exception (a JSON library's, std::out_of_range from a stoi,
// std::length_error from an absurd size): those reach users as a message that does not name the
// file (issue 10).
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>
#include <typeinfo>

#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace fuzz {

// One folder per process under $TMPDIR (scripts/fuzz.sh points it into build-fuzz/); the input
// file is rewritten for every run.
inline const std::filesystem::path& work_dir() {
  static const std::filesystem::path dir = [] {
    std::error_code ec;
    std::filesystem::path d = std::filesystem::temp_directory_path(ec);
    if (ec) d = "/tmp";
    d /= "sonoslice-fuzz-" + std::to_string(::getpid());
    std::filesystem::create_directories(d);
    return d;
  }();
  return dir;
}

// Writes the fuzz input to `<work_dir>/<name>` and returns the path.
inline std::string write_input(const uint8_t* data, size_t size, const std::string& name) {
  const std::string path = (work_dir() / name).string();
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) std::abort();
  if (size && std::fwrite(data, 1, size, f) != size) std::abort();
  std::fclose(f);
  return path;
}

inline bool starts_with(const uint8_t* data, size_t size, const char* magic) {
  const std::string m(magic);
  return size >= m.size() && std::string(reinterpret_cast<const char*>(data), m.size()) == m;
}

inline void quiet(const std::string&) {}

// Runs `parse`; returns normally for no error or a sonoslice::Error, aborts (a finding) otherwise.
template <typename F>
void expect_sonoslice_errors_only(F&& parse) {
  static const bool once = (set_warning_handler(&quiet), true);
  (void)once;
  try {
    parse();
  } catch (const Error&) {
    // The expected refusal of bad input.
  } catch (const std::exception& e) {
    std::fprintf(stderr, "\nFOREIGN EXCEPTION (%s, not a sonoslice::Error): %s\n", typeid(e).name(),
                 e.what());
    std::abort();
  } catch (...) {
    std::fprintf(stderr, "\nFOREIGN EXCEPTION of unknown type\n");
    std::abort();
  }
}

}  // namespace fuzz
}  // namespace sonoslice
