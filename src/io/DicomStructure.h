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

/// FileError "cannot read <where>: ..." for a DICOM file whose elements do not fit together
/// (truncated, a length beyond its item or file, a missing delimiter, an unknown VR, a sequence
/// in the file meta group) or whose samples per pixel or ultrasound regions GDCM would assert on.
/// A file without the preamble (which GDCM also reads) is walked in the syntax GDCM guesses for
/// it, its file meta group explicit or implicit; one that does not start with an element is not
/// DICOM. Returns whether its data set holds pixel data (7FE0,0010).
bool check_structure(const std::string& path, const std::string& where);

/// Whether a file is DICOM at all: "DICM" after the 128-byte preamble, or (without it) first
/// bytes that start an element as GDCM guesses. A folder's other files (a README, a viewer's
/// index, .DS_Store) are not, and a folder's series scan does not show them to GDCM.
bool is_dicom(const std::string& path);

}  // namespace dicom
}  // namespace sonoslice
