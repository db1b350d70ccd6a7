// The C++ side of the Python package: thin bindings over the library, one file per area
// (volumes.cpp, slicing.cpp, surfaces.cpp, compounding.cpp, io.cpp, simulation.cpp, ...), in one
// style: settings as typed classes built from keywords (checked by the library when made), choices
// as enums, no more than 6 positional parameters (python/tests/test_bindings_style.py), no JSON
// text (dicts of settings are read by the library's parsers, json.cpp). Arrays cross the border
// without copies (NumPy's buffer protocol / DLPack through nanobind's ndarray); the GIL is
// released while C++ computes; C++ errors become ValueError / OSError / RuntimeError. The
// Pythonic API (argument handling, torch tensors, tqdm) is python/sonoslice/, one module per area.
#include <nanobind/stl/string.h>

#include <exception>

#include "bindings.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/io/VolumeFile.h"

namespace nb = nanobind;
using namespace nb::literals;

NB_MODULE(_sonoslice, m) {
  using namespace sonoslice;
  m.doc() = "sonoslice C++ core (use the sonoslice package, not this module)";
  // An autograd graph still alive when Python exits (a loss kept in a global) holds a Volume and
  // a Probe in its context (sonoslice.torch) and is torn down after this module: nanobind would
  // report those as leaks at exit, alarming and harmless. The objects are freed with the graph.
  nb::set_leak_warnings(false);

  // C++ errors → the Python exceptions users expect. Messages are the C++ ones.
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const InputError& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const FileError& e) {
      PyErr_SetString(PyExc_OSError, e.what());
    } catch (const Error& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    }
  });

  // Warnings go through Python's warnings module, once the interpreter can take them.
  set_warning_handler([](const std::string& message) {
    nb::gil_scoped_acquire gil;
    // With warnings turned into errors there is no caller to raise into here: report it.
    if (PyErr_WarnEx(PyExc_UserWarning, message.c_str(), 1) < 0) PyErr_WriteUnraisable(nullptr);
  });

  // ---- devices and threads
  m.def("describe_devices", &describe_devices);
  m.def("built_with_cuda", &built_with_cuda);
  m.def("built_with_itk", &built_with_itk);
  m.def("built_with_vtk", &built_with_vtk);
  m.def("require_device", [](const std::string& d) { require_device(Device::parse(d)); });
  m.def("cpu_threads", &cpu_threads);
  m.def("set_cpu_threads", &set_cpu_threads, "n"_a);
  m.def("reset_cpu_threads", &reset_cpu_threads);
  m.def("cpu_kernel_isa", [] { return std::string(to_string(cpu_kernel_isa())); });
  m.def(
      "set_cpu_kernel_isa", [](const std::string& isa) { set_cpu_kernel_isa(isa); }, "isa"_a);

  // In this order: a class is registered before a later area's default arguments use it.
  bindings::bind_volumes(m);
  bindings::bind_slicing(m);
  bindings::bind_surfaces(m);
  bindings::bind_compounding(m);
  bindings::bind_io(m);
  bindings::bind_plus(m);
  bindings::bind_reconstruction(m);
  bindings::bind_simulation(m);
  bindings::bind_registration(m);
  bindings::bind_sampling(m);
  bindings::bind_live(m);
}
