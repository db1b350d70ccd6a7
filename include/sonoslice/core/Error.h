#pragma once
/// @file Error types of sonoslice. Every error owns a message that names the offending input
/// (file, value, index); library code never exits or prints and continues.
#include <functional>
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

/// An InputError about one named parameter of a library function ("spacing_mm", "threads"):
/// the message reads "<parameter> <detail>". Front ends that spell the parameter otherwise (the
/// CLI's --spacing) rebuild the message from parameter() and detail().
class ParameterError : public InputError {
 public:
  ParameterError(std::string parameter, std::string detail)
      : InputError(parameter + " " + detail),
        parameter_(std::move(parameter)),
        detail_(std::move(detail)) {}
  const std::string& parameter() const { return parameter_; }
  const std::string& detail() const { return detail_; }

 private:
  std::string parameter_, detail_;
};

/// How a front end spells the library's parameters (settings) in messages: given the library's
/// name (snake_case, as the settings' fields and Python's keywords: "metric", "frequency_mhz"),
/// the front end's ("--metric", "--frequency"). Empty: the library's own names.
using ParameterNames = std::function<std::string(const std::string& parameter)>;

/// `parameter` as `names` spells it; `parameter` itself when `names` is empty.
inline std::string spelled(const ParameterNames& names, const std::string& parameter) {
  return names ? names(parameter) : parameter;
}

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
