// Surface meshes: reading, voxelising, exact plane-cut label images, colour images, fan-slicer's
// surface configurations.
#include <nanobind/stl/array.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <memory>

#include "bindings.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/surface/Colorize.h"
#include "sonoslice/surface/Mesh.h"
#include "sonoslice/surface/SurfaceConfig.h"
#include "sonoslice/surface/SurfaceSlicer.h"
#include "sonoslice/surface/Voxelize.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;

constexpr int kCpu = nb::device::cpu::value;

// (N, H, W) label images from exact plane cuts, into a CPU array, chunk by chunk.
void surface_slice_into(const SurfaceSlicer& slicer, Matrices pose_array, nb::ndarray<> out,
                        nb::object progress, int64_t chunk) {
  const std::vector<Pose> poses = matrices_from(pose_array);
  const int64_t n = int64_t(poses.size());
  if (!has_shape(out, n, slicer.height(), slicer.width()) || !c_contiguous(out) ||
      out.device_type() != kCpu)
    throw InputError("out: expected a C-contiguous " +
                     shape_text(n, slicer.height(), slicer.width()) + " array in host memory");
  check_out_dtype(out, slicer.output_type());
  auto* base = static_cast<char*>(out.data());
  const size_t image_bytes =
      size_t(slicer.width()) * size_t(slicer.height()) * pixel_size(slicer.output_type());
  slice_in_chunks(poses, progress, chunk, [&](int64_t first, int64_t count) {
    slicer.slice(poses.data() + first, size_t(count), base + size_t(first) * image_bytes,
                 size_t(first));
  });
}

// The column counts are checked here (not by a typed shape) so that a wrong one is a ValueError
// naming the mesh, as the rest of the mesh checks (TriangleMesh::validate) are.
TriangleMesh mesh_from_arrays(
    nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu> vertices,
    nb::ndarray<const int32_t, nb::ndim<2>, nb::c_contig, nb::device::cpu> triangles,
    const std::string& name) {
  if (vertices.shape(1) != 3 || triangles.shape(1) != 3)
    throw InputError("mesh '" + name + "': vertices must be (V, 3) and triangles (T, 3)");
  TriangleMesh m;
  m.name = name;
  m.vertices.resize(vertices.shape(0));
  for (size_t i = 0; i < m.vertices.size(); ++i)
    m.vertices[i] = {vertices(i, 0), vertices(i, 1), vertices(i, 2)};
  m.triangles.resize(triangles.shape(0));
  for (size_t i = 0; i < m.triangles.size(); ++i)
    m.triangles[i] = {triangles(i, 0), triangles(i, 1), triangles(i, 2)};
  m.validate();
  return m;
}

}  // namespace

void bind_surfaces(nb::module_& m) {
  m.def("built_with_vtk", &built_with_vtk);
  nb::class_<TriangleMesh>(m, "Mesh")
      .def_static("from_arrays", &mesh_from_arrays, "vertices"_a, "triangles"_a, "name"_a = "mesh")
      .def_static(
          "from_file",
          [](const std::string& path, const std::string& world) {
            const WorldFrame f = parse_world_frame(world);
            nb::gil_scoped_release release;
            return read_mesh(path, f);
          },
          "path"_a, "world"_a = "LPS")
      .def("save",
           [](const TriangleMesh& mesh, const std::string& path) { write_mesh(path, mesh); })
      .def_prop_ro("name", [](const TriangleMesh& mesh) { return mesh.name; })
      .def("vertices",
           [](const TriangleMesh& mesh) {
             auto keep = std::make_shared<std::vector<Vec3>>(mesh.vertices);
             return numpy_view(keep->data(), {keep->size(), 3}, PixelType::Float64, keep);
           })
      .def("triangles",
           [](const TriangleMesh& mesh) {
             auto keep = std::make_shared<std::vector<std::array<int32_t, 3>>>(mesh.triangles);
             return numpy_view(keep->data(), {keep->size(), 3}, PixelType::Int32, keep);
           })
      .def("bounds", &TriangleMesh::bounds)
      .def("closed", [](const TriangleMesh& mesh) { return mesh_topology(mesh).closed(); })
      .def("topology", [](const TriangleMesh& mesh) { return mesh_topology(mesh).describe(); });

  m.def("voxel_grid_around", &voxel_grid_around, "meshes"_a, "spacing"_a, "margin"_a);
  m.def(
      "voxelize",
      [](const std::vector<TriangleMesh>& meshes, double spacing, double margin,
         const Volume* reference, const std::vector<uint16_t>& labels) {
        nb::gil_scoped_release release;
        const VolumeGrid g =
            reference ? reference->grid() : voxel_grid_around(meshes, spacing, margin);
        return voxelize(meshes, g, labels);
      },
      "meshes"_a, "spacing"_a = 0.0, "margin"_a = 0.0, "reference"_a = nb::none(),
      "labels"_a = std::vector<uint16_t>{});

  nb::class_<SurfaceSlicer>(m, "SurfaceSlicer")
      .def(
          "__init__",
          [](SurfaceSlicer* self, const std::vector<TriangleMesh>& meshes,
             const ProbeGeometry& probe, const std::vector<uint16_t>& labels,
             const std::string& dtype) {
            const PixelType t = parse_pixel_type(dtype);  // SurfaceSlicer says which it makes
            nb::gil_scoped_release release;
            new (self) SurfaceSlicer(meshes, probe, labels, t);
          },
          "meshes"_a, "probe"_a, "labels"_a = std::vector<uint16_t>{}, "dtype"_a = "uint8")
      .def("slice_into", &surface_slice_into, "poses"_a, "out"_a, "progress"_a = nb::none(),
           "chunk"_a = 0)
      .def_prop_ro("width", &SurfaceSlicer::width)
      .def_prop_ro("height", &SurfaceSlicer::height)
      .def_prop_ro("dtype", [](const SurfaceSlicer& s) { return to_string(s.output_type()); })
      .def("mask", [](const SurfaceSlicer& s) {
        auto mk = std::make_shared<std::vector<uint8_t>>(s.mask());
        return numpy_view(mk->data(), {size_t(s.height()), size_t(s.width())}, PixelType::UInt8,
                          mk);
      });

  m.def(
      "cut_polygons",
      [](const TriangleMesh& mesh, Matrices pose) {
        const std::vector<Pose> poses = matrices_from(pose);
        if (poses.size() != 1) throw InputError("cut_polygons: one pose");
        std::vector<std::pair<std::vector<std::array<double, 2>>, bool>> out;
        for (const CutPolygon& p : cut_polygons(mesh, poses[0]))
          out.emplace_back(p.points, p.closed);
        return out;
      },
      "mesh"_a, "pose"_a);
  m.def(
      "colorize",
      [](nb::ndarray<> labels, Mask mask, const std::vector<std::array<uint8_t, 3>>& colors) {
        if (labels.ndim() != 3 || !c_contiguous(labels) || labels.device_type() != kCpu)
          throw InputError("labels: expected a C-contiguous (N, H, W) array in host memory");
        const PixelType t = pixel_type_of(labels.dtype(), "labels");
        if (mask.shape(0) != labels.shape(1) || mask.shape(1) != labels.shape(2))
          throw InputError("mask: must be (H, W) like the labels");
        auto rgb = std::make_shared<std::vector<uint8_t>>(labels.size() * 3);
        {
          nb::gil_scoped_release release;
          colorize(labels.data(), t, int64_t(labels.shape(0)), int(labels.shape(2)),
                   int(labels.shape(1)), mask.data(), colors, rgb->data());
        }
        return numpy_view(rgb->data(), {labels.shape(0), labels.shape(1), labels.shape(2), 3},
                          PixelType::UInt8, rgb);
      },
      "labels"_a, "mask"_a, "colors"_a);
  m.def("default_label_color", &default_label_color, "label"_a);
  m.def(
      "fanslicer_models",
      [](const std::string& config, const std::string& mesh_dir) {
        std::vector<std::tuple<std::string, std::string, uint16_t, std::array<uint8_t, 3>>> out;
        for (const SurfaceModel& s : read_fanslicer_models(config, mesh_dir))
          out.emplace_back(s.name, s.path, s.label, s.color);
        return out;
      },
      "config"_a, "mesh_dir"_a);
}

}  // namespace sonoslice::bindings
