// PLUS toolkit files (docs/conventions.md §7, docs/compounding.md): tracked-frame sequences,
// transform repositories and reconstruction configurations.
#include <nanobind/stl/array.h>
#include <nanobind/stl/map.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <algorithm>
#include <cstring>

#include "bindings.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/plus/TransformRepository.h"

namespace sonoslice::bindings {

using namespace nb::literals;

void bind_plus(nb::module_& m) {
  nb::class_<PlusSequence>(m, "PlusSequence",
                           "A PLUS tracked-frame sequence, frames in MF orientation.")
      .def_ro("path", &PlusSequence::path)
      .def_ro("width", &PlusSequence::width)
      .def_ro("height", &PlusSequence::height)
      .def_ro("frame_count", &PlusSequence::frame_count)
      .def_ro("orientation", &PlusSequence::orientation)
      .def_prop_ro("dtype", [](const PlusSequence& s) { return to_string(s.pixel_type); })
      .def_ro("frame_fields", &PlusSequence::frame_fields,
              "Per frame, every Seq_FrameNNNN_<Field> (a copy).")
      .def(
          "frames",
          [](nb::handle_t<PlusSequence> self) {
            PlusSequence& s = nb::cast<PlusSequence&>(self);
            const size_t shape[3] = {size_t(s.frame_count), size_t(s.height), size_t(s.width)};
            // A view of the sequence's pixels; the array keeps the sequence object alive.
            return nb::ndarray<nb::numpy>(s.pixels.data(), 3, shape, self, nullptr,
                                          dlpack_dtype(s.pixel_type));
          },
          "(N, H, W) view of the frames (no copy).")
      .def("image_ok", &PlusSequence::image_ok, "frame"_a)
      .def("transform_names", &PlusSequence::transform_names, "frame"_a)
      .def(
          "transform",
          [](const PlusSequence& s, int frame, const std::string& name) {
            return matrix_or_none(s.transform(frame, name));
          },
          "frame"_a, "name"_a,
          "Frame's <name>Transform (4x4) or None (missing or its status not OK).")
      .def("timestamps", [](const PlusSequence& s) {
        std::vector<double> t(size_t(s.frame_count));
        for (int k = 0; k < s.frame_count; ++k) t[size_t(k)] = s.timestamp(k);
        return t;
      });
  m.def(
      "read_plus_sequence",
      [](const std::string& path) {
        nb::gil_scoped_release release;
        return read_plus_sequence(path);
      },
      "path"_a);
  m.def(
      "write_plus_sequence",
      [](const std::string& path, HostPixels frames,
         const std::vector<std::map<std::string, std::string>>& fields,
         const std::string& orientation, bool compress) {
        const std::string what = "write_plus_sequence: frames";
        PlusSequence s;
        s.pixel_type = pixel_type_of(frames.dtype(), what);
        if (frames.ndim() != 3)
          throw InputError(what + " has shape " + shape_text(frames) + "; expected (N, H, W)");
        s.path = path;
        s.frame_count = int(frames.shape(0));
        s.height = int(frames.shape(1));
        s.width = int(frames.shape(2));
        if (int64_t(s.frame_count) != int64_t(frames.shape(0)) ||
            int64_t(s.height) != int64_t(frames.shape(1)) ||
            int64_t(s.width) != int64_t(frames.shape(2)))
          throw InputError(what + ": too many frames or pixels");
        s.orientation = orientation;
        s.frame_fields = fields;
        const auto* p = static_cast<const uint8_t*>(frames.data());
        s.pixels.assign(p, p + frames.nbytes());
        nb::gil_scoped_release release;
        write_plus_sequence(path, s, compress);
      },
      "path"_a, "frames"_a, "fields"_a, "orientation"_a = "MF", "compress"_a = true);

  nb::class_<TransformRepository>(m, "TransformRepository",
                                  "Named transforms; chains of them on request.")
      .def(nb::init<>())
      .def("copy", [](const TransformRepository& r) { return r; })
      .def(
          "set",
          [](TransformRepository& r, const std::string& from, const std::string& to, Matrix4 matrix,
             bool valid) { r.set(from, to, Mat4::from_row_major(matrix.data()), valid); },
          "from_frame"_a, "to_frame"_a, "matrix"_a, "valid"_a = true)
      .def("set_frame", &TransformRepository::set_frame, "sequence"_a, "frame"_a)
      .def(
          "get",
          [](const TransformRepository& r, const std::string& from, const std::string& to) {
            return matrix_or_none(r.get(from, to));
          },
          "from_frame"_a, "to_frame"_a)
      .def_static("split_name", &TransformRepository::split_name, "name"_a);

  nb::class_<PlusReconstructionConfig>(m, "PlusConfig",
                                       "A PLUS configuration's reconstruction settings.")
      .def_ro("path", &PlusReconstructionConfig::path)
      .def_prop_ro("coordinate_definitions",
                   [](const PlusReconstructionConfig& c) { return c.coordinate_definitions; })
      .def_ro("image_frame", &PlusReconstructionConfig::image_frame)
      .def_ro("reference_frame", &PlusReconstructionConfig::reference_frame)
      .def_ro("spacing", &PlusReconstructionConfig::output_spacing_mm)
      .def_ro("origin", &PlusReconstructionConfig::output_origin_mm)
      .def_ro("extent", &PlusReconstructionConfig::output_extent)
      .def_prop_ro("output_grid", &PlusReconstructionConfig::output_grid,
                   "The grid OutputSpacing, OutputOrigin and OutputExtent fix, or None.")
      .def_ro("settings", &PlusReconstructionConfig::settings)
      .def_ro("clip", &PlusReconstructionConfig::clip)
      .def_ro("skip_interval", &PlusReconstructionConfig::skip_interval)
      .def_ro("ignored_attributes", &PlusReconstructionConfig::ignored_attributes)
      .def_ro("unknown_attributes", &PlusReconstructionConfig::unknown_attributes);
  m.def(
      "read_plus_config",
      [](const std::string& path) {
        nb::gil_scoped_release release;
        return read_plus_config(path);
      },
      "path"_a);
}

}  // namespace sonoslice::bindings
