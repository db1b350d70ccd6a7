// Files: poses, image stacks and PNG bytes. Volumes, probes, meshes and beam geometries read and
// write through their own classes' from_file/save; PLUS toolkit files are plus.cpp.
#include <nanobind/stl/array.h>
#include <nanobind/stl/map.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "bindings.h"
#include "sonoslice/io/Png.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/StackWriter.h"
#include "sonoslice/io/VolumeFile.h"

namespace sonoslice::bindings {

using namespace nb::literals;

void bind_io(nb::module_& m) {
  // ---- PNG bytes (dataset shards), through libpng
  m.def(
      "encode_png",
      [](nb::ndarray<nb::c_contig, nb::device::cpu> image, std::array<double, 2> spacing_mm) {
        const bool rgb = image.ndim() == 3;
        if ((image.ndim() != 2 && !rgb) || (rgb && image.shape(2) != 3))
          throw InputError("encode_png: expected an (H, W) or (H, W, 3) image");
        PixelType type;
        if (image.dtype() == nb::dtype<uint8_t>())
          type = PixelType::UInt8;
        else if (image.dtype() == nb::dtype<uint16_t>())
          type = PixelType::UInt16;
        else
          throw InputError("encode_png: PNG holds uint8 or uint16 images");
        std::vector<uint8_t> bytes;
        {
          nb::gil_scoped_release release;
          bytes = encode_png(image.data(), type, int(image.shape(1)), int(image.shape(0)),
                             rgb ? 3 : 1, spacing_mm.data());
        }
        return nb::bytes(reinterpret_cast<const char*>(bytes.data()), bytes.size());
      },
      "image"_a, "spacing_mm"_a);
  m.def(
      "apply_window",
      [](nb::ndarray<float, nb::c_contig, nb::device::cpu> images, double level, double width) {
        if (!std::isfinite(level) || !(width > 0) || !std::isfinite(width))
          throw InputError("window: level and width must be finite and the width > 0");
        std::vector<size_t> shape(images.ndim());
        for (size_t k = 0; k < images.ndim(); ++k) shape[k] = images.shape(k);
        auto out = std::make_shared<std::vector<uint8_t>>(images.size());
        {
          nb::gil_scoped_release release;
          apply_window(images.data(), PixelType::Float32, images.size(), level, width, out->data());
        }
        return numpy_view(out->data(), shape, PixelType::UInt8, out);
      },
      "images"_a, "level"_a, "width"_a,
      "float32 images to uint8 through the window (level, width), as `slice --window` writes "
      "PNGs.");
  m.def(
      "decode_png",
      [](nb::bytes data) {
        DecodedPng png;
        {
          nb::gil_scoped_release release;
          png = decode_png(reinterpret_cast<const uint8_t*>(data.c_str()), data.size(), "PNG");
        }
        auto pixels = std::make_shared<std::vector<uint8_t>>(std::move(png.pixels));
        std::vector<size_t> shape = {size_t(png.height), size_t(png.width)};
        if (png.components == 3) shape.push_back(3);
        return numpy_view(pixels->data(), shape,
                          png.bit_depth == 16 ? PixelType::UInt16 : PixelType::UInt8, pixels);
      },
      "data"_a);
  // ---- poses and image stacks
  m.def(
      "read_poses",
      [](const std::string& path, const std::string& world) {
        return matrices_to_numpy(read_poses(path, parse_world_frame(world)));
      },
      "path"_a, "world"_a = to_string(WorldFrame::LPS));
  m.def(
      "write_poses",
      [](const std::string& path, Matrices a) {
        const std::vector<Pose> poses = matrices_from(a);
        if (file_extension(path) == ".npy")
          write_poses_npy(path, poses);
        else
          write_poses_text(path, poses);
      },
      "path"_a, "poses"_a);
  m.def(
      "read_stack",
      [](const std::string& path) {
        auto stack = std::make_shared<Volume>();
        {
          nb::gil_scoped_release release;
          *stack = read_image_stack(path, "stack");
        }
        const auto& d = stack->grid().dims;
        return numpy_view(stack->data(), {size_t(d[2]), size_t(d[1]), size_t(d[0])},
                          stack->pixel_type(), stack);
      },
      "path"_a);
  m.def(
      "write_stack",
      [](const std::string& path, HostPixels images, std::pair<double, double> spacing,
         std::optional<std::pair<double, double>> window, std::optional<Matrices> poses,
         std::optional<Mask> mask) {
        if (images.ndim() != 3)
          throw InputError("images has shape " + shape_text(images) + "; expected (N, H, W)");
        StackSpec spec;
        spec.type = pixel_type_of(images.dtype(), "images");
        spec.count = int64_t(images.shape(0));
        spec.height = int(images.shape(1));
        spec.width = int(images.shape(2));
        spec.spacing_mm[0] = spacing.first;
        spec.spacing_mm[1] = spacing.second;
        spec.window = window;
        if (poses)
          spec.poses = matrices_from(*poses);
        else
          spec.poses.assign(size_t(spec.count), Pose::identity());
        if (mask) spec.mask = mask->data();
        const size_t image_bytes = size_t(spec.width) * size_t(spec.height) * pixel_size(spec.type);
        nb::gil_scoped_release release;
        auto writer = StackWriter::create(path, spec);
        const int64_t chunk = chunk_images(image_bytes, spec.count);
        for (int64_t first = 0; first < spec.count; first += chunk) {
          const int64_t n = std::min(chunk, spec.count - first);
          std::memcpy(writer->buffer(first, n),
                      static_cast<const char*>(images.data()) + size_t(first) * image_bytes,
                      size_t(n) * image_bytes);
          writer->write(first, n);
        }
        writer->commit();
      },
      "path"_a, "images"_a, "spacing_mm"_a, "window"_a = nb::none(), "poses"_a = nb::none(),
      "mask"_a = nb::none());
}

}  // namespace sonoslice::bindings
