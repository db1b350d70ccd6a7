// sonoslice: ultrasound-shaped images from 3D medical data.
//
// Exit codes (README, "Exit codes"): 0 done; 1 bad input or a failure while running (one line
// "sonoslice: error: ..." naming the input); 2 a usage error: an unknown command or flag, a
// missing required flag, a value that is not of the flag's type (one line, nothing runs).
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"

namespace {

constexpr int kExitBadInput = 1;
constexpr int kExitUsage = 2;

void print_warning(const std::string& message) {
  std::fprintf(stderr, "sonoslice: warning: %s\n", message.c_str());
}

std::string join(const std::vector<std::string>& items, const std::string& separator) {
  std::string s;
  for (const std::string& item : items) s += (s.empty() ? "" : separator) + item;
  return s;
}

/// One line for a CLI11 parse error, naming what was wrong and where to look. CLI11 checks
/// required flags before unexpected ones, so a mistyped flag would otherwise be reported as the
/// required one it failed to set: unexpected arguments are named first.
// " live compound": the subcommands parsed, nested ones included ("" for none).
std::string command_path(CLI::App& app) {
  std::string path;
  for (CLI::App* sub = &app; !sub->get_subcommands().empty();) {
    sub = sub->get_subcommands().front();
    path += " " + sub->get_name();
  }
  return path;
}

std::string usage_error(CLI::App& app, const CLI::ParseError& e, int argc, char** argv) {
  const std::vector<CLI::App*> parsed = app.get_subcommands();
  std::vector<std::string> commands;
  for (CLI::App* sub : app.get_subcommands([](CLI::App*) { return true; }))
    commands.push_back(sub->get_name());
  if (parsed.empty() && argc > 1 && argv[1][0] != '-')
    return "unknown command '" + std::string(argv[1]) + "' (commands: " + join(commands, ", ") +
           "; see 'sonoslice --help')";
  if (parsed.empty() && e.get_name() == "RequiredError")
    return "give a command: " + join(commands, ", ") + " (see 'sonoslice --help')";
  std::string what = e.what();
  const std::vector<std::string> extra = app.remaining(true);
  if (!extra.empty() && e.get_name() == "RequiredError")
    what = "unexpected argument(s) " + join(extra, " ") + " (and " + what + ")";
  for (char& c : what)
    if (c == '\n') c = ' ';
  return what + "; see 'sonoslice" + command_path(app) + " --help'";
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "sonoslice: fast ultrasound-shaped slicing of CT/MRI volumes and freehand 3D reconstruction "
      "(CPU and CUDA)",
      "sonoslice"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("sonoslice ") + SONOSLICE_VERSION);
  app.footer(
      "Exit status: 0 done, 1 bad input or a failure (one line naming the input), 2 a usage "
      "error.");
  sonoslice::cli::add_slice_command(app);
  sonoslice::cli::add_info_command(app);
  sonoslice::cli::add_phantom_command(app);
  sonoslice::cli::add_demo_command(app);
  sonoslice::cli::add_voxelize_command(app);
  sonoslice::cli::add_compound_command(app);
  sonoslice::cli::add_simulate_command(app);
  sonoslice::cli::add_register_command(app);
  sonoslice::cli::add_poses_command(app);
  sonoslice::cli::add_dataset_command(app);
  sonoslice::cli::add_live_command(app);
  sonoslice::cli::add_view_command(app);
  sonoslice::cli::add_bench_command(app);
  sonoslice::set_warning_handler(&print_warning);
  // Ctrl-C, SIGTERM or a file-size limit mid-write: the half-written temporaries go, good outputs
  // stay.
  sonoslice::install_output_cleanup_on_signals();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);  // --help, --version
    std::fprintf(stderr, "sonoslice: error: %s\n", usage_error(app, e, argc, argv).c_str());
    return kExitUsage;
  } catch (const sonoslice::cli::UsageError& e) {
    std::fprintf(stderr, "sonoslice: error: %s; see 'sonoslice%s --help'\n", e.what(),
                 command_path(app).c_str());
    return kExitUsage;
  } catch (const sonoslice::ParameterError& e) {
    // A library parameter, said as the flag that sets it.
    std::fprintf(stderr, "sonoslice: error: %s %s\n",
                 sonoslice::cli::flag_of(e.parameter()).c_str(), e.detail().c_str());
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "sonoslice: error: out of memory\n");
    return kExitBadInput;
  } catch (const std::exception& e) {
    // One line, naming the input (every sonoslice error message does).
    std::fprintf(stderr, "sonoslice: error: %s\n", e.what());
    return kExitBadInput;
  }
  return 0;
}
