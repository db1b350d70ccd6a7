#include "sonoslice/io/AtomicFile.h"

#include <sys/statvfs.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "sonoslice/core/Error.h"

namespace fs = std::filesystem;

namespace sonoslice {
namespace {
std::atomic<int> g_counter{0};

fs::path parent_of(const std::string& path) {
  fs::path parent = fs::path(path).parent_path();
  return parent.empty() ? fs::path(".") : parent;
}
}  // namespace

void check_output_path(const std::string& path, bool directory) {
  if (path.empty()) throw FileError("output path is empty");
  const fs::path parent = parent_of(path);
  std::error_code ec;
  if (!fs::is_directory(parent, ec))
    throw FileError("cannot write '" + path + "': directory '" + parent.string() +
                    "' does not exist");
  if (::access(parent.c_str(), W_OK) != 0)
    throw FileError("cannot write '" + path + "': directory '" + parent.string() +
                    "' is not writable (" + std::strerror(errno) + ")");
  if (!directory && fs::is_directory(path, ec))
    throw FileError("cannot write '" + path + "': it is an existing directory");
  if (directory && fs::exists(path, ec) && !fs::is_directory(path, ec))
    throw FileError("cannot write directory '" + path + "': a file of that name exists");
}

AtomicFile::AtomicFile(std::string path, bool directory)
    : path_(std::move(path)), directory_(directory) {
  check_output_path(path_, directory_);
  const fs::path p(path_);
  temp_ = (parent_of(path_) / (".tmp-sonoslice-" + std::to_string(::getpid()) + "-" +
                               std::to_string(g_counter++) + "." + p.filename().string()))
              .string();
  if (directory_) {
    std::error_code ec;
    fs::create_directory(temp_, ec);
    if (ec) throw FileError("cannot create '" + temp_ + "': " + ec.message());
  }
}

AtomicFile::~AtomicFile() {
  if (committed_) return;
  std::error_code ec;
  fs::remove_all(temp_, ec);  // never throw from a destructor
}

void AtomicFile::commit() {
  std::error_code ec;
  if (!fs::exists(temp_, ec)) throw FileError("cannot write '" + path_ + "': nothing was written");
  if (directory_ && fs::exists(path_, ec)) {
    // rename() cannot replace a non-empty directory: move the old one aside first.
    const std::string old = temp_ + ".old";
    fs::rename(path_, old, ec);
    if (ec) throw FileError("cannot replace '" + path_ + "': " + ec.message());
    fs::rename(temp_, path_, ec);
    if (ec) {
      std::error_code ignored;
      fs::rename(old, path_, ignored);
      throw FileError("cannot write '" + path_ + "': " + ec.message());
    }
    fs::remove_all(old, ec);
  } else {
    fs::rename(temp_, path_, ec);
    if (ec) throw FileError("cannot write '" + path_ + "': " + ec.message());
  }
  committed_ = true;
}

void write_text_file(const std::string& path, const std::string& text) {
  AtomicFile file(path);
  {
    std::ofstream out(file.temp_path());
    out << text;
    if (!out) throw FileError("cannot write '" + path + "'");
  }
  file.commit();
}

unsigned long long free_disk_bytes(const std::string& path) {
  struct statvfs s;
  if (::statvfs(parent_of(path).c_str(), &s) != 0) return ~0ull;
  return static_cast<unsigned long long>(s.f_bavail) * s.f_frsize;
}

}  // namespace sonoslice
