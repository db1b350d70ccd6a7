// libFuzzer harness: OpenIGTLink messages as `sonoslice live` receives them. The input is a
// stream: each message's header is parsed and checked, its body (with the CRC made right, so the
// fuzzer reaches the content parsers) split into content and metadata, and the content parsed as
// every type sonoslice reads.
#include "sonoslice/live/Igtl.h"

#include <vector>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  size_t at = 0;
  while (size - at >= igtl::kHeaderBytes) {
    igtl::Header h = igtl::parse_header(data + at);
    at += igtl::kHeaderBytes;
    if (!igtl::header_problem(h).empty()) break;  // a stream cannot go on after a bad header
    const size_t n = size_t(std::min<uint64_t>(h.body_bytes, size - at));
    h.body_bytes = n;
    h.crc = igtl::crc64(data + at, n);
    igtl::Message m;
    fuzz::expect_sonoslice_errors_only([&] {
      if (!igtl::parse_body(h, data + at, n, m).empty()) return;
      igtl::Image image;
      Mat4 transform;
      std::string text;
      uint16_t code = 0;
      igtl::Command command;
      if (igtl::parse_image(m.content, image).empty() && image.pixel_bytes > 0)
        (void)image.pixels[image.pixel_bytes - 1];  // the pixels it points at are in the body
      igtl::parse_transform(m.content, transform);
      igtl::parse_string(m.content, text);
      igtl::parse_status(m.content, code, text);
      igtl::parse_command(m.content, command);
    });
    at += n;
  }
  return 0;
}
