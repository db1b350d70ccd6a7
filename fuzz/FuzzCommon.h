#pragma once
// Shared by the libFuzzer harnesses (fuzz/README.md): the input as a file with the extension the
// parser dispatches on, and the rule for what counts as a finding.
//
// A sonoslice::Error (InputError, FileError, ResourceError, ...) is the expected answer to bad
// input. Anything else escaping the library is a finding and aborts: a crash or sanitizer report
// of course, but also a foreign exception (a JSON library's, std::out_of_range from a stoi,
// std::length_error from an absurd size): those reach users as a message that does not name the
// file.
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <functional>
#include <string>
#include <typeinfo>

#include "sonoslice/core/Error.h"
#include "sonoslice/volume/Volume.h"

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

// The input being run (for SONOSLICE_FUZZ_FOREIGN_DIR below).
struct CurrentInput {
  const uint8_t* data = nullptr;
  size_t size = 0;
};
inline CurrentInput& current_input() {
  static CurrentInput input;
  return input;
}
inline void remember_input(const uint8_t* data, size_t size) {
  current_input() = {data, size};
}

// Writes the fuzz input to `<work_dir>/<name>` and returns the path.
inline std::string write_input(const uint8_t* data, size_t size, const std::string& name) {
  remember_input(data, size);
  const std::string path = (work_dir() / name).string();
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) std::abort();
  if (size && std::fwrite(data, 1, size, f) != size) std::abort();
  std::fclose(f);
  return path;
}

inline void quiet(const std::string&) {}

// Reads every byte a reader returned: a reader that hands back fewer bytes than its header claims
// is then an AddressSanitizer report, not a silent over-read later in a kernel.
inline void touch(const void* data, size_t size) {
  const auto* bytes = static_cast<const uint8_t*>(data);
  uint8_t sum = 0;
  for (size_t i = 0; i < size; ++i) sum ^= bytes[i];
  volatile uint8_t keep = sum;
  (void)keep;
}
inline void touch(const Volume& volume) {
  touch(volume.data(), volume.byte_size());
}

// A foreign exception aborts: a finding. With SONOSLICE_FUZZ_FOREIGN_DIR set (long runs that
// should look past a known one), each kind of exception has its first
// input saved there as foreign-<hash> (with the kind in foreign-<hash>.txt), and the run carries
// on.
inline void foreign_exception(const char* type, const std::string& what) {
  const char* dir = std::getenv("SONOSLICE_FUZZ_FOREIGN_DIR");
  if (!dir) {
    std::fprintf(stderr, "\nFOREIGN EXCEPTION (%s, not a sonoslice::Error): %s\n", type,
                 what.c_str());
    std::abort();
  }
  // The kind: the type and the message up to its first quoted value, without digits.
  std::string kind = std::string(type) + ": ";
  for (char c : what.substr(0, std::min<size_t>(80, what.find_first_of("'\""))))
    if (!(c >= '0' && c <= '9')) kind += c;
  // One file per kind across processes (libFuzzer's fork mode runs many): created only once.
  char name[32];
  std::snprintf(name, sizeof name, "/foreign-%016zx", std::hash<std::string>()(kind));
  const std::string path = std::string(dir) + name;
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL, 0644);
  if (fd < 0) return;
  [[maybe_unused]] const ssize_t written = ::write(fd, current_input().data, current_input().size);
  ::close(fd);
  std::fprintf(stderr, "\nFOREIGN EXCEPTION (%s, not a sonoslice::Error): %s (input saved as %s)\n",
               type, what.c_str(), path.c_str());
  if (std::FILE* f = std::fopen((path + ".txt").c_str(), "w")) {
    std::fprintf(f, "%s\n", kind.c_str());
    std::fclose(f);
  }
}

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
    foreign_exception(typeid(e).name(), e.what());
  } catch (...) {
    foreign_exception("unknown type", "");
  }
}

}  // namespace fuzz
}  // namespace sonoslice
