// sonoslice dataset SPEC --out DIR: hands over to the Python package (sonoslice.datasets.writer),
// where the shards are written with tarfile and scaled out on Dask (docs/datasets.md). The
// arguments pass through unchanged; Python's exit status is this command's.
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "Commands.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace cli {
namespace {

/// Imports the package's entry point; a Python without sonoslice says so in one line.
constexpr const char* kBootstrap =
    "import sys\n"
    "try:\n"
    "    from sonoslice.__main__ import main\n"
    "except ImportError as e:\n"
    "    sys.stderr.write('sonoslice: error: dataset runs in the sonoslice Python package, which "
    "'\n"
    "                     '%s cannot import (%s): install it (bash scripts/install-python.sh) or "
    "'\n"
    "                     'set SONOSLICE_PYTHON to a Python that has it\\n' % (sys.executable, "
    "e))\n"
    "    sys.exit(1)\n"
    "sys.exit(main(['dataset'] + sys.argv[1:]))\n";

/// SONOSLICE_PYTHON, else the build's virtual environment, else python3 on the PATH.
std::string python_executable() {
  if (const char* env = std::getenv("SONOSLICE_PYTHON"); env && *env) return env;
#ifdef SONOSLICE_BUILD_PYTHON
  if (access(SONOSLICE_BUILD_PYTHON, X_OK) == 0) return SONOSLICE_BUILD_PYTHON;
#endif
  return "python3";
}

void run_dataset(const std::vector<std::string>& args) {
  const std::string python = python_executable();
  std::vector<std::string> argv = {python, "-c", kBootstrap};
  argv.insert(argv.end(), args.begin(), args.end());
  std::vector<char*> c_argv;
  for (std::string& a : argv) c_argv.push_back(a.data());
  c_argv.push_back(nullptr);
  std::fflush(nullptr);
  execvp(python.c_str(), c_argv.data());
  throw InputError("dataset: cannot run Python '" + python + "' (" + std::strerror(errno) +
                   "): set SONOSLICE_PYTHON to a Python with the sonoslice package");
}

}  // namespace

void add_dataset_command(CLI::App& app) {
  auto args = std::make_shared<std::vector<std::string>>();
  CLI::App* cmd = app.add_subcommand(
      "dataset",
      "Write a sharded dataset from a SPEC (YAML/JSON): sonoslice dataset SPEC --out DIR "
      "[--dry-run] [--scheduler local:N|tcp://HOST:PORT] (docs/datasets.md; runs in Python)");
  // Everything after `dataset` goes to Python unparsed (its --help included).
  cmd->prefix_command();
  cmd->set_help_flag();
  cmd->allow_extras();
  cmd->callback([cmd, args] {
    *args = cmd->remaining();
    run_dataset(*args);
  });
}

}  // namespace cli
}  // namespace sonoslice
