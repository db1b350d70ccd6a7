// sonoslice view: a local web page showing a volume's planes, meshes, probe poses and the image at
// each pose (docs/view.md). Parses the flags, reads the inputs and hands them to the viewer.
#include <algorithm>
#include <cstdio>
#include <cstring>
#include <memory>

#include "Commands.h"
#include "Common.h"
#include "ViewFlags.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/simulate/Simulator.h"
#include "sonoslice/surface/SurfaceConfig.h"

namespace sonoslice {
namespace cli {
namespace {

struct ViewFlags {
  VolumeFlags volume;
  std::string labels, mesh_dir, probe, poses, images, compound, world = "LPS";
  std::vector<std::string> meshes;
  std::string host = "127.0.0.1";
  int port = 0, downsampling = 1;
  std::optional<int> threads;
  bool no_browser = false, simulate = false;
};

Volume read_labels(const std::string& path, const VolumeReadOptions& options) {
  Volume v = read_volume(path, options);
  if (v.pixel_type() != PixelType::UInt8 && v.pixel_type() != PixelType::UInt16)
    throw InputError("--labels '" + path + "': a label volume is uint8 or uint16, this one is " +
                     to_string(v.pixel_type()));
  return v;
}

void run_view(const ViewFlags& f) {
  // Checked before anything loads; out of range is bad input (1), as `live --view` says it.
  if (f.port < 0 || f.port > 65535)
    throw InputError("--port " + std::to_string(f.port) + ": expected a port 0-65535");
  setup_threads(f.threads);
  if (!f.volume.path.empty() && !f.compound.empty())
    throw UsageError("view: give --volume or --compound, not both (the planes show one volume)");
  if (!f.meshes.empty() && !f.mesh_dir.empty())
    throw UsageError("view: give --meshes or --mesh-dir, not both");
  if (!f.mesh_dir.empty() && f.probe.empty())
    throw UsageError("--mesh-dir: the fan-slicer configuration (--probe) names the meshes");
  if (f.poses.empty() != f.probe.empty() && f.images.empty())
    throw UsageError("view: --probe and --poses go together");
  if (!f.images.empty() && (f.probe.empty() || f.poses.empty()))
    throw UsageError("--images: give the --probe and --poses the images were taken with");
  if (f.simulate && (f.probe.empty() || (f.volume.path.empty() && f.labels.empty())))
    throw UsageError("--simulate: give a --probe and the --volume (CT) or --labels to simulate");
  if (f.simulate && !f.images.empty()) throw UsageError("give --simulate or --images, not both");
  if (f.volume.path.empty() && f.labels.empty() && f.compound.empty() && f.meshes.empty() &&
      f.mesh_dir.empty() && f.poses.empty())
    throw UsageError("view: nothing to show (give --volume, --labels, --meshes, --poses, ...)");
  if (f.host.empty() || f.host.find_first_of(" /") != std::string::npos)
    throw InputError("--host '" + f.host + "': expected an address (127.0.0.1, 0.0.0.0, a name)");
  const WorldFrame world = parse_world_frame(f.world);

  ViewContent c;
  // Small files first, so a typo fails before a CT is read.
  if (!f.probe.empty()) c.probe = read_probe(f.probe, f.downsampling);
  if (!f.poses.empty()) c.poses = read_poses(f.poses, world);
  if (!f.mesh_dir.empty()) {
    for (const SurfaceModel& m : read_fanslicer_models(f.probe, f.mesh_dir))
      c.meshes.push_back({read_mesh(m.path, world), m.color});
  }
  for (size_t k = 0; k < f.meshes.size(); ++k)
    c.meshes.push_back({read_mesh(f.meshes[k], world), default_label_color(int(k + 1))});
  if (!f.volume.path.empty() || !f.compound.empty()) {
    c.volume_name = f.volume.path.empty() ? f.compound : f.volume.path;
    c.volume = read_volume(c.volume_name, f.volume.options());
  }
  if (!f.labels.empty()) {
    c.labels = read_labels(f.labels, f.volume.options());
    c.labels_name = f.labels;
    const int top = int(std::min(c.labels->value_range().second, 65535.0));
    for (int k = 1; k <= top; ++k) c.label_colors.push_back(default_label_color(k));
  }
  c.title = !c.volume_name.empty() ? c.volume_name : !f.labels.empty() ? f.labels : "sonoslice";

  // The image at a pose: the stack's, else sliced as `sonoslice slice` slices (its defaults).
  std::shared_ptr<Slicer> slicer;
  if (!f.images.empty()) {
    auto stack = std::make_shared<Volume>(read_image_stack(f.images, "--images"));
    const auto& d = stack->grid().dims;
    if (d[0] != c.probe->image.width || d[1] != c.probe->image.height ||
        d[2] != int64_t(c.poses.size()))
      throw InputError("--images '" + f.images + "': " + std::to_string(d[2]) + " images of " +
                       std::to_string(d[0]) + "x" + std::to_string(d[1]) +
                       ", but the probe's are " + std::to_string(c.probe->image.width) + "x" +
                       std::to_string(c.probe->image.height) + " and there are " +
                       std::to_string(c.poses.size()) + " poses");
    const size_t pixels = size_t(d[0] * d[1]);
    c.image_source = "images";
    c.render = [stack, pixels](const Pose&, int64_t index, float* out) {
      if (index < 0) throw InputError("--images: the stack has images at its own poses only");
      const uint8_t* base = static_cast<const uint8_t*>(stack->data()) +
                            size_t(index) * pixels * pixel_size(stack->pixel_type());
      for_each_value(base, stack->pixel_type(), pixels,
                     [out](size_t i, double v) { out[i] = float(v); });
    };
  } else if (f.simulate) {
    // As `sonoslice simulate` at its defaults: the source (CT or labels) guessed from the volume.
    const Volume& source = c.volume ? *c.volume : *c.labels;
    auto sim = std::make_shared<Simulator>(source, default_simulation_source(source, false),
                                           *c.probe, default_tissues());
    auto bytes = std::make_shared<std::vector<uint8_t>>(sim->image_bytes());
    const PixelType type =
        sim->settings().output == SimulationOutput::BMode ? PixelType::UInt8 : PixelType::Float32;
    c.image_source = "simulate";
    if (type == PixelType::UInt8) c.image_window = std::make_pair(127.5, 255.0);
    c.render = [sim, bytes, type](const Pose& pose, int64_t, float* out) {
      sim->simulate(&pose, 1, bytes->data());
      for_each_value(bytes->data(), type, size_t(sim->probe().image.pixel_count()),
                     [out](size_t i, double v) { out[i] = float(v); });
    };
  } else if (c.probe && (c.volume || c.labels)) {
    SliceSettings settings;
    if (!c.volume) settings.interpolation = Interpolation::Nearest;  // labels stay labels
    slicer = std::make_shared<Slicer>(c.volume ? *c.volume : *c.labels, *c.probe, settings);
    c.image_source = "slice";
    c.render = [slicer](const Pose& pose, int64_t, float* out) { slicer->slice(&pose, 1, out); };
  }

  const auto server =
      start_view("sonoslice view", std::move(c), f.host + ":" + std::to_string(f.port));
  if (!f.no_browser && !open_in_browser(server->url()))
    std::fprintf(stderr, "sonoslice view: open %s in a browser (no desktop browser found)\n",
                 server->url().c_str());
  wait_for_interrupt();
}

}  // namespace

void add_view_command(CLI::App& app) {
  auto f = std::make_shared<ViewFlags>();
  CLI::App* cmd = app.add_subcommand(
      "view", "A browser viewer of volumes, labels, meshes, probe poses and images (docs/view.md)");
  f->volume.add_to(*cmd, /*path_required=*/false);
  cmd->add_option("--labels", f->labels, "A label volume (uint8/uint16), drawn over the planes");
  cmd->add_option("--meshes", f->meshes, "Surface meshes, in `slice --colors`' colours");
  cmd->add_option("--mesh-dir", f->mesh_dir,
                  "Folder of the meshes the fan-slicer configuration (--probe) names");
  cmd->add_option("--probe", f->probe, "Probe JSON (native or fan-slicer config)");
  cmd->add_option("--poses", f->poses, "Pose file: .npy, .txt/.csv, .json");
  cmd->add_option("--images", f->images,
                  "A stack of images at the poses (.npy (N,H,W), .nii, .mha, .nrrd, a multi-frame "
                  "DICOM .dcm, a folder of PNGs) shown instead "
                  "of slicing");
  cmd->add_option("--compound", f->compound, "A compounded volume, shown in the planes");
  cmd->add_flag(
      "--simulate", f->simulate,
      "The image at a pose is simulated ultrasound (`simulate`'s defaults), not the slice");
  cmd->add_option("--world", f->world, "Frame of the poses and meshes: LPS (default) or RAS");
  cmd->add_option("--downsampling", f->downsampling, "Divide the probe image size by K");
  cmd->add_option("--host", f->host, "Address to serve on (127.0.0.1)");
  cmd->add_option("--port", f->port, "Port (default: a free one)");
  cmd->add_flag("--no-browser", f->no_browser, "Do not open a browser");
  add_threads_option(*cmd, f->threads);
  cmd->callback([f] { run_view(*f); });
}

}  // namespace cli
}  // namespace sonoslice
