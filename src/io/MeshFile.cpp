// The VTK edge of sonoslice: surface meshes in and out.
#include "sonoslice/io/MeshFile.h"

#include <filesystem>

#include "TextParse.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/VolumeFile.h"

#ifdef SONOSLICE_HAVE_VTK
#include <vtkAlgorithm.h>
#include <vtkCellArray.h>
#include <vtkCleanPolyData.h>
#include <vtkIdList.h>
#include <vtkLogger.h>
#include <vtkNew.h>
#include <vtkOBJReader.h>
#include <vtkOBJWriter.h>
#include <vtkOutputWindow.h>
#include <vtkPLYReader.h>
#include <vtkPLYWriter.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataReader.h>
#include <vtkPolyDataWriter.h>
#include <vtkSTLReader.h>
#include <vtkSTLWriter.h>
#include <vtkSmartPointer.h>
#include <vtkTriangleFilter.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLPolyDataWriter.h>
#endif

namespace sonoslice {

bool built_with_vtk() {
#ifdef SONOSLICE_HAVE_VTK
  return true;
#else
  return false;
#endif
}

#ifdef SONOSLICE_HAVE_VTK
namespace {

// VTK readers report trouble through vtkOutputWindow and carry on; this window collects what
// they say during one read so that it can become an error (or a warning) with the file's name.
class CollectingWindow : public vtkOutputWindow {
 public:
  static CollectingWindow* New();
  vtkTypeMacro(CollectingWindow, vtkOutputWindow);
  void DisplayErrorText(const char* t) override { errors += clean(t); }
  void DisplayWarningText(const char* t) override { warnings += clean(t); }
  void DisplayGenericWarningText(const char* t) override { warnings += clean(t); }
  void DisplayText(const char*) override {}
  std::string errors, warnings;

 private:
  static std::string clean(const char* text) {
    // "ERROR: In /path/x.cxx, line N\nvtkClass (0x...): message" → "message"
    const std::string s = text::one_line_message(text ? text : "", /*drop_location=*/true);
    return s.empty() ? s : s + "; ";
  }
};
vtkStandardNewMacro(CollectingWindow);

// Some VTK 9 readers log through vtkLogger (to stderr) instead: silence that and collect it too.
void collect_log(void* user, const vtkLogger::Message& m) {
  static_cast<CollectingWindow*>(user)->warnings += std::string(m.message ? m.message : "") + "; ";
}

struct WindowScope {
  vtkSmartPointer<vtkOutputWindow> previous;
  vtkNew<CollectingWindow> window;
  WindowScope() : previous(vtkOutputWindow::GetInstance()) {
    vtkOutputWindow::SetInstance(window);
    vtkLogger::SetStderrVerbosity(vtkLogger::VERBOSITY_OFF);
    vtkLogger::AddCallback("sonoslice-mesh-read", &collect_log, window.GetPointer(),
                           vtkLogger::VERBOSITY_WARNING);
  }
  ~WindowScope() {
    vtkLogger::RemoveCallback("sonoslice-mesh-read");
    vtkOutputWindow::SetInstance(previous);
  }
};

std::string trimmed(const std::string& s) {
  return s.size() > 2 ? s.substr(0, s.size() - 2) : s;
}

vtkSmartPointer<vtkAlgorithm> reader_for(const std::string& path, const std::string& ext) {
  if (ext == ".vtk") {
    auto r = vtkSmartPointer<vtkPolyDataReader>::New();
    r->SetFileName(path.c_str());
    return r;
  }
  if (ext == ".vtp") {
    auto r = vtkSmartPointer<vtkXMLPolyDataReader>::New();
    r->SetFileName(path.c_str());
    return r;
  }
  if (ext == ".stl") {
    auto r = vtkSmartPointer<vtkSTLReader>::New();
    r->SetFileName(path.c_str());
    return r;
  }
  if (ext == ".obj") {
    auto r = vtkSmartPointer<vtkOBJReader>::New();
    r->SetFileName(path.c_str());
    return r;
  }
  if (ext == ".ply") {
    auto r = vtkSmartPointer<vtkPLYReader>::New();
    r->SetFileName(path.c_str());
    return r;
  }
  throw InputError("mesh '" + path + "': unknown format '" + ext +
                   "' (expected .vtk, .vtp, .stl, .obj or .ply)");
}

}  // namespace

TriangleMesh read_mesh(const std::string& path, WorldFrame frame) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    throw FileError("cannot read mesh '" + path + "': no such file");
  const std::string ext = file_extension(path);
  WindowScope scope;
  auto reader = reader_for(path, ext);
  if (ext == ".vtk") {
    auto* legacy = vtkPolyDataReader::SafeDownCast(reader);
    if (!legacy || !legacy->IsFilePolyData())
      throw FileError("cannot read mesh '" + path + "': not a legacy VTK POLYDATA file");
  }
  vtkNew<vtkTriangleFilter> triangles;
  triangles->SetInputConnection(reader->GetOutputPort());
  triangles->PassVertsOff();
  triangles->PassLinesOff();
  vtkNew<vtkCleanPolyData> clean;  // merge coincident points: shared edges share vertices
  clean->SetInputConnection(triangles->GetOutputPort());
  clean->PointMergingOn();
  clean->SetTolerance(0.0);
  clean->Update();
  if (!scope.window->errors.empty())
    throw FileError("cannot read mesh '" + path + "': " + trimmed(scope.window->errors));
  vtkPolyData* poly = clean->GetOutput();
  TriangleMesh mesh;
  mesh.name = std::filesystem::path(path).filename().string();
  const vtkIdType np = poly->GetNumberOfPoints();
  mesh.vertices.resize(size_t(np));
  for (vtkIdType i = 0; i < np; ++i) {
    double p[3];
    poly->GetPoint(i, p);
    mesh.vertices[size_t(i)] = {p[0], p[1], p[2]};
  }
  vtkCellArray* polys = poly->GetPolys();
  vtkNew<vtkIdList> ids;
  polys->InitTraversal();
  while (polys->GetNextCell(ids)) {
    if (ids->GetNumberOfIds() != 3) continue;
    mesh.triangles.push_back(
        {int32_t(ids->GetId(0)), int32_t(ids->GetId(1)), int32_t(ids->GetId(2))});
  }
  if (mesh.triangles.empty()) {
    if (!scope.window->warnings.empty())  // what VTK said is the likelier story
      throw FileError("cannot read mesh '" + path + "': " + trimmed(scope.window->warnings));
    throw InputError("mesh '" + path + "': no triangles");
  }
  if (!scope.window->warnings.empty())
    warn("mesh '" + path + "': VTK: " + trimmed(scope.window->warnings));
  if (frame == WorldFrame::RAS) mesh.transform(pose_to_lps(Pose::identity(), WorldFrame::RAS));
  mesh.validate();
  return mesh;
}

void write_mesh(const std::string& path, const TriangleMesh& mesh) {
  mesh.validate();
  const std::string ext = file_extension(path);
  vtkNew<vtkPoints> points;
  for (const Vec3& v : mesh.vertices) points->InsertNextPoint(v[0], v[1], v[2]);
  vtkNew<vtkCellArray> cells;
  for (const auto& t : mesh.triangles) {
    const vtkIdType ids[3] = {t[0], t[1], t[2]};
    cells->InsertNextCell(3, ids);
  }
  vtkNew<vtkPolyData> poly;
  poly->SetPoints(points);
  poly->SetPolys(cells);
  AtomicFile file(path);
  WindowScope scope;
  bool ok = false;
  if (ext == ".vtk") {
    vtkNew<vtkPolyDataWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    w->SetFileTypeToBinary();
    ok = w->Write() == 1;
  } else if (ext == ".vtp") {
    vtkNew<vtkXMLPolyDataWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    ok = w->Write() == 1;
  } else if (ext == ".stl") {
    vtkNew<vtkSTLWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    w->SetFileTypeToBinary();
    ok = w->Write() == 1;
  } else if (ext == ".obj") {
    vtkNew<vtkOBJWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    ok = w->Write() == 1;
  } else if (ext == ".ply") {
    vtkNew<vtkPLYWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    ok = w->Write() == 1;
  } else {
    throw InputError("mesh '" + path + "': unknown format '" + ext + "'");
  }
  if (!ok || !scope.window->errors.empty()) throw FileError("cannot write mesh '" + path + "'");
  file.commit();
}

#else

TriangleMesh read_mesh(const std::string& path, WorldFrame) {
  throw Error("mesh '" + path + "': this sonoslice was built without VTK; meshes cannot be read");
}
void write_mesh(const std::string& path, const TriangleMesh&) {
  throw Error("mesh '" + path + "': this sonoslice was built without VTK");
}

#endif

}  // namespace sonoslice
