// sonoslice: ultrasound-shaped images from 3D medical data.
#include <cstdio>
#include <exception>
#include <string>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"

namespace {
void print_warning(const std::string& message) {
  std::fprintf(stderr, "sonoslice: warning: %s\n", message.c_str());
}
}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "sonoslice: fast ultrasound-shaped slicing of CT/MRI volumes and freehand 3D reconstruction "
      "(CPU and CUDA)",
      "sonoslice"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("sonoslice ") + SONOSLICE_VERSION);
  sonoslice::cli::add_slice_command(app);
  sonoslice::cli::add_info_command(app);
  sonoslice::cli::add_phantom_command(app);
  sonoslice::cli::add_demo_command(app);
  sonoslice::cli::add_voxelize_command(app);
  sonoslice::cli::add_compound_command(app);
  sonoslice::cli::add_bench_command(app);
  sonoslice::set_warning_handler(&print_warning);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const sonoslice::ParameterError& e) {
    // A library parameter, said as the flag that sets it.
    std::fprintf(stderr, "sonoslice: error: %s %s\n",
                 sonoslice::cli::flag_of(e.parameter()).c_str(), e.detail().c_str());
    return 1;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "sonoslice: error: out of memory\n");
    return 1;
  } catch (const std::exception& e) {
    // One line, naming the input (every sonoslice error message does).
    std::fprintf(stderr, "sonoslice: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
