// libFuzzer harness: DICOM Part 10 files (sonoslice's structure walk, then GDCM through ITK): a
// multi-frame clip read as frames (read_image_stack), the file as a volume (read_volume), and the
// file alone in a folder read as a series (the folder check, GDCM's series scan and reader).
#include "sonoslice/io/VolumeFile.h"

#include <filesystem>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = fuzz::write_input(data, size, "clip.dcm");
  fuzz::expect_sonoslice_errors_only([&] { fuzz::touch(read_image_stack(path, "--frames")); });
  fuzz::expect_sonoslice_errors_only([&] { fuzz::touch(read_volume(path)); });
  const std::filesystem::path series = fuzz::work_dir() / "series";
  std::filesystem::create_directories(series);
  fuzz::write_input(data, size, "series/slice.dcm");
  fuzz::expect_sonoslice_errors_only([&] { fuzz::touch(read_volume(series.string())); });
  return 0;
}
