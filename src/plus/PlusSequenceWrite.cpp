// Writing PLUS toolkit tracked-frame sequences (MetaImage .mha, NRRD .nrrd), raw or compressed,
// atomically, with the frames flipped back to the sequence's orientation.
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "../io/TextParse.h"
#include "PlusFormat.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/plus/PlusSequence.h"

#ifdef SONOSLICE_PLUS_HAVE_ZLIB
#include <zlib.h>
#endif

namespace sonoslice {

using namespace text;
using plus::flip_frame;
using plus::Flips;
using plus::frame_label;
using plus::meta_type_name;
using plus::nrrd_type_name;
using plus::orientation_flips;
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
using plus::kChunk;
#endif

namespace {

class OutputFile {
 public:
  explicit OutputFile(const std::string& temp_path, const std::string& path) : path_(path) {
    file_ = std::fopen(temp_path.c_str(), "wb");
    if (!file_) throw FileError("cannot write '" + path + "': " + std::strerror(errno));
  }
  ~OutputFile() {
    if (file_) std::fclose(file_);
  }
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;
  void write(const void* data, size_t n) {
    if (n && std::fwrite(data, 1, n, file_) != n)
      throw FileError("cannot write '" + path_ + "': " + std::strerror(errno));
  }
  void write(const std::string& s) { write(s.data(), s.size()); }
  void seek(uint64_t offset) {
    if (::fseeko(file_, static_cast<off_t>(offset), SEEK_SET) != 0)
      throw FileError("cannot write '" + path_ + "': seek failed");
  }
  void close() {
    const bool ok = std::fflush(file_) == 0 && !std::ferror(file_);
    const bool closed = std::fclose(file_) == 0;
    file_ = nullptr;
    if (!ok || !closed) throw FileError("cannot write '" + path_ + "': " + std::strerror(errno));
  }

 private:
  std::string path_;
  FILE* file_ = nullptr;
};

/// Feeds frames to the file, raw or through zlib (zlib or gzip wrapper).
class PixelSink {
 public:
  PixelSink(OutputFile* out, bool compress, int window_bits, const std::string& path)
      : out_(out), compress_(compress), path_(path) {
    if (!compress_) return;
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    if (deflateInit2(&zs_, Z_DEFAULT_COMPRESSION, Z_DEFLATED, window_bits, 8, Z_DEFAULT_STRATEGY) !=
        Z_OK)
      throw ResourceError("cannot write '" + path + "': cannot initialise zlib");
    initialised_ = true;
    buffer_.resize(kChunk);
#else
    (void)window_bits;
    throw Error("cannot write '" + path +
                "': compressed PLUS sequences need zlib, and sonoslice "
                "was built without ITK/zlib (write with compression off)");
#endif
  }
  ~PixelSink() {
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    if (initialised_) deflateEnd(&zs_);
#endif
  }
  PixelSink(const PixelSink&) = delete;
  PixelSink& operator=(const PixelSink&) = delete;

  void write(const uint8_t* data, uint64_t n) {
    if (!compress_) {
      out_->write(data, size_t(n));
      written_ += n;
      return;
    }
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    while (n > 0) {
      const uInt part = uInt(std::min<uint64_t>(n, uint64_t(1) << 30));
      zs_.next_in = const_cast<uint8_t*>(data);
      zs_.avail_in = part;
      pump(Z_NO_FLUSH);
      data += part;
      n -= part;
    }
#endif
  }
  /// Ends the stream; returns the bytes written to the file.
  uint64_t finish() {
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    if (compress_) pump(Z_FINISH);
#endif
    return written_;
  }

 private:
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
  void pump(int flush) {
    for (;;) {
      zs_.next_out = buffer_.data();
      zs_.avail_out = uInt(buffer_.size());
      const int ret = deflate(&zs_, flush);
      if (ret == Z_STREAM_ERROR) throw FileError("cannot write '" + path_ + "': zlib error");
      const size_t have = buffer_.size() - zs_.avail_out;
      out_->write(buffer_.data(), have);
      written_ += have;
      if (flush == Z_FINISH ? ret == Z_STREAM_END : (zs_.avail_in == 0 && zs_.avail_out != 0))
        return;
    }
  }
  z_stream zs_{};
  bool initialised_ = false;
  std::vector<unsigned char> buffer_;
#endif
  OutputFile* out_;
  bool compress_;
  std::string path_;
  uint64_t written_ = 0;
};

void check_header_text(const std::string& text, const std::string& what, const std::string& path) {
  if (text.find_first_of("\r\n") != std::string::npos || text.find('\0') != std::string::npos)
    throw InputError("cannot write '" + path + "': " + what + " " + quote_value(text) +
                     " contains a line break");
}

}  // namespace

void check_plus_sequence_name(const std::string& path) {
  const std::string name = lower(path);
  if (!ends_with(name, ".nrrd") && !ends_with(name, ".mha"))
    throw InputError("cannot write PLUS sequence '" + path +
                     "': unsupported file name ending (expected .mha or .nrrd, e.g. .igs.mha)");
}

void write_plus_sequence(const std::string& path, const PlusSequence& s, bool compress,
                         OutputSet* together) {
  check_plus_sequence_name(path);
  const bool nrrd = ends_with(lower(path), ".nrrd");
  if (s.width <= 0 || s.height <= 0 || s.frame_count <= 0)
    throw InputError("cannot write PLUS sequence '" + path + "': " + std::to_string(s.width) + "x" +
                     std::to_string(s.height) + " pixels, " + std::to_string(s.frame_count) +
                     " frames (need at least one frame of at least one pixel)");
  const uint64_t frame_bytes = s.frame_bytes();
  if (uint64_t(s.pixels.size()) != frame_bytes * uint64_t(s.frame_count))
    throw InputError("cannot write PLUS sequence '" + path +
                     "': " + std::to_string(s.pixels.size()) + " pixel bytes, expected " +
                     std::to_string(frame_bytes * uint64_t(s.frame_count)) + " for " +
                     std::to_string(s.frame_count) + " frames of " + std::to_string(s.width) + "x" +
                     std::to_string(s.height) + " " + to_string(s.pixel_type));
  if (s.frame_fields.size() > size_t(s.frame_count))
    throw InputError("cannot write PLUS sequence '" + path + "': fields for " +
                     std::to_string(s.frame_fields.size()) + " frames but " +
                     std::to_string(s.frame_count) + " frames of pixels");
  const Flips flips = orientation_flips(s.orientation, "cannot write PLUS sequence '" + path + "'");
  check_header_text(s.orientation, "orientation", path);

  std::ostringstream h;
  const std::string dims = std::to_string(s.width) + " " + std::to_string(s.height) + " " +
                           std::to_string(s.frame_count);
  // PLUS pads CompressedDataSize so that it can be filled in once the data is written.
  const std::string size_placeholder(20, ' ');
  if (nrrd) {
    h << "NRRD0004\n"
      << "# Complete NRRD file format specification at:\n"
      << "# http://teem.sourceforge.net/nrrd/format.html\n"
      << "dimension: 3\n"
      << "encoding: " << (compress ? "gz" : "raw") << "\n"
      << "endian: little\n"
      << "kinds: domain domain list\n"
      << "sizes: " << dims << "\n"
      << "space dimension: 2\n"
      << "space directions: (1,0) (0,1) none\n"
      << "space origin: (0,0)\n"
      << "type: " << nrrd_type_name(s.pixel_type) << "\n"
      << "ultrasound image orientation:=" << s.orientation << "\n"
      << "ultrasound image type:=BRIGHTNESS\n";
  } else {
    h << "ObjectType = Image\n"
      << "NDims = 3\n"
      << "AnatomicalOrientation = RAI\n"
      << "BinaryData = True\n"
      << "BinaryDataByteOrderMSB = False\n"
      << "CenterOfRotation = 0 0 0\n"
      << "CompressedData = " << (compress ? "True" : "False") << "\n";
    if (compress) h << "CompressedDataSize = " << size_placeholder << "\n";
    h << "DimSize = " << dims << "\n"
      << "Kinds = domain domain list\n"
      << "ElementSpacing = 1 1 1\n"
      << "ElementType = " << meta_type_name(s.pixel_type) << "\n"
      << "Offset = 0 0 0\n"
      << "TransformMatrix = 1 0 0 0 1 0 0 0 1\n"
      << "UltrasoundImageOrientation = " << s.orientation << "\n"
      << "UltrasoundImageType = BRIGHTNESS\n";
  }
  for (size_t f = 0; f < s.frame_fields.size(); ++f) {
    const auto& fields = s.frame_fields[f];
    // NRRD sequences call the image status `Status` (the reader stores it as ImageStatus).
    const bool rename_status = nrrd && fields.count("ImageStatus") && !fields.count("Status");
    for (const auto& [key, value] : fields) {
      const std::string field = rename_status && key == "ImageStatus" ? "Status" : key;
      check_header_text(field, "frame field name", path);
      check_header_text(value, "frame field value", path);
      if (field.empty() || trim(field) != field ||
          (nrrd ? field.find(":=") != std::string::npos : field.find('=') != std::string::npos))
        throw InputError("cannot write PLUS sequence '" + path + "': frame field name " +
                         quote_value(field) + " cannot be written");
      // What the reader would refuse is refused here, before anything is written.
      const auto status = fields.find(key + "Status");
      Mat4 m;
      if (ends_with(field, "Transform") &&
          (status == fields.end() || iequals(trim(status->second), "OK")) &&
          !parse_matrix16(value, &m))
        throw InputError(
            "cannot write PLUS sequence '" + path + "': frame " + std::to_string(f) + ": " + field +
            ": expected 16 finite numbers (a row-major 4x4 matrix), got " + quote_value(value));
      h << "Seq_Frame" << frame_label(int(f)) << "_" << field << (nrrd ? ":=" : " = ") << value
        << "\n";
    }
  }
  h << (nrrd ? "\n" : "ElementDataFile = LOCAL\n");
  const std::string header = h.str();

  auto atomic = std::make_unique<AtomicFile>(path);
  {
    OutputFile out(atomic->temp_path(), path);
    out.write(header);
    PixelSink sink(&out, compress, nrrd ? 15 + 16 : 15, path);
    std::vector<uint8_t> frame;
    for (int f = 0; f < s.frame_count; ++f) {
      const uint8_t* src = s.pixels.data() + frame_bytes * size_t(f);
      if (flips.x || flips.y) {
        frame.assign(src, src + frame_bytes);
        flip_frame(frame.data(), s.width, s.height, pixel_size(s.pixel_type), flips);
        src = frame.data();
      }
      sink.write(src, frame_bytes);
    }
    const uint64_t data_bytes = sink.finish();
    if (compress && !nrrd) {
      const std::string value = std::to_string(data_bytes);
      const size_t at = header.find("CompressedDataSize = ") + std::strlen("CompressedDataSize = ");
      out.seek(at);
      out.write(value);  // shorter than the padding, which stays as trailing spaces
    }
    out.close();
  }
  if (together)
    together->add(std::move(atomic));
  else
    atomic->commit();
}

}  // namespace sonoslice
