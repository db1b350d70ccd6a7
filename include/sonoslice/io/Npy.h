#pragma once
/// @file NumPy .npy arrays (format versions 1–3): whole-array reading and streamed writing.
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

class OutputSet;

struct NpyArray {
  PixelType type = PixelType::Float32;
  std::vector<int64_t> shape;
  bool fortran_order = false;
  std::shared_ptr<void> data;    ///< native byte order, 64-byte aligned (null from read_npy_header)
  uint64_t data_offset = 0;      ///< where the data starts in the file
  bool swapped_on_disk = false;  ///< the file stores the other byte order
  int64_t element_count() const;
};

/// Strides (in elements) of each dimension of `a`'s shape, honouring C or Fortran order.
std::vector<int64_t> npy_element_strides(const NpyArray& a);

/// Reads `path`; FileError for a missing, corrupt or truncated file, InputError for a dtype
/// sonoslice does not handle (names the dtype). Big-endian data is swapped to native order.
NpyArray read_npy(const std::string& path);

/// Reads only the header (dtype and shape) without loading the data.
NpyArray read_npy_header(const std::string& path);

/// Writes a .npy whose data arrives in pieces (C order), through a temporary file renamed on
/// commit(): an interrupted run leaves no partial file.
class NpyWriter {
 public:
  NpyWriter(const std::string& path, PixelType type, const std::vector<int64_t>& shape);
  ~NpyWriter();
  NpyWriter(const NpyWriter&) = delete;
  NpyWriter& operator=(const NpyWriter&) = delete;
  void write(const void* data, size_t bytes);
  /// The data bytes the shape announces (refused at construction if they overflow).
  uint64_t expected_bytes() const { return expected_; }
  /// Checks that exactly the announced bytes arrived, then renames; with `together`, leaves the
  /// rename to that set's commit() (several outputs of one run go into place together).
  void commit(OutputSet* together = nullptr);

 private:
  std::string path_;
  std::unique_ptr<class AtomicFile> file_;
  uint64_t expected_ = 0, written_ = 0, header_bytes_ = 0;
};

/// Convenience: writes a whole C-order array at once (`together`: as NpyWriter::commit).
void write_npy(const std::string& path, PixelType type, const std::vector<int64_t>& shape,
               const void* data, OutputSet* together = nullptr);

}  // namespace sonoslice
