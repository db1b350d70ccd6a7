// Runs a harness's LLVMFuzzerTestOneInput once on every file given (a directory: every file in
// it), without libFuzzer and without mutation: the regression inputs and the seeds become a ctest
// test in every build, the GCC sanitizer build (scripts/sanitize.sh) included.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "FuzzCommon.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  size_t count = 0;
  for (int i = 1; i < argc; ++i) {
    std::vector<fs::path> files;
    std::error_code ec;
    if (fs::is_directory(argv[i], ec)) {
      for (const auto& entry : fs::directory_iterator(argv[i]))
        if (entry.is_regular_file()) files.push_back(entry.path());
      std::sort(files.begin(), files.end());
    } else if (fs::exists(argv[i], ec)) {
      files.push_back(argv[i]);
    }
    for (const fs::path& file : files) {
      std::ifstream in(file, std::ios::binary);
      const std::vector<uint8_t> data{std::istreambuf_iterator<char>(in),
                                      std::istreambuf_iterator<char>()};
      // Named first: a crash below leaves this as the last line, naming the input.
      std::fprintf(stderr, "replay: %s\n", file.c_str());
      LLVMFuzzerTestOneInput(data.data(), data.size());
      ++count;
    }
  }
  std::error_code ec;
  fs::remove_all(sonoslice::fuzz::work_dir(), ec);
  std::printf("replay: %zu inputs ran clean\n", count);
  return 0;
}
