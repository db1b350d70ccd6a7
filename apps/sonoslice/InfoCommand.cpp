// sonoslice info: what a volume file holds (geometry, pixel type, value range), and devices.
#include <cstdio>
#include <filesystem>
#include <memory>

#include <nlohmann/json.hpp>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/core/Memory.h"

namespace sonoslice {
namespace cli {
namespace {

struct InfoFlags {
  VolumeFlags volume;
  bool json = false, devices = false;
};

void run_info(const InfoFlags& f) {
  if (f.devices) {
    std::printf("%s", describe_devices().c_str());
    if (f.volume.path.empty()) return;
  }
  if (f.volume.path.empty()) throw UsageError("info: give a volume path (or --devices)");
  std::vector<DicomSeriesInfo> series;
  std::error_code ec;
  if (std::filesystem::is_directory(f.volume.path, ec)) series = list_dicom_series(f.volume.path);
  const Volume v = read_volume(f.volume.path, f.volume.options());
  const VolumeGrid& g = v.grid();
  const auto range = v.value_range();
  if (f.json) {
    nlohmann::json j;
    j["path"] = f.volume.path;
    j["dims"] = {g.dims[0], g.dims[1], g.dims[2]};
    j["spacing"] = {g.spacing_mm[0], g.spacing_mm[1], g.spacing_mm[2]};
    j["origin"] = {g.origin_mm[0], g.origin_mm[1], g.origin_mm[2]};
    j["direction"] = g.direction.row_major();
    j["pixel_type"] = to_string(v.pixel_type());
    j["value_range"] = {range.first, range.second};
    j["bytes"] = v.byte_size();
    if (!series.empty()) {
      j["dicom_series"] = nlohmann::json::array();
      for (const auto& s : series)
        j["dicom_series"].push_back({{"uid", s.uid}, {"files", s.file_count}});
    }
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf("file:        %s\n", f.volume.path.c_str());
  std::printf("dimensions:  %lld x %lld x %lld\n", static_cast<long long>(g.dims[0]),
              static_cast<long long>(g.dims[1]), static_cast<long long>(g.dims[2]));
  std::printf("spacing:     %.6g %.6g %.6g mm\n", g.spacing_mm[0], g.spacing_mm[1],
              g.spacing_mm[2]);
  std::printf("origin:      %.6g %.6g %.6g mm (LPS)\n", g.origin_mm[0], g.origin_mm[1],
              g.origin_mm[2]);
  std::printf(
      "direction:   [%.6g %.6g %.6g; %.6g %.6g %.6g; %.6g %.6g %.6g] (index axes as columns)\n",
      g.direction.m[0][0], g.direction.m[0][1], g.direction.m[0][2], g.direction.m[1][0],
      g.direction.m[1][1], g.direction.m[1][2], g.direction.m[2][0], g.direction.m[2][1],
      g.direction.m[2][2]);
  std::printf("pixel type:  %s\n", to_string(v.pixel_type()).c_str());
  std::printf("value range: %.6g .. %.6g\n", range.first, range.second);
  std::printf("memory:      %.1f MiB\n", double(v.byte_size()) / double(kMiB));
  for (const auto& s : series)
    std::printf("dicom series: %s (%zu files)\n", s.uid.c_str(), s.file_count);
}

}  // namespace

void add_info_command(CLI::App& app) {
  auto flags = std::make_shared<InfoFlags>();
  CLI::App* cmd =
      app.add_subcommand("info", "Print a volume's geometry, pixel type and value range");
  flags->volume.add_to(*cmd, /*path_required=*/false, "path");
  cmd->add_flag("--json", flags->json, "Machine-readable output");
  cmd->add_flag("--devices", flags->devices, "List compute devices");
  cmd->callback([flags] { run_info(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
