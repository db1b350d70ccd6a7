#pragma once
/// @file Outputs written under a temporary name in the destination's directory and renamed
/// into place when complete (docs/conventions.md §6): a failed run leaves no partial file and never
/// replaces good data with bad.
#include <string>

#include "sonoslice/core/Memory.h"

namespace sonoslice {

class AtomicFile {
 public:
  /// Checks up front that the destination's directory exists and is writable (FileError
  /// naming `path` otherwise). `directory`: the output is a directory (e.g. a PNG stack).
  explicit AtomicFile(std::string path, bool directory = false);
  ~AtomicFile();  ///< removes the temporary when commit() was not reached
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  /// Where to write: same directory and same file name ending as the destination (so
  /// extension-based writers such as ITK's pick the right format).
  const std::string& temp_path() const { return temp_; }
  const std::string& path() const { return path_; }

  /// Renames the temporary over the destination (replacing an existing file or directory).
  void commit();

 private:
  std::string path_, temp_;
  bool directory_, committed_ = false;
};

/// Writes a small text file atomically.
void write_text_file(const std::string& path, const std::string& text);

/// Throws FileError when `path` could not be created as an output (directory missing, not
/// writable, or `path` is an existing directory where a file is expected).
void check_output_path(const std::string& path, bool directory = false);

/// Free bytes on the filesystem that holds `path`'s directory.
unsigned long long free_disk_bytes(const std::string& path);

}  // namespace sonoslice
