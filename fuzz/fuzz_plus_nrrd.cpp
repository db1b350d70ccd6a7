// libFuzzer harness: PLUS tracked-frame sequences as NRRD: header, per-frame fields, raw or
// compressed pixels, through read_plus_sequence, then every frame's status, transforms and
// timestamp.
#include "sonoslice/io/PlusSequence.h"

#include <algorithm>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = fuzz::write_input(data, size, "sequence.igs.nrrd");
  fuzz::expect_sonoslice_errors_only([&] {
    const PlusSequence s = read_plus_sequence(path);
    for (int f = 0; f < s.frame_count; ++f) {
      s.image_ok(f);
      s.timestamp(f);
      for (const std::string& name : s.transform_names(f)) s.transform(f, name);
      TransformRepository repository;
      repository.set_frame(s, f);
    }
  });
  return 0;
}
