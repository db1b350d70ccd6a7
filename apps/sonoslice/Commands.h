#pragma once
// Each subcommand registers its flags and callback on the top-level app.
#include <CLI/CLI.hpp>

namespace sonoslice {
namespace cli {
void add_slice_command(CLI::App& app);
void add_info_command(CLI::App& app);
void add_phantom_command(CLI::App& app);
void add_demo_command(CLI::App& app);
void add_bench_command(CLI::App& app);
void add_voxelize_command(CLI::App& app);
void add_compound_command(CLI::App& app);
void add_simulate_command(CLI::App& app);
void add_register_command(CLI::App& app);
void add_poses_command(CLI::App& app);
void add_dataset_command(CLI::App& app);
void add_live_command(CLI::App& app);
void add_view_command(CLI::App& app);
}  // namespace cli
}  // namespace sonoslice
