#pragma once
// Internal: what the PLUS sequence reader's files share: the file, the header parsers' results.
#include <cstdint>
#include <cstdio>
#include <map>
#include <string>

#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace plus {

/// A sequence file being read (or its detached data file); its FileErrors name it.
class InputFile {
 public:
  explicit InputFile(const std::string& path);
  ~InputFile();
  InputFile(const InputFile&) = delete;
  InputFile& operator=(const InputFile&) = delete;

  /// One header line without its end ('\n' or "\r\n"); false at the end of the file.
  bool line(std::string* out);
  uint64_t tell() const;
  void seek(uint64_t offset);
  size_t read(void* dst, size_t n);
  uint64_t size() const { return size_; }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  FILE* file_ = nullptr;
  uint64_t size_ = 0;
  int64_t lines_ = 0;  ///< lines read so far, for messages
};

/// What a header says about the pixel data.
struct DataLayout {
  int width = 0, height = 0, frames = 0;
  PixelType type = PixelType::UInt8;
  int components = 1;  ///< values per pixel: 1, or 3 and 4 (RGB and RGBA frames)
  enum Encoding { Raw, Zlib, Gzip } encoding = Raw;
  uint64_t compressed_size = 0;  ///< Zlib: the CompressedDataSize field (0: to the end)
  std::string data_path;         ///< where the data lies (the header file unless detached)
  uint64_t data_offset = 0;
};

/// The `Seq_FrameNNNN_<Field>` entries of a header, by frame number.
struct FrameFieldSink {
  std::map<int, std::map<std::string, std::string>> pending;  // frame number → fields

  /// Keeps a frame field and returns true; false for any other key.
  bool add(const std::string& key, const std::string& value, const std::string& where);
};

/// The header parsers (PlusHeaders.cpp): read `in` from its start up to the pixel data, set the
/// sequence's orientation, keep the frame fields in `sink`.
DataLayout read_meta_header(InputFile& in, PlusSequence* seq, FrameFieldSink* sink);
DataLayout read_nrrd_header(InputFile& in, PlusSequence* seq, FrameFieldSink* sink);

}  // namespace plus
}  // namespace sonoslice
