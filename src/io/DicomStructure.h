#pragma once
// Internal: DICOM files walked element by element before GDCM reads them.
//
// GDCM as Debian (and any build without NDEBUG) ships it asserts on broken files, which aborts
// the whole process: a length past the end of the file, a value of the file meta group cut short,
// an unknown value representation, samples per pixel other than 1, 3 or 4 (mutating real
// ultrasound clips byte by byte, 41 of 400 files aborted sonoslice, and one such file in a
// folder aborted the reading of every series there). GDCM cannot be told to refuse instead, so
// sonoslice checks the structure itself first: every element's length within its file, item and
// sequence; the item and sequence delimiters; the encapsulated fragments; and the attributes
// GDCM asserts on. It reads headers only (values are skipped by seeking), written by hand because
// no library offers a check that cannot abort.
#include <string>

namespace sonoslice {
namespace dicom {

/// FileError "cannot read <where>: ..." for a Part 10 file whose elements do not fit together
/// (truncated, a length beyond its item or file, a missing delimiter, an unknown VR) or whose
/// samples per pixel GDCM would assert on. A file without the preamble is left to GDCM, which
/// refuses what is not DICOM without asserting.
void check_structure(const std::string& path, const std::string& where);

}  // namespace dicom
}  // namespace sonoslice
