#pragma once
/// @file Error types of sonoslice. Every error owns a message that names the offending input
/// (file, value, index); library code never exits or prints and continues.
#include <stdexcept>
#include <string>

namespace sonoslice {

/// Base class of all sonoslice errors.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Bad input value or shape: a pose, a probe key, a size, a dtype (Python: ValueError).
class InputError : public Error {
 public:
  using Error::Error;
};

/// A file that cannot be read or written: missing, corrupt, truncated, unwritable (Python:
/// OSError).
class FileError : public Error {
 public:
  using Error::Error;
};

/// A resource limit: memory, disk space, device memory (Python: RuntimeError).
class ResourceError : public Error {
 public:
  using Error::Error;
};

/// Where warnings go (default: "sonoslice: warning: ..." on stderr). The CLI and the Python
/// package install their own handler; library code never prints directly.
using WarningHandler = void (*)(const std::string& message);
void set_warning_handler(WarningHandler handler);
void warn(const std::string& message);

}  // namespace sonoslice
