// DICOM Part 10 structure, walked before GDCM reads a file (DicomStructure.h says why).
#include "DicomStructure.h"

#include <sys/types.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <map>
#include <sstream>

#include <gdcmPhotometricInterpretation.h>

#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace dicom {
namespace {

constexpr uint32_t kUndefined = 0xffffffffu;
constexpr int kMaxDepth = 32;  // sequences within sequences; deeper is not an image's header

std::string hex4(unsigned v) {
  char s[8];
  std::snprintf(s, sizeof s, "%04X", v & 0xffffu);
  return s;
}

std::string tag_text(unsigned group, unsigned element) {
  return "(" + hex4(group) + "," + hex4(element) + ")";
}

bool known_vr(const char* vr) {
  static const char* const kVrs[] = {"AE", "AS", "AT", "CS", "DA", "DS", "DT", "FD", "FL",
                                     "IS", "LO", "LT", "OB", "OD", "OF", "OL", "OV", "OW",
                                     "PN", "SH", "SL", "SQ", "SS", "ST", "SV", "TM", "UC",
                                     "UI", "UL", "UN", "UR", "US", "UT", "UV"};
  for (const char* k : kVrs)
    if (vr[0] == k[0] && vr[1] == k[1]) return true;
  return false;
}

// Whether the first six bytes of a file without the preamble start an element in the syntax GDCM
// guesses: the file meta group, a known explicit VR, or the groups and element GDCM looks for.
bool starts_with_element(const uint8_t first[6]) {
  const unsigned group = unsigned(first[0] | first[1] << 8),
                 element = unsigned(first[2] | first[3] << 8);
  return group == 0x0002 || known_vr(reinterpret_cast<const char*>(first + 4)) || group == 0x0008 ||
         group == 0x0800 || element == 0x0010;
}

// Explicit VRs whose length is 32 bits, after two reserved bytes.
bool long_vr(const char* vr) {
  static const char* const kLong[] = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ",
                                      "SV", "UC", "UN", "UR", "UT", "UV"};
  for (const char* k : kLong)
    if (vr[0] == k[0] && vr[1] == k[1]) return true;
  return false;
}

// Attributes GDCM reads into typed values when it reads an image, with their value
// representations (PS3.6); an explicit VR it does not find compatible is an assertion in GDCM.
struct TypedAttribute {
  uint32_t tag;
  const char* vrs;  // the VRs allowed, two characters each
};
constexpr TypedAttribute kTypedAttributes[] = {
    {0x00180050, "DS"},   {0x00180088, "DS"},   {0x00181164, "DS"},   {0x0018602c, "FD"},
    {0x0018602e, "FD"},   {0x00200032, "DS"},   {0x00200037, "DS"},   {0x00280002, "US"},
    {0x00280006, "US"},   {0x00280008, "IS"},   {0x00280009, "AT"},   {0x00280010, "US"},
    {0x00280011, "US"},   {0x00280030, "DS"},   {0x00280034, "IS"},   {0x00280100, "US"},
    {0x00280101, "US"},   {0x00280102, "US"},   {0x00280103, "US"},   {0x00280106, "USSS"},
    {0x00280107, "USSS"}, {0x00281050, "DS"},   {0x00281051, "DS"},   {0x00281052, "DS"},
    {0x00281053, "DS"},   {0x00281101, "USSS"}, {0x00281102, "USSS"}, {0x00281103, "USSS"},
    {0x3004000c, "DS"}};

// The VRs `tag` may have when GDCM reads it typed, or nullptr for any.
const char* typed_vrs(uint32_t tag) {
  for (const TypedAttribute& a : kTypedAttributes)
    if (a.tag == tag) return a.vrs;
  return nullptr;
}

struct Element {
  unsigned group = 0, element = 0;
  char vr[2] = {0, 0};  // explicit VR only
  uint32_t length = 0;
  uint64_t value_at = 0;
};

class Walker {
 public:
  Walker(std::FILE* f, uint64_t size, std::string where)
      : f_(f), size_(size), where_(std::move(where)) {}

  // `part10`: the file has the preamble and "DICM"; otherwise its first element starts it.
  // Returns whether the data set holds pixel data.
  bool check(bool part10) {
    uint64_t at = part10 ? 132 : 0;
    uint8_t first[6];
    if (!read(at, first, 6)) fail("truncated file (shorter than one element)");
    const unsigned group = u16(first, true), element = u16(first + 2, true);
    const bool first_vr = known_vr(reinterpret_cast<const char*>(first + 4));
    if (!part10 && group != 0x0002) {
      // No file meta information: the syntax guessed from the first element, as GDCM does.
      if (group == 0x0800 ||
          (first_vr && group != 0x0008 && element != 0x0010 && (group > 0xff || element > 0xff)))
        little_ = false;
      if (!starts_with_element(first))
        fail("not a DICOM file (no \"DICM\" at byte 128, and it does not start with an element)");
      check_tail(walk(0, size_, first_vr, 0, /*top=*/true, /*until_delimiter=*/false), first_vr);
      check_pixel_format();
      return pixel_data_;
    }
    // GDCM takes a Part 10 file's meta group to start with its group length, (0002,0000) UL, and
    // reads one that does not by guesswork that this walk cannot follow.
    if (part10 && !(group == 0x0002 && element == 0x0000 && first[4] == 'U' && first[5] == 'L'))
      fail(
          "corrupt file (its file meta information does not start with its group length "
          "(0002,0000))");
    // The file meta group (0002): explicit VR little endian, whatever the data set's syntax
    // (implicit in some files without the preamble, which GDCM reads).
    const bool meta_explicit = part10 || first_vr;
    std::string syntax;
    bool have_syntax = false;
    for (;;) {
      uint8_t tag[4];
      if (!read(at, tag, 4)) fail("truncated file (it ends in its file meta information)");
      if ((tag[0] | tag[1] << 8) != 0x0002) break;
      const Element e = header(at, size_, meta_explicit, /*little=*/true);
      if (e.length == kUndefined) fail("corrupt file (a file meta element of undefined length)");
      if (e.vr[0] == 'S' && e.vr[1] == 'Q')
        fail("corrupt file (a sequence " + tag_text(e.group, e.element) +
             " in its file meta information)");
      fits(e, size_);
      if (e.element == 0x0010) {
        syntax.assign(e.length, '\0');
        if (e.length && !read(e.value_at, &syntax[0], e.length)) fail("truncated file");
        while (!syntax.empty() && (syntax.back() == '\0' || syntax.back() == ' '))
          syntax.pop_back();
        have_syntax = true;
      }
      at = e.value_at + e.length;
    }
    // Deflated: GDCM inflates, then reads (taken to hold pixel data, so that they are checked).
    if (syntax == "1.2.840.10008.1.2.1.99") return true;
    rle_ = syntax == "1.2.840.10008.1.2.5";
    bool explicit_vr = syntax != "1.2.840.10008.1.2";
    little_ = syntax != "1.2.840.10008.1.2.2";
    if (!have_syntax) {  // no transfer syntax: explicit when the first VR reads as one
      uint8_t next[6];
      explicit_vr = read(at, next, 6) && known_vr(reinterpret_cast<const char*>(next + 4));
    }
    check_tail(walk(at, size_, explicit_vr, 0, /*top=*/true, /*until_delimiter=*/false),
               explicit_vr);
    check_pixel_format();
    return pixel_data_;
  }

 private:
  std::FILE* f_;
  uint64_t size_;
  std::string where_;
  bool little_ = true;
  bool rle_ = false;  // RLE Lossless: each frame's fragment starts with its segment table

  [[noreturn]] void fail(const std::string& why) const {
    throw FileError("cannot read " + where_ + ": " + why);
  }

  bool read(uint64_t at, void* out, size_t n) const {
    if (at > size_ || n > size_ - at) return false;
    if (::fseeko(f_, off_t(at), SEEK_SET) != 0) return false;
    return std::fread(out, 1, n, f_) == n;
  }
  unsigned u16(const uint8_t* b, bool little) const {
    return little ? unsigned(b[0] | b[1] << 8) : unsigned(b[0] << 8 | b[1]);
  }
  uint32_t u32(const uint8_t* b, bool little) const {
    return little
               ? uint32_t(b[0]) | uint32_t(b[1]) << 8 | uint32_t(b[2]) << 16 | uint32_t(b[3]) << 24
               : uint32_t(b[3]) | uint32_t(b[2]) << 8 | uint32_t(b[1]) << 16 | uint32_t(b[0]) << 24;
  }

  // The element header at `at`, which must end before `end`. Items and delimiters (group FFFE)
  // have no VR in either syntax.
  Element header(uint64_t at, uint64_t end, bool explicit_vr, bool little) const {
    uint8_t h[12];
    const auto need = [&](uint64_t n) {
      if (at + n > end || !read(at, h, size_t(n)))
        fail(end == size_ ? "truncated file (it ends inside an element's header at byte " +
                                std::to_string(at) + ")"
                          : "corrupt file (an element's header at byte " + std::to_string(at) +
                                " crosses the end of its item)");
    };
    need(8);
    Element e;
    e.group = u16(h, little);
    e.element = u16(h + 2, little);
    if (e.group == 0xfffe || !explicit_vr) {
      e.length = u32(h + 4, little);
      e.value_at = at + 8;
      return e;
    }
    e.vr[0] = char(h[4]);
    e.vr[1] = char(h[5]);
    if (!known_vr(e.vr))
      fail("corrupt file (element " + tag_text(e.group, e.element) + " at byte " +
           std::to_string(at) + " has no valid value representation)");
    if (long_vr(e.vr)) {
      need(12);
      e.length = u32(h + 8, little);
      e.value_at = at + 12;
    } else {
      e.length = u16(h + 6, little);
      e.value_at = at + 8;
    }
    return e;
  }

  // A defined length must end within `end`: the file, or the item holding the element.
  void fits(const Element& e, uint64_t end) const {
    if (e.value_at + e.length <= end) return;
    std::ostringstream s;
    if (e.group == 0x7fe0 && e.element == 0x0010)
      s << "truncated or corrupt file (its pixel data needs " << e.value_at + e.length
        << " bytes, the file has " << size_ << ")";
    else if (end == size_)
      s << "truncated or corrupt file (element " << tag_text(e.group, e.element) << " needs "
        << e.value_at + e.length << " bytes, the file has " << size_ << ")";
    else
      s << "corrupt file (element " << tag_text(e.group, e.element) << " at byte " << e.value_at
        << " runs past the end of its item)";
    fail(s.str());
  }

  // Elements from `at` to `end` (or, `until_delimiter`, to an item delimiter); returns where the
  // walk stopped. `top`: the data set itself, whose image attributes are checked. `children`:
  // where to note each element (its header) by tag (group << 16 | element).
  uint64_t walk(uint64_t at, uint64_t end, bool explicit_vr, int depth, bool top,
                bool until_delimiter, std::map<uint32_t, Element>* children = nullptr) {
    if (depth > kMaxDepth) fail("corrupt file (sequences nested deeper than 32)");
    while (at < end) {
      const Element e = header(at, end, explicit_vr, little_);
      if (e.group == 0xfffe) {
        if (until_delimiter && e.element == 0xe00d) return delimiter(e, at);
        fail("corrupt file (a delimiter " + tag_text(e.group, e.element) + " at byte " +
             std::to_string(at) + " out of place)");
      }
      if (children) (*children)[uint32_t(e.group) << 16 | e.element] = e;
      if (explicit_vr) check_typed_vr(e);
      const bool pixel_data = e.group == 0x7fe0 && e.element == 0x0010;
      if (top && pixel_data) pixel_data_ = true, pixel_native_ = e.length != kUndefined;
      const bool regions = top && e.group == 0x0018 && e.element == 0x6011;
      Regions first_region;
      const bool sequence =
          !explicit_vr || (e.vr[0] == 'S' && e.vr[1] == 'Q') || (e.vr[0] == 'U' && e.vr[1] == 'N');
      if (e.length == kUndefined) {
        if (pixel_data) {
          at = fragments(e.value_at, end);
          if (top) return at;
        } else if (sequence) {
          // An undefined-length UN is a sequence in implicit VR (PS3.5 6.2.2).
          at = items(e.value_at, end, explicit_vr && e.vr[0] != 'U', depth + 1, true,
                     regions ? &first_region : nullptr);
          if (regions) check_regions(first_region);
        } else {
          fail("corrupt file (element " + tag_text(e.group, e.element) +
               " has an undefined length)");
        }
        continue;
      }
      fits(e, end);
      if ((explicit_vr && e.vr[0] == 'S' && e.vr[1] == 'Q') || (regions && !explicit_vr)) {
        items(e.value_at, e.value_at + e.length, explicit_vr, depth + 1, false,
              regions ? &first_region : nullptr);
        if (regions) check_regions(first_region);
      }
      if (top && e.group == 0x0028 && e.element == 0x0008)
        number_of_frames(e);
      else if (top && e.group == 0x0028 && e.element == 0x0004)
        photometric_interpretation(e);
      else if (top && e.group == 0x0028 && e.length >= 2)
        note_pixel_format(e);
      if (top && e.group == 0x0008 && e.element == 0x0010 && e.length > 0) recognition_code(e);
      at = e.value_at + e.length;
      // What follows the pixel data is not the image's: check_tail() walks it.
      if (top && pixel_data) return at;
    }
    if (until_delimiter) fail("truncated file (an item without its delimiter)");
    return at;
  }

  // The pixel format attributes (0028,xxxx) of the data set, -1 where absent. Of an attribute
  // given twice the first counts: GDCM keeps the first and skips the duplicates.
  int samples_ = -1, bits_allocated_ = -1, bits_stored_ = -1, representation_ = -1;
  int rows_ = -1, columns_ = -1, planar_ = -1;
  int64_t frames_ = -1;
  bool pixel_data_ = false, pixel_native_ = false;  // native: not encapsulated in fragments
  // The photometric interpretation as GDCM reads it, and its text (its first value counts, as
  // above).
  bool photometric_seen_ = false;
  gdcm::PhotometricInterpretation::PIType photometric_ = gdcm::PhotometricInterpretation::UNKNOWN;
  std::string photometric_text_;
  // RLE Lossless: the frames' fragments (the basic offset table not counted) and the shortest.
  int64_t rle_fragments_ = 0;
  uint64_t rle_shortest_ = 0;

  void note_pixel_format(const Element& e) {
    int* value = e.element == 0x0002   ? &samples_
                 : e.element == 0x0006 ? &planar_
                 : e.element == 0x0010 ? &rows_
                 : e.element == 0x0011 ? &columns_
                 : e.element == 0x0100 ? &bits_allocated_
                 : e.element == 0x0101 ? &bits_stored_
                 : e.element == 0x0103 ? &representation_
                                       : nullptr;
    if (!value || *value >= 0) return;
    uint8_t v[2];
    if (!read(e.value_at, v, 2)) fail("truncated file");
    *value = int(u16(v, little_));
  }

  // Photometric interpretation (0028,0004), a code string, named by GDCM's own matching (which
  // takes a value that starts a name, "PALETTE COLO", for that name). GDCM reads the value as a
  // C string and, given an empty one, reads before its start: blank values are told apart here.
  void photometric_interpretation(const Element& e) {
    if (photometric_seen_) return;
    photometric_seen_ = true;
    std::string text(std::min<uint32_t>(e.length, 64), '\0');
    if (!text.empty() && !read(e.value_at, &text[0], text.size())) fail("truncated file");
    text = text.substr(0, text.find('\0'));
    photometric_text_ = text;
    photometric_ = text.find_first_not_of(' ') == std::string::npos
                       ? gdcm::PhotometricInterpretation::PI_END
                       : gdcm::PhotometricInterpretation::GetPIType(text.c_str());
  }

  // Number of frames (0028,0008), an integer string: GDCM reads its leading number (leading
  // spaces, an optional '+', digits; trailing padding or a second value after a backslash do not
  // count) and sizes the image's buffer by it; 0 (or none) asserts in its decoder.
  void number_of_frames(const Element& e) {
    if (frames_ >= 0) return;
    std::string text(std::min<uint32_t>(e.length, 16), '\0');
    if (!text.empty() && !read(e.value_at, &text[0], text.size())) fail("truncated file");
    size_t i = text.find_first_not_of(' ');
    if (i != std::string::npos && text[i] == '+') ++i;
    int64_t n = 0;
    size_t digits = 0;
    for (; i < text.size() && std::isdigit(static_cast<unsigned char>(text[i])) && n < (1 << 30);
         ++i, ++digits)
      n = n * 10 + (text[i] - '0');
    if (digits == 0 || n < 1 || n >= (1 << 30))
      fail("corrupt file (its number of frames (0028,0008) is not a count of frames)");
    frames_ = n;
  }

  // The pixel format GDCM asserts on (its PixelFormat): samples per pixel other than 1, 3 or 4;
  // bits allocated not a whole number of bytes (but 1 and 12); more bits stored than allocated,
  // or more than 32, or fewer than 8 of 8; a pixel representation other than 0 (unsigned) or 1
  // (signed); a planar configuration other than 0 or 1; RLE frames of a format its decoder does
  // not take.
  void check_pixel_format() const {
    const auto bad = [&](const std::string& what) {
      fail("corrupt file (" + what + ": not a DICOM pixel format)");
    };
    if (pixel_data_ && (rows_ < 0 || columns_ < 0 || bits_allocated_ < 0))
      fail(
          "corrupt file (pixel data without the rows, columns and bits allocated of its image, "
          "(0028,0010), (0028,0011) and (0028,0100))");
    // GDCM asserts (or aborts) on palette images whose lookup tables are missing or do not fit
    // their descriptors; sonoslice reads greyscale and RGB images, so palettes are refused.
    using PI = gdcm::PhotometricInterpretation;
    if (pixel_data_ && photometric_seen_ && photometric_ == PI::PALETTE_COLOR)
      fail(
          "PALETTE COLOR images are not supported (greyscale and RGB are; convert the palette "
          "to RGB first)");
    if (samples_ >= 0 && samples_ != 1 && samples_ != 3 && samples_ != 4)
      fail("corrupt file (samples per pixel " + std::to_string(samples_) +
           ": DICOM images have 1, 3 or 4)");
    // GDCM's decoders assert on the interpretations they do not convert (uncompressed and RLE:
    // all but greyscale, RGB and YBR_FULL(_422); JPEG-LS: HSV, ARGB, CMYK, YBR_PARTIAL_420) and
    // on a value that names none, and read past the pixels' end, or assert, for a colour
    // interpretation of one sample per pixel or a greyscale one of three. Refused here is what
    // DICOM does not allow either: YBR_FULL_422 in RLE, the JPEG colour spaces (YBR_PARTIAL_422,
    // YBR_ICT, YBR_RCT) in other than JPEG-family compressed data, and the retired ones.
    if (pixel_data_ && photometric_seen_) {
      const bool jpeg = !pixel_native_ && !rle_;
      const bool grey = photometric_ == PI::MONOCHROME1 || photometric_ == PI::MONOCHROME2;
      const bool colour = photometric_ == PI::RGB || photometric_ == PI::YBR_FULL ||
                          (photometric_ == PI::YBR_FULL_422 && !rle_) ||
                          (jpeg && (photometric_ == PI::YBR_PARTIAL_422 ||
                                    photometric_ == PI::YBR_ICT || photometric_ == PI::YBR_RCT));
      const std::string name = printable(photometric_text_);
      if (!grey && !colour)
        fail((name.empty() ? "an empty photometric interpretation"
                           : "photometric interpretation '" + name + "'") +
             " is not supported in " +
             (rle_            ? "RLE"
              : pixel_native_ ? "uncompressed"
                              : "compressed") +
             " pixel data (MONOCHROME1, MONOCHROME2, RGB and YBR_FULL are; YBR_FULL_422 but in "
             "RLE; YBR_PARTIAL_422, YBR_ICT and YBR_RCT in JPEG-compressed data)");
      const int samples = samples_ < 0 ? 1 : samples_;
      if (samples != (grey ? 1 : 3))
        fail("corrupt file (photometric interpretation '" + name + "' with " +
             std::to_string(samples) + " sample" + (samples == 1 ? "" : "s") +
             " per pixel: MONOCHROME1 and MONOCHROME2 have 1, the colour ones 3)");
    }
    // 0 bits allocated: GDCM keeps its default bits stored (8) above it and asserts.
    if (bits_allocated_ == 0 || (bits_allocated_ > 0 && bits_allocated_ % 8 &&
                                 bits_allocated_ != 1 && bits_allocated_ != 12))
      bad("bits allocated " + std::to_string(bits_allocated_));
    if (bits_stored_ > 32) bad("bits stored " + std::to_string(bits_stored_));
    if (bits_stored_ >= 0 && bits_allocated_ >= 0 && bits_stored_ > bits_allocated_)
      bad("bits stored " + std::to_string(bits_stored_) + " of " + std::to_string(bits_allocated_) +
          " allocated");
    if (representation_ > 1) bad("pixel representation " + std::to_string(representation_));
    if (planar_ > 1) bad("planar configuration " + std::to_string(planar_));
    // GDCM's decoder clears unused high bits only in pixels of more than 8 bits.
    if (bits_allocated_ == 8 && bits_stored_ > 0 && bits_stored_ != 8)
      bad("bits stored " + std::to_string(bits_stored_) + " of 8 allocated");
    // RLE Lossless holds one frame a fragment, and a fragment at most 64 bytes of pixels a byte
    // (a run of 128 equal bytes in 2): a header claiming more is refused before GDCM allocates
    // what it claims.
    if (rle_ && pixel_data_ && rows_ > 0 && columns_ > 0 && bits_allocated_ > 0) {
      const int64_t frames = frames_ > 0 ? frames_ : 1;
      if (frames > rle_fragments_)
        fail("corrupt file (RLE Lossless pixel data of " + std::to_string(frames) + " frames in " +
             std::to_string(rle_fragments_) + " fragments, one a frame)");
      const uint64_t frame_bytes = uint64_t(rows_) * uint64_t(columns_) *
                                   uint64_t(samples_ > 0 ? samples_ : 1) *
                                   uint64_t((bits_allocated_ + 7) / 8);
      if (frame_bytes > 64 * rle_shortest_)
        fail("corrupt file (its header claims frames of " + std::to_string(frame_bytes) +
             " bytes, more than an RLE fragment of " + std::to_string(rle_shortest_) +
             " bytes can hold)");
    }
    // GDCM's RLE decoder asserts on other formats.
    if (rle_ && pixel_data_ &&
        (!(bits_allocated_ == 8 || bits_allocated_ == 16 || bits_allocated_ == 32) ||
         !(samples_ < 0 || samples_ == 1 || samples_ == 3)))
      fail("corrupt file (RLE Lossless frames of " + std::to_string(bits_allocated_) +
           " bits allocated and " + std::to_string(samples_ < 0 ? 1 : samples_) +
           " samples per pixel: RLE holds 8, 16 or 32 bits of 1 or 3 samples)");
  }

  // An attribute GDCM reads typed (kTypedAttributes) in a value representation it asserts on.
  void check_typed_vr(const Element& e) const {
    const char* vrs = typed_vrs(uint32_t(e.group) << 16 | e.element);
    if (!vrs) return;
    for (const char* v = vrs; *v; v += 2)
      if (v[0] == e.vr[0] && v[1] == e.vr[1]) return;
    fail("corrupt file (element " + tag_text(e.group, e.element) +
         " has the value representation " + text_vr(e.vr) + "; DICOM defines " +
         std::string(vrs, 2) + ")");
  }
  static std::string text_vr(const char* vr) { return printable(std::string(vr, 2)); }
  // A value for a message: other bytes than printable ASCII as '?', trailing padding dropped.
  static std::string printable(std::string t) {
    for (char& c : t)
      if (!std::isprint(static_cast<unsigned char>(c))) c = '?';
    while (!t.empty() && t.back() == ' ') t.pop_back();
    return t;
  }

  // What follows the image's pixel data: GDCM reads it as elements too, and asserts on some that
  // are cut short. Elements, or zero bytes that GDCM passes over (fewer than 4, or 8 and more).
  void check_tail(uint64_t at, bool explicit_vr) {
    if (at >= size_) return;
    const uint64_t n = size_ - at;
    if (n < 4 || (n >= 8 && all_zero(at, n))) return;
    walk(at, size_, explicit_vr, 0, /*top=*/false, /*until_delimiter=*/false);
  }
  bool all_zero(uint64_t at, uint64_t n) const {
    uint8_t chunk[4096];
    for (uint64_t done = 0; done < n;) {
      const size_t k = size_t(std::min<uint64_t>(sizeof chunk, n - done));
      if (!read(at + done, chunk, k)) return false;
      for (size_t i = 0; i < k; ++i)
        if (chunk[i]) return false;
      done += k;
    }
    return true;
  }

  // ACR-NEMA's recognition code (0008,0010), which GDCM asserts is "ACR-NEMA" or "ACRNEMA" when
  // an image has one.
  void recognition_code(const Element& e) const {
    char v[8] = {0};
    const size_t n = std::min<size_t>(e.length, 8);
    if (!read(e.value_at, v, n)) fail("truncated file");
    if (std::strncmp(v, "ACR-NEMA", 8) != 0 && std::strncmp(v, "ACRNEMA", 7) != 0)
      fail("corrupt file (its recognition code (0008,0010) is not ACR-NEMA's)");
  }

  // A delimiter (item or sequence) at `at`: its length must be 0 (PS3.5 7.5), which GDCM takes
  // as the length of a value to allocate. Returns where it ends.
  uint64_t delimiter(const Element& e, uint64_t at) const {
    if (e.length != 0)
      fail("corrupt file (the delimiter " + tag_text(e.group, e.element) + " at byte " +
           std::to_string(at) + " has the length " + std::to_string(e.length) + ", not 0)");
    return e.value_at;
  }

  // The first item of a sequence: whether there is one, and its elements' headers by tag.
  struct Regions {
    bool found = false;
    std::map<uint32_t, Element> children;
  };

  // An ultrasound image's regions (0018,6011): GDCM reads the physical size of a pixel from the
  // first one and asserts unless it holds both deltas, (0018,602C) and (0018,602E), FD of one
  // value each.
  void check_regions(const Regions& first) const {
    if (!first.found) fail("corrupt file (its ultrasound regions (0018,6011) hold no item)");
    for (const uint32_t tag : {0x0018602cu, 0x0018602eu}) {
      const auto it = first.children.find(tag);
      const char* vr = it == first.children.end() ? "" : it->second.vr;
      if (it == first.children.end() || it->second.length != 8 ||
          (vr[0] && !(vr[0] == 'F' && vr[1] == 'D')))
        fail("corrupt file (its first ultrasound region lacks the physical delta " +
             tag_text(tag >> 16, tag & 0xffff) + ", one FD value)");
    }
  }

  // The items of a sequence from `at`: to `end` (a defined length), or, `undefined`, to the
  // sequence delimiter. Returns the position after the sequence. `first`: where to note the
  // first item's elements.
  uint64_t items(uint64_t at, uint64_t end, bool explicit_vr, int depth, bool undefined,
                 Regions* first = nullptr) {
    while (at < end) {
      const Element item = header(at, end, explicit_vr, little_);
      if (item.group == 0xfffe && item.element == 0xe0dd) return delimiter(item, at);
      if (item.group != 0xfffe || item.element != 0xe000)
        fail("corrupt file (a sequence holds " + tag_text(item.group, item.element) + " at byte " +
             std::to_string(at) + " where an item belongs)");
      std::map<uint32_t, Element>* children = nullptr;
      if (first && !first->found) {
        first->found = true;
        children = &first->children;
      }
      if (item.length == kUndefined) {
        at =
            walk(item.value_at, end, explicit_vr, depth, false, /*until_delimiter=*/true, children);
      } else {
        fits(item, end);
        walk(item.value_at, item.value_at + item.length, explicit_vr, depth, false, false,
             children);
        at = item.value_at + item.length;
      }
    }
    if (undefined)
      fail(end == size_ ? "truncated file (a sequence without its delimiter)"
                        : "corrupt file (a sequence runs past the end of its item)");
    return at;
  }

  // Encapsulated (compressed) pixel data: items to the sequence delimiter, each within the file.
  uint64_t fragments(uint64_t at, uint64_t end) {
    bool first_item = true;  // the basic offset table
    for (;;) {
      uint8_t h[8];
      if (at + 8 > end || !read(at, h, 8))
        fail("truncated file (its compressed pixel data ends at byte " + std::to_string(size_) +
             ", before its last fragment)");
      const unsigned group = u16(h, true), element = u16(h + 2, true);
      if (group != 0xfffe || (element != 0xe000 && element != 0xe0dd))
        fail("corrupt file (compressed pixel data without its fragment items)");
      const uint64_t n = u32(h + 4, true);
      if (element == 0xe0dd) {
        Element e;
        e.group = group;
        e.element = element;
        e.length = uint32_t(n);
        e.value_at = at + 8;
        return delimiter(e, at);
      }
      at += 8;
      if (at + n > end) {
        std::ostringstream s;
        s << "truncated file (a fragment of its compressed pixel data needs " << at + n
          << " bytes, the file has " << size_ << ")";
        fail(s.str());
      }
      if (rle_ && !first_item) {
        rle_segments(at, n);
        rle_shortest_ = rle_fragments_++ ? std::min(rle_shortest_, n) : n;
      }
      first_item = false;
      at += n;
    }
  }

  // An RLE frame's header (PS3.5 G.3.1): the segment count (1 to 15) and their offsets, the
  // first 64, ascending, within the fragment, the unused ones 0. GDCM's decoder reads past its
  // buffers on a broken one.
  void rle_segments(uint64_t at, uint64_t length) const {
    uint8_t h[64];
    if (length < 64 || !read(at, h, 64))
      fail("corrupt file (an RLE frame shorter than its 64-byte header)");
    const uint32_t segments = u32(h, true);
    bool ok = segments >= 1 && segments <= 15 && u32(h + 4, true) == 64;
    for (uint32_t i = 1; ok && i < 15; ++i) {
      const uint32_t offset = u32(h + 4 + 4 * i, true);
      ok = i < segments ? offset > u32(h + 4 * i, true) && offset < length : offset == 0;
    }
    if (!ok)
      fail("corrupt file (an RLE frame's segment table at byte " + std::to_string(at) +
           " is broken)");
  }
};

}  // namespace

bool check_structure(const std::string& path, const std::string& where) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) throw FileError("cannot read " + where + ": " + std::strerror(errno));
  struct Close {
    std::FILE* f;
    ~Close() { std::fclose(f); }
  } close{f};
  // A Part 10 file: a 128-byte preamble, then "DICM"; GDCM also reads files without them.
  char magic[4] = {0};
  const bool part10 = std::fseek(f, 128, SEEK_SET) == 0 && std::fread(magic, 1, 4, f) == 4 &&
                      std::memcmp(magic, "DICM", 4) == 0;
  if (::fseeko(f, 0, SEEK_END) != 0) throw FileError("cannot read " + where + ": cannot seek");
  const uint64_t size = uint64_t(::ftello(f));
  return Walker(f, size, where).check(part10);
}

bool is_dicom(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) return true;  // unreadable: check_structure says why
  uint8_t head[132];
  const size_t n = std::fread(head, 1, sizeof head, f);
  std::fclose(f);
  if (n == sizeof head && std::memcmp(head + 128, "DICM", 4) == 0) return true;
  // A file shorter than one element's header whose first bytes start one as GDCM guesses is
  // DICOM, truncated: GDCM's series scan asserts on it, so it is walked (and refused) too.
  if (n < 2) return false;
  std::memset(head + n, 0, sizeof head - n);
  return starts_with_element(head);
}

}  // namespace dicom
}  // namespace sonoslice
