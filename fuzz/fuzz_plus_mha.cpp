// libFuzzer harness: PLUS tracked-frame sequences as MetaImage (.mha, ElementDataFile = LOCAL):
// header, per-frame fields, raw or compressed pixels, through read_plus_sequence, then every
// frame's status, transforms and timestamp.
#include "FuzzPlusSequence.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  return sonoslice::fuzz::fuzz_plus_sequence(data, size, "sequence.igs.mha");
}
