#pragma once
// What the two PLUS sequence harnesses share (fuzz_plus_mha.cpp, fuzz_plus_nrrd.cpp): the input,
// written under `name` (the extension picks the reader), through read_plus_sequence, then every
// frame's status, transforms and timestamp.
#include <string>

#include "FuzzCommon.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/plus/TransformRepository.h"

namespace sonoslice {
namespace fuzz {

inline int fuzz_plus_sequence(const uint8_t* data, size_t size, const std::string& name) {
  const std::string path = write_input(data, size, name);
  expect_sonoslice_errors_only([&] {
    const PlusSequence s = read_plus_sequence(path);
    for (int f = 0; f < s.frame_count; ++f) {
      s.image_ok(f);
      s.timestamp(f);
      for (const std::string& transform : s.transform_names(f)) s.transform(f, transform);
      TransformRepository repository;
      repository.set_frame(s, f);
    }
  });
  return 0;
}

}  // namespace fuzz
}  // namespace sonoslice
