#include "PngFile.h"

#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"

#ifdef SONOSLICE_HAVE_PNG
#include <png.h>
#include <unistd.h>

#include <cerrno>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>

#include "MappedFile.h"
#endif

namespace sonoslice {

#ifdef SONOSLICE_HAVE_PNG
namespace {

// What the callbacks tell the code after setjmp: libpng reports errors by longjmp, so no C++
// object with a destructor may live between setjmp and png_destroy_write_struct.
struct PngState {
  int fd = -1;
  std::vector<uint8_t>* memory = nullptr;  // when set, bytes go here instead of fd
  int write_errno = 0;                     // errno of the failed write, when writing failed
  char message[256] = {};                  // libpng's own complaint otherwise
};

extern "C" void on_png_error(png_structp png, png_const_charp message) {
  auto* state = static_cast<PngState*>(png_get_error_ptr(png));
  std::snprintf(state->message, sizeof state->message, "%s", message ? message : "libpng error");
  png_longjmp(png, 1);
}

extern "C" void on_png_warning(png_structp, png_const_charp) {}  // nothing a user can act on

extern "C" void on_png_write(png_structp png, png_bytep data, size_t n) {
  auto* state = static_cast<PngState*>(png_get_io_ptr(png));
  if (state->memory) {
    state->memory->insert(state->memory->end(), data, data + n);
    return;
  }
  while (n > 0) {
    const ssize_t written = ::write(state->fd, data, n);
    if (written < 0 && errno == EINTR) continue;
    if (written <= 0) {
      state->write_errno = written < 0 ? errno : ENOSPC;
      png_error(png, "write failed");
    }
    data += written;
    n -= size_t(written);
  }
}

extern "C" void on_png_flush(png_structp) {}  // unbuffered: every write went to the file

constexpr int kPngZlibLevel = 4;

// Returns 0 on success; on failure `state` says why. Plain C inside: see PngState.
int encode(PngState* state, const unsigned char* pixels, int bit_depth, int width, int height,
           int components, const double spacing_mm[2]) {
  png_structp png =
      png_create_write_struct(PNG_LIBPNG_VER_STRING, state, on_png_error, on_png_warning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_write_struct(&png, nullptr);
    std::snprintf(state->message, sizeof state->message, "out of memory");
    return 1;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return 1;
  }
  png_set_write_fn(png, state, on_png_write, on_png_flush);
  png_set_IHDR(png, info, png_uint_32(width), png_uint_32(height), bit_depth,
               components == 3 ? PNG_COLOR_TYPE_RGB : PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  // ITK's convention (the values are mm though the unit says metres): ITK's reader, and so
  // read_volume, gets the pixel spacing back, as from the PNGs ITK wrote before.
  png_set_sCAL(png, info, PNG_SCALE_METER, spacing_mm[0], spacing_mm[1]);
  // zlib level 4 rather than libpng's default 6: on windowed CT images 2.5 times faster for
  // files 4 % larger; on speckle the two are alike (docs/cli.md, Files).
  png_set_compression_level(png, kPngZlibLevel);
  png_write_info(png, info);
  if (bit_depth == 16) png_set_swap(png);  // PNG stores 16-bit samples big-endian
  const size_t row_bytes = size_t(width) * size_t(components) * size_t(bit_depth / 8);
  for (int row = 0; row < height; ++row)
    png_write_row(png, const_cast<png_bytep>(pixels + size_t(row) * row_bytes));
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return 0;
}

}  // namespace

bool built_with_png() {
  return true;
}

namespace {

void check_png_image(const std::string& path, PixelType type, int width, int height,
                     int components) {
  if (type != PixelType::UInt8 && type != PixelType::UInt16)
    throw InputError("'" + path + "': PNG holds uint8 or uint16 images, not " + to_string(type));
  if (components != 1 && components != 3)
    throw InputError("'" + path + "': PNG images here are grey or RGB");
  if (width <= 0 || height <= 0)
    throw InputError("'" + path + "': image size " + std::to_string(width) + "x" +
                     std::to_string(height));
}

/// Reads PNG bytes from memory for libpng.
struct PngSource {
  const uint8_t* data;
  size_t size, at;
  char message[256];
};

extern "C" void on_png_read(png_structp png, png_bytep out, size_t n) {
  auto* src = static_cast<PngSource*>(png_get_io_ptr(png));
  if (n > src->size - src->at) png_error(png, "truncated PNG");
  std::memcpy(out, src->data + src->at, n);
  src->at += n;
}

extern "C" void on_png_read_error(png_structp png, png_const_charp message) {
  auto* src = static_cast<PngSource*>(png_get_error_ptr(png));
  std::snprintf(src->message, sizeof src->message, "%s", message ? message : "libpng error");
  png_longjmp(png, 1);
}

// 0 on success. Plain C between setjmp and the end (see PngState); `out` is sized first.
// `any_layout`: also palette, grey+alpha, RGBA, 1- to 4-bit grey and interlaced images, as
// libpng expands them (palette to RGB, transparency to alpha); otherwise the grey and RGB
// images of 8 or 16 bits that sonoslice writes.
int decode(PngSource* src, DecodedPng* out, bool any_layout) {
  png_structp png =
      png_create_read_struct(PNG_LIBPNG_VER_STRING, src, on_png_read_error, on_png_warning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    std::snprintf(src->message, sizeof src->message, "out of memory");
    return 1;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    return 1;
  }
  png_set_read_fn(png, src, on_png_read);
  png_read_info(png, info);
  const int color = png_get_color_type(png, info), depth = png_get_bit_depth(png, info);
  // Deflate packs at most 1032 bytes into one: a header that claims more (filtered) rows than
  // the whole file could hold compressed is corrupt, refused before its pixels are allocated.
  const uint64_t stored_row =
      (uint64_t(png_get_image_width(png, info)) * png_get_channels(png, info) * depth + 7) / 8 + 1;
  if (stored_row * png_get_image_height(png, info) > 1032 * uint64_t(src->size) + 4096)
    png_error(png, "its header claims more pixels than its bytes can hold");
  int passes = 1;
  if (any_layout) {
    if (color == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(png);
    if (color == PNG_COLOR_TYPE_GRAY && depth < 8) png_set_expand_gray_1_2_4_to_8(png);
    if (png_get_valid(png, info, PNG_INFO_tRNS)) png_set_tRNS_to_alpha(png);
    passes = png_set_interlace_handling(png);
  } else if ((color != PNG_COLOR_TYPE_GRAY && color != PNG_COLOR_TYPE_RGB) || depth < 8 ||
             png_get_interlace_type(png, info) != PNG_INTERLACE_NONE) {
    png_error(png, "not an 8- or 16-bit grey or RGB PNG");
  }
  if (depth == 16) png_set_swap(png);  // to native (little-endian) order
  png_read_update_info(png, info);
  out->width = int(png_get_image_width(png, info));
  out->height = int(png_get_image_height(png, info));
  out->components = png_get_channels(png, info);
  out->bit_depth = png_get_bit_depth(png, info);
  int unit = 0;
  double sx = 0, sy = 0;
  // ITK's convention for the pixel spacing (write_png writes it so): the sCAL values in mm.
  if (png_get_sCAL(png, info, &unit, &sx, &sy) && sx > 0 && sy > 0 && sx < 1e9 && sy < 1e9) {
    out->spacing_mm[0] = sx;
    out->spacing_mm[1] = sy;
  }
  const size_t row = png_get_rowbytes(png, info);
  if (size_t(out->height) * row > size_t(1) << 31) png_error(png, "image too large");
  out->pixels.resize(size_t(out->height) * row);
  for (int pass = 0; pass < passes; ++pass)
    for (int r = 0; r < out->height; ++r)
      png_read_row(png, out->pixels.data() + size_t(r) * row, nullptr);
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  return 0;
}

}  // namespace

void write_png(int fd, const std::string& path, const void* pixels, PixelType type, int width,
               int height, int components, const double spacing_mm[2]) {
  check_png_image(path, type, width, height, components);
  PngState state;
  state.fd = fd;
  if (encode(&state, static_cast<const unsigned char*>(pixels), type == PixelType::UInt16 ? 16 : 8,
             width, height, components, spacing_mm) == 0)
    return;
  if (state.write_errno != 0) throw FileError(write_error_message(path, state.write_errno));
  throw FileError("cannot write '" + path + "': " + state.message);
}

std::vector<uint8_t> encode_png(const void* pixels, PixelType type, int width, int height,
                                int components, const double spacing_mm[2]) {
  check_png_image("png", type, width, height, components);
  std::vector<uint8_t> bytes;
  PngState state;
  state.memory = &bytes;
  if (encode(&state, static_cast<const unsigned char*>(pixels), type == PixelType::UInt16 ? 16 : 8,
             width, height, components, spacing_mm) != 0)
    throw Error(std::string("PNG encoding failed: ") + state.message);
  return bytes;
}

DecodedPng decode_png(const uint8_t* data, size_t size, const std::string& what) {
  static const uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (size < 8 || std::memcmp(data, kSignature, 8) != 0)
    throw InputError(what + ": not a PNG (no PNG signature)");
  PngSource src{data, size, 0, {}};
  DecodedPng out;
  if (decode(&src, &out, false) != 0)
    throw InputError(what + ": cannot decode the PNG (" + src.message + ")");
  return out;
}

DecodedPng read_png_file(const std::string& path) {
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path, ec);
  if (ec) throw FileError("cannot read image '" + path + "': " + ec.message());
  static const uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  const std::shared_ptr<void> mapped = size < 8 ? nullptr : map_file_region(path, 0, size);
  const auto* bytes = static_cast<const uint8_t*>(mapped.get());
  if (!bytes || std::memcmp(bytes, kSignature, 8) != 0)
    throw FileError("cannot read image '" + path + "': not a PNG (no PNG signature)");
  PngSource src{bytes, size_t(size), 0, {}};
  DecodedPng out;
  if (decode(&src, &out, true) != 0)
    throw FileError("cannot read image '" + path + "': corrupt PNG (" + src.message + ")");
  return out;
}

#else

bool built_with_png() {
  return false;
}

void write_png(int, const std::string& path, const void*, PixelType, int, int, int, const double*) {
  throw Error("'" + path + "': this sonoslice was built without libpng; write .npy or .nii.gz");
}

std::vector<uint8_t> encode_png(const void*, PixelType, int, int, int, const double*) {
  throw Error("PNG images: this sonoslice was built without libpng; use .npy");
}

DecodedPng decode_png(const uint8_t*, size_t, const std::string& what) {
  throw Error(what + ": this sonoslice was built without libpng");
}

DecodedPng read_png_file(const std::string& path) {
  throw Error("'" + path + "': this sonoslice was built without libpng");
}

#endif

}  // namespace sonoslice
