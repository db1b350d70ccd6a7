#pragma once
// Stanford PLY meshes, parsed here rather than by vtkPLYReader (VTK 9.1), which reads on after a
// file without x, y and z (use after free: a four-line file crashed it), prints end-of-file
// errors to stderr from C code and carries on, and trusts every count in the file. sonoslice
// needs the vertices' x, y, z and the faces' vertex lists; everything is checked against the
// file's size and the vertex count while it is read.
//
// The grammar is Greg Turk's (the PLY format as VTK's vtkPLY.cxx, Blender and MeshLab read and
// write it): "ply", "format ascii|binary_little_endian|binary_big_endian 1.0", "comment" and
// "obj_info" lines, "element NAME COUNT", "property TYPE NAME" and "property list COUNT_TYPE
// ITEM_TYPE NAME" (types char/int8, uchar/uint8, short/int16, ushort/uint16, int/int32,
// uint/uint32, float/float32, double/float64), "end_header", then each element's records in
// order. The faces' list is "vertex_indices" (or "vertex_index", as some exporters write it);
// other elements and properties are read past.
#include <cstdint>
#include <string>
#include <vector>

namespace sonoslice {

/// Points (x, y, z each) and polygons (as offsets into a connectivity list, n + 1 offsets for
/// n polygons); polygons of fewer than three vertices are left out.
struct PolygonSoup {
  std::vector<double> points;
  std::vector<int64_t> offsets{0}, connectivity;
};

/// The mesh of a PLY file's bytes; FileError ("cannot read mesh 'PATH': ...") for a file that is
/// not one or is truncated, InputError for non-finite coordinates.
PolygonSoup parse_ply(const std::string& path, const std::string& bytes);

}  // namespace sonoslice
