#include "sonoslice/io/StackWriter.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "../backend/ParallelFor.h"
#include "PngFile.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/VolumeGrid.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/VolumeFile.h"

namespace fs = std::filesystem;

namespace sonoslice {
namespace {

size_t image_bytes(const StackSpec& s) {
  return size_t(s.width) * size_t(s.height) * size_t(s.components) * pixel_size(s.type);
}

// .npy: header first, then images appended chunk by chunk.
class NpyStackWriter : public StackWriter {
 public:
  NpyStackWriter(const std::string& path, const StackSpec& spec)
      : spec_(spec), writer_(path, spec.type, shape_of(spec)) {}
  static std::vector<int64_t> shape_of(const StackSpec& s) {
    std::vector<int64_t> shape{s.count, s.height, s.width};
    if (s.components == 3) shape.push_back(3);  // (N, H, W, 3) RGB
    return shape;
  }
  bool streams() const override { return true; }
  void* buffer(int64_t, int64_t n) override {
    chunk_.resize(size_t(n) * image_bytes(spec_));
    return chunk_.data();
  }
  void write(int64_t, int64_t n) override {
    writer_.write(chunk_.data(), size_t(n) * image_bytes(spec_));
  }
  void finish(OutputSet& together) override { writer_.commit(&together); }

 private:
  StackSpec spec_;
  NpyWriter writer_;
  std::vector<unsigned char> chunk_;
};

// NIfTI / MetaImage / NRRD: ITK writes whole images, so the stack is held in memory.
class ItkStackWriter : public StackWriter {
 public:
  ItkStackWriter(const std::string& path, const StackSpec& spec) : path_(path), spec_(spec) {
    check_output_path(path);
    try {
      stack_.resize(size_t(spec.count) * image_bytes(spec));
    } catch (const std::bad_alloc&) {
      throw ResourceError("output '" + path + "': cannot hold " +
                          std::to_string((spec.count * image_bytes(spec)) >> 20) +
                          " MiB in memory; write .npy or a PNG directory (streamed) instead");
    }
  }
  bool streams() const override { return false; }
  void* buffer(int64_t first, int64_t) override {
    return stack_.data() + size_t(first) * image_bytes(spec_);
  }
  void write(int64_t, int64_t) override {}
  void finish(OutputSet& together) override {
    write_image(path_, stack_.data(), spec_.type, {spec_.width, spec_.height, spec_.count},
                {spec_.spacing_mm[0], spec_.spacing_mm[1], 1.0}, spec_.components, &together);
  }

 private:
  std::string path_;
  StackSpec spec_;
  std::vector<unsigned char> stack_;
};

// A directory of 8-bit PNGs plus poses.txt, built in a new temporary folder and renamed into
// place (replacing only a folder of sonoslice's own images). libpng, not ITK, writes the images:
// ITK's 2-D writer does not check its writes and crashed when the disk filled.
class PngStackWriter : public StackWriter {
 public:
  PngStackWriter(const std::string& path, const StackSpec& spec)
      : path_(path), spec_(spec), dir_(std::make_unique<AtomicFile>(path, OutputKind::Folder)) {
    if (!built_with_png())
      throw Error("output '" + path + "': this sonoslice was built without libpng; write .npy");
    digits_ = std::max<int>(5, int(std::to_string(std::max<int64_t>(spec.count - 1, 0)).size()));
    if (spec.window) window_ = spec.window;
  }
  bool streams() const override { return true; }
  void* buffer(int64_t, int64_t n) override {
    chunk_.resize(size_t(n) * image_bytes(spec_));
    return chunk_.data();
  }
  void write(int64_t first, int64_t n) override {
    const size_t pixels = size_t(spec_.width) * size_t(spec_.height);
    const bool rgb = spec_.components == 3;  // colour images go out as they are
    if (!rgb && !window_) window_ = auto_window(chunk_.data(), spec_.type, n, pixels, spec_.mask);
    // One image per task over the CPU threads: encoding, not slicing, is what a folder of PNGs
    // waits for. The first error stops the rest (the folder is then discarded whole).
    backend::parallel_for(n, [&](int64_t i) {
      std::vector<uint8_t> png(rgb ? 0 : pixels);
      const unsigned char* image = chunk_.data() + size_t(i) * image_bytes(spec_);
      if (!rgb)
        apply_window(image, spec_.type, pixels, window_->first, window_->second, png.data());
      char name[32];
      std::snprintf(name, sizeof name, "img_%0*lld.png", digits_,
                    static_cast<long long>(first + i));
      // The folder is new and ours, yet O_EXCL all the same: nothing is written through a link.
      const std::string file = (fs::path(dir_->temp_path()) / name).string();
      const int fd =
          ::open(file.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0666);
      if (fd < 0) throw FileError(write_error_message(path_, errno));
      try {
        write_png(fd, path_, rgb ? image : png.data(), PixelType::UInt8, spec_.width, spec_.height,
                  spec_.components, spec_.spacing_mm);
      } catch (...) {
        ::close(fd);
        throw;
      }
      if (::close(fd) != 0) throw FileError(write_error_message(path_, errno));
    });
  }
  void finish(OutputSet& together) override {
    const std::string poses = (fs::path(dir_->temp_path()) / "poses.txt").string();
    try {
      write_poses_text(poses, spec_.poses);
    } catch (const FileError& e) {  // named as the user will find it
      std::string message = e.what();
      const size_t at = message.find(dir_->temp_path());
      if (at != std::string::npos) message.replace(at, dir_->temp_path().size(), path_);
      throw FileError(message);
    }
    together.add(std::move(dir_));
  }

 private:
  std::string path_;
  StackSpec spec_;
  std::unique_ptr<AtomicFile> dir_;
  int digits_ = 5;
  std::optional<std::pair<double, double>> window_;
  std::vector<unsigned char> chunk_;
};

}  // namespace

void StackWriter::commit() {
  OutputSet alone;
  finish(alone);
  alone.commit();
}

StackFormat stack_format(const std::string& path) {
  switch (image_format(path, "output")) {
    case ImageFormat::Npy:
      return StackFormat::Npy;
    case ImageFormat::Nifti:
    case ImageFormat::MetaImage:
    case ImageFormat::Nrrd:
      return StackFormat::ItkImage;
    case ImageFormat::Directory:
      return StackFormat::PngDirectory;
    case ImageFormat::Dicom:
      throw InputError("output '" + path +
                       "': sonoslice reads DICOM but does not write it; write a stack as "
                       ".nii.gz, .mha, .nrrd, .npy or a directory of PNGs");
    case ImageFormat::Png:
      break;
  }
  throw InputError("output '" + path + "': a stack of images is one 3-D file (.nii.gz, .mha, " +
                   ".nrrd, .npy) or a directory of PNGs");
}

std::unique_ptr<StackWriter> StackWriter::create(const std::string& path, const StackSpec& spec) {
  // The pixel grid's rules are a volume's (the formats' writers abort or write nonsense on a
  // spacing of NaN or 1e300), checked before anything is created.
  VolumeGrid grid;
  grid.dims = {spec.width, spec.height, std::max<int64_t>(spec.count, 1)};
  grid.spacing_mm = {spec.spacing_mm[0], spec.spacing_mm[1], 1.0};
  grid.validate("output '" + path + "'");
  if (!spec.poses.empty())
    validate_poses(spec.poses.data(), spec.poses.size(), "poses for '" + path + "'", 0, false);
  std::string clean = path;
  while (clean.size() > 1 && clean.back() == '/') clean.pop_back();
  switch (stack_format(path)) {
    case StackFormat::Npy:
      return std::make_unique<NpyStackWriter>(clean, spec);
    case StackFormat::ItkImage:
      if (!built_with_itk())
        throw Error("output '" + path + "': this sonoslice was built without ITK; write .npy");
      return std::make_unique<ItkStackWriter>(clean, spec);
    case StackFormat::PngDirectory:
      return std::make_unique<PngStackWriter>(clean, spec);
  }
  return nullptr;
}

uint64_t stack_memory_bytes(const std::string& path, const StackSpec& spec, int64_t chunk) {
  const uint64_t one = image_bytes(spec);
  return stack_format(path) == StackFormat::ItkImage ? one * uint64_t(spec.count)
                                                     : one * uint64_t(std::min(chunk, spec.count));
}

int64_t chunk_images(size_t image_bytes, int64_t count, size_t bytes) {
  return std::max<int64_t>(
      1, std::min<int64_t>(count, int64_t(bytes / std::max<size_t>(image_bytes, 1))));
}

void apply_window(const void* images, PixelType type, size_t pixels, double level, double width,
                  uint8_t* out) {
  const double lo = level - width / 2, scale = width > 0 ? 255.0 / width : 0.0;
  for_each_value(images, type, pixels, [&](size_t i, double v) {
    const double g = (v - lo) * scale;
    out[i] = g != g ? 0 : uint8_t(std::lround(std::min(255.0, std::max(0.0, g))));
  });
}

std::pair<double, double> auto_window(const void* images, PixelType type, int64_t n,
                                      size_t image_pixels, const uint8_t* mask) {
  std::vector<double> values;
  values.reserve(size_t(n) * image_pixels / 2);
  for_each_value(images, type, size_t(n) * image_pixels, [&](size_t i, double v) {
    if ((!mask || mask[i % image_pixels]) && std::isfinite(v)) values.push_back(v);
  });
  if (values.empty()) return {0.5, 1.0};
  auto at = [&](double q) {
    auto it = values.begin() + std::ptrdiff_t(q * double(values.size() - 1));
    std::nth_element(values.begin(), it, values.end());
    return *it;
  };
  const double lo = at(0.005), hi = at(0.995);
  if (!(hi > lo)) return {lo, 1.0};
  return {(lo + hi) / 2, hi - lo};
}

}  // namespace sonoslice
