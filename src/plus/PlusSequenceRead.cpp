// Reading PLUS toolkit tracked-frame sequences (docs/conventions.md §7), MetaImage (.mha) and
// NRRD (.nrrd), without ITK. The headers are parsed in PlusHeaders.cpp; the pixel data is read (or
// inflated with zlib) straight into the sequence's one pixel buffer, then flipped to MF in place.
//
// We do not use ITK's readers: its NRRD reader turns the `list` axis into vector components, and
// neither keeps the per-frame `Seq_FrameNNNN_<Field>` entries in order.
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "../io/TextParse.h"
#include "PlusFormat.h"
#include "PlusSequenceRead.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/core/Memory.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/volume/Volume.h"

#ifdef SONOSLICE_PLUS_HAVE_ZLIB
#include <zlib.h>
#endif

namespace fs = std::filesystem;

namespace sonoslice {

using namespace text;

namespace plus {

constexpr size_t kMaxHeaderLine = size_t(1) << 20;  // a longer "line" is not a text header

InputFile::InputFile(const std::string& path) : path_(path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw FileError("PLUS sequence '" + path + "' not found");
  if (fs::is_directory(path, ec))
    throw FileError("cannot read PLUS sequence '" + path + "': it is a directory");
  file_ = std::fopen(path.c_str(), "rb");
  if (!file_) throw FileError("cannot open PLUS sequence '" + path + "': " + std::strerror(errno));
  size_ = fs::file_size(path, ec);
  if (ec) size_ = 0;
}

InputFile::~InputFile() {
  if (file_) std::fclose(file_);
}

bool InputFile::line(std::string* out) {
  out->clear();
  ++lines_;
  int c;
  while ((c = std::getc(file_)) != EOF) {
    if (c == '\n') break;
    if (out->size() >= kMaxHeaderLine)
      throw FileError(lines_ == 1 ? path_ + ": not a PLUS sequence file (no text header)"
                                  : path_ + ": header line " + std::to_string(lines_) +
                                        " is longer than 1 MiB (not a text header line)");
    out->push_back(static_cast<char>(c));
  }
  if (c == EOF && out->empty()) return false;
  if (!out->empty() && out->back() == '\r') out->pop_back();
  return true;
}

uint64_t InputFile::tell() const {
  return static_cast<uint64_t>(::ftello(file_));
}

void InputFile::seek(uint64_t offset) {
  if (::fseeko(file_, static_cast<off_t>(offset), SEEK_SET) != 0)
    throw FileError(path_ + ": cannot seek to byte " + std::to_string(offset));
}

size_t InputFile::read(void* dst, size_t n) {
  return std::fread(dst, 1, n, file_);
}

}  // namespace plus

using plus::DataLayout;
using plus::flip_frame;
using plus::Flips;
using plus::frame_label;
using plus::FrameFieldSink;
using plus::InputFile;
using plus::orientation_flips;
using plus::read_meta_header;
using plus::read_nrrd_header;
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
using plus::kChunk;
#endif

namespace {

// The caller has checked that the file holds `bytes` more bytes.
void read_raw(InputFile& in, uint8_t* dst, uint64_t bytes) {
  uint64_t done = 0;
  while (done < bytes) {
    const size_t want = size_t(std::min<uint64_t>(bytes - done, uint64_t(1) << 30));
    const size_t got = in.read(dst + done, want);
    if (got == 0)
      throw FileError(in.path() + ": read error after " + std::to_string(done) +
                      " bytes of pixel data");
    done += got;
  }
}

#ifdef SONOSLICE_PLUS_HAVE_ZLIB
void inflate_into(InputFile& in, uint64_t compressed_bytes, int window_bits, uint8_t* dst,
                  uint64_t bytes) {
  const std::string& what = in.path();
  z_stream zs{};
  if (inflateInit2(&zs, window_bits) != Z_OK)
    throw ResourceError(what + ": cannot initialise zlib");
  struct End {
    z_stream* z;
    ~End() { inflateEnd(z); }
  } end{&zs};

  std::vector<unsigned char> input(kChunk);
  uint64_t input_left = compressed_bytes;
  bool more_input = input_left > 0;
  uint64_t produced = 0;
  unsigned char scratch[1];
  for (;;) {
    if (zs.avail_in == 0 && more_input) {
      const size_t want = size_t(std::min<uint64_t>(input.size(), input_left));
      const size_t got = in.read(input.data(), want);
      input_left -= got;
      if (got < want || input_left == 0) more_input = false;
      zs.next_in = input.data();
      zs.avail_in = uInt(got);
    }
    // Once the buffer is full, a one-byte scratch output tells a clean end from extra data.
    const bool full = produced == bytes;
    zs.next_out = full ? scratch : dst + produced;
    zs.avail_out = full ? 1u : uInt(std::min<uint64_t>(bytes - produced, uint64_t(1) << 30));
    const uInt before = zs.avail_out;
    const int ret = inflate(&zs, Z_NO_FLUSH);
    const uInt made = before - zs.avail_out;
    if (full && made > 0)
      throw FileError(what + ": corrupt pixel data: it decompresses to more than the " +
                      std::to_string(bytes) + " bytes the header describes");
    if (!full) produced += made;
    if (ret == Z_STREAM_END) {
      if (produced != bytes)
        throw FileError(what + ": corrupt pixel data: it decompresses to " +
                        std::to_string(produced) + " bytes, the header describes " +
                        std::to_string(bytes));
      return;
    }
    if (ret == Z_BUF_ERROR || (ret == Z_OK && zs.avail_in == 0 && !more_input && made == 0)) {
      if (zs.avail_in == 0 && !more_input)
        throw FileError(what + ": truncated: the compressed pixel data ends after " +
                        std::to_string(produced) + " of " + std::to_string(bytes) + " bytes");
      continue;
    }
    if (ret == Z_MEM_ERROR) throw ResourceError(what + ": out of memory while decompressing");
    if (ret != Z_OK)
      throw FileError(what + ": corrupt compressed pixel data (zlib: " +
                      (zs.msg ? std::string(zs.msg) : std::to_string(ret)) + ")");
  }
}
#endif

void read_pixels(const DataLayout& layout, InputFile& header_file, PlusSequence* seq) {
  const uint64_t frame_bytes = uint64_t(layout.width) * uint64_t(layout.height) *
                               pixel_size(layout.type) * uint64_t(layout.components);
  const uint64_t bytes = frame_bytes * uint64_t(layout.frames);
  if (frame_bytes != 0 && bytes / frame_bytes != uint64_t(layout.frames))
    throw InputError(header_file.path() + ": image size overflows");
  if (bytes == 0) return;  // tracking-only sequence

  std::unique_ptr<InputFile> detached;
  InputFile* in = &header_file;
  if (layout.data_path != header_file.path()) {
    detached = std::make_unique<InputFile>(layout.data_path);
    in = detached.get();
  }
  in->seek(layout.data_offset);
  const uint64_t after_header =
      in->size() > layout.data_offset ? in->size() - layout.data_offset : 0;
  if (layout.encoding == DataLayout::Raw && after_header < bytes)
    throw FileError(in->path() + ": truncated: " + std::to_string(bytes) +
                    " bytes of pixel data expected, the file has " + std::to_string(after_header));
  if (layout.encoding == DataLayout::Zlib && layout.compressed_size > after_header)
    throw FileError(in->path() + ": truncated: CompressedDataSize is " +
                    std::to_string(layout.compressed_size) + " bytes, the file has " +
                    std::to_string(after_header) + " after the header");
#ifndef SONOSLICE_PLUS_HAVE_ZLIB
  if (layout.encoding != DataLayout::Raw)
    throw Error(in->path() +
                ": compressed PLUS sequences need zlib, and sonoslice was built "
                "without ITK/zlib");
#endif
  const unsigned long long available = available_memory_bytes();
  if (bytes > available)
    throw ResourceError(in->path() + ": the frames need " + std::to_string(bytes >> 20) +
                        " MiB of memory, " + std::to_string(available >> 20) +
                        " MiB are available");
  try {
    seq->pixels.resize(size_t(bytes));
  } catch (const std::bad_alloc&) {
    throw ResourceError(in->path() + ": cannot allocate " + std::to_string(bytes >> 20) +
                        " MiB for the frames");
  }
  switch (layout.encoding) {
    case DataLayout::Raw:
      read_raw(*in, seq->pixels.data(), bytes);
      break;
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    case DataLayout::Zlib:
      inflate_into(*in, layout.compressed_size ? layout.compressed_size : after_header, 15,
                   seq->pixels.data(), bytes);
      break;
    case DataLayout::Gzip:
      inflate_into(*in, after_header, 15 + 32, seq->pixels.data(), bytes);
      break;
#else
    case DataLayout::Zlib:
    case DataLayout::Gzip:
      break;  // refused above: this build has no zlib
#endif
  }
  if (layout.components > 1) {
    const int64_t pixels = int64_t(bytes / (pixel_size(layout.type) * size_t(layout.components)));
    const int64_t colour = first_component(seq->pixels.data(), layout.type, pixels,
                                           layout.components, seq->pixels.data());
    seq->pixels.resize(size_t(pixels) * pixel_size(layout.type));
    seq->pixels.shrink_to_fit();
    if (colour > 0)
      warn(header_file.path() + ": frames of " + std::to_string(layout.components) +
           " components: the first is used, as PLUS's reconstruction writes it; " +
           std::to_string(colour) + " of " + std::to_string(pixels) +
           " pixels have components that differ (colour in the frames)");
  }
}

void validate_frame_fields(const PlusSequence& seq) {
  for (int f = 0; f < seq.frame_count; ++f) {
    const auto& fields = seq.frame_fields[size_t(f)];
    for (const auto& [name, value] : fields) {
      const std::string where =
          seq.path + ": frame " + std::to_string(f) + ": Seq_Frame" + frame_label(f) + "_" + name;
      if (name == "Timestamp") {
        double t;
        if (!parse_double(trim(value), &t))
          throw InputError(where + " " + quote_value(value) + " is not a number");
      }
      if (!ends_with(name, "Transform")) continue;
      auto status = fields.find(name + "Status");
      if (status != fields.end() && !iequals(trim(status->second), "OK")) continue;
      Mat4 m;
      if (!parse_matrix16(value, &m))
        throw InputError(where + ": expected 16 finite numbers (a row-major 4x4 matrix), got " +
                         quote_value(value));
    }
  }
}

}  // namespace

PlusSequence read_plus_sequence(const std::string& path) {
  InputFile in(path);
  PlusSequence seq;
  seq.path = path;

  // The format comes from the content: NRRD files start with their magic, MetaImage with
  // `Key = Value` lines.
  char magic[8] = {0};
  const size_t got = in.read(magic, sizeof magic);
  in.seek(0);
  if (got == 0) throw FileError(path + ": empty file (not a PLUS sequence)");
  FrameFieldSink sink;
  const bool nrrd = got >= 7 && std::memcmp(magic, "NRRD000", 7) == 0;
  const DataLayout layout =
      nrrd ? read_nrrd_header(in, &seq, &sink) : read_meta_header(in, &seq, &sink);

  // Validates the orientation before any pixel is read; the flips apply once they are.
  const Flips flips = orientation_flips(seq.orientation, path);
  seq.width = layout.width;
  seq.height = layout.height;
  seq.frame_count = layout.frames;
  seq.pixel_type = layout.type;
  seq.frame_fields.assign(size_t(seq.frame_count), {});
  int beyond = 0;
  for (auto& [frame, fields] : sink.pending) {
    if (frame >= seq.frame_count) {
      ++beyond;
      continue;
    }
    // NRRD sequences call the image status `Status`: kept under MetaImage's name, ImageStatus,
    // so that frame fields mean the same whatever the format (the writer renames it back).
    if (nrrd) {
      auto status = fields.find("Status");
      if (status != fields.end() && !fields.count("ImageStatus")) {
        fields["ImageStatus"] = status->second;
        fields.erase(status);
      }
    }
    seq.frame_fields[size_t(frame)] = std::move(fields);
  }
  if (beyond > 0)
    warn(path + ": fields of " + std::to_string(beyond) + " frame(s) numbered beyond the " +
         std::to_string(seq.frame_count) + " frames of pixel data are ignored");
  validate_frame_fields(seq);

  read_pixels(layout, in, &seq);
  // NaN and infinite samples are splatted like any other (into NaN voxels): said once.
  const int64_t samples = int64_t(seq.width) * seq.height * seq.frame_count;
  if (const int64_t bad = count_non_finite(seq.pixels.data(), seq.pixel_type, samples))
    warn(path + ": " + std::to_string(bad) + " of " + std::to_string(samples) +
         " pixels are NaN or infinite; they are used as they are");
  const size_t frame_bytes = seq.frame_bytes();
  if (frame_bytes > 0)
    for (int f = 0; f < seq.frame_count; ++f)
      flip_frame(seq.pixels.data() + frame_bytes * size_t(f), seq.width, seq.height,
                 pixel_size(seq.pixel_type), flips);
  return seq;
}

}  // namespace sonoslice
