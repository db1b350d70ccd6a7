// sonoslice live: the OpenIGTLink codec (layouts, CRC, timestamps, every way a message can be
// malformed), the network endpoint and the live compounder (queue policies, counts, and the
// volume against the offline reconstruction of the same frames).
#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <random>
#include <thread>

#include "sonoslice/compound/Compounder.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/live/Igtl.h"
#include "sonoslice/live/LiveServers.h"

namespace sonoslice {
namespace {

using igtl::Message;

// A frame (W×H uint8 ramp) and its placement: pixel (i, j) → mm, moving `k` mm along z.
struct TestFrame {
  std::vector<uint8_t> pixels;
  Mat4 to_reference;
};
TestFrame test_frame(int w, int h, int k) {
  TestFrame f;
  f.pixels.resize(size_t(w) * h);
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i)
      f.pixels[size_t(j) * w + i] = uint8_t((i * 7 + j * 3 + k * 11) % 251);
  const double c = std::cos(0.1 * k), s = std::sin(0.1 * k);
  f.to_reference = Mat4::from_columns({{0.3 * c, 0.3 * s, 0}}, {{-0.3 * s, 0.3 * c, 0.05}},
                                      {{0, 0, 1}}, {{-5, -3, 0.4 * k}});
  return f;
}

Message round_trip(const std::vector<uint8_t>& bytes) {
  Message m;
  const igtl::Header h = igtl::parse_header(bytes.data());
  EXPECT_EQ(igtl::header_problem(h), "");
  EXPECT_EQ(
      igtl::parse_body(h, bytes.data() + igtl::kHeaderBytes, bytes.size() - igtl::kHeaderBytes, m),
      "");
  return m;
}

TEST(Igtl, Crc64IsOpenIGTLinksEcma182) {
  // CRC-64/ECMA-182 (not reflected, initial 0, no final xor) of "123456789": its check value.
  const char* text = "123456789";
  EXPECT_EQ(igtl::crc64(reinterpret_cast<const uint8_t*>(text), 9), 0x6C40DF5F0B497347ULL);
  EXPECT_EQ(igtl::crc64(nullptr, 0), 0u);
}

TEST(Igtl, TimestampsAreThe32Dot32FixedPointOfOpenIGTLink) {
  // igtl_nanosec_to_frac: 0.5 s is the top bit; the round trip keeps nanoseconds.
  EXPECT_EQ(igtl::timestamp_of_seconds(3.5), (uint64_t(3) << 32) | 0x80000000u);
  for (double s : {0.0, 1.25, 1234.567890123, 4000000000.999999})
    EXPECT_NEAR(igtl::seconds_of_timestamp(igtl::timestamp_of_seconds(s)), s, 2e-9 * (1 + s * 1e-6))
        << s;
  EXPECT_EQ(igtl::timestamp_of_seconds(-1), 0u);
  EXPECT_EQ(igtl::timestamp_of_seconds(NAN), 0u);
}

TEST(Igtl, EveryMessageTypeRoundTripsThroughPackAndParse) {
  const TestFrame f = test_frame(5, 3, 2);
  const int size[3] = {5, 3, 1};
  for (uint16_t version : {1, 2}) {
    Message m = round_trip(
        igtl::pack("IMAGE", "Image_Reference", 77,
                   igtl::image_content(f.pixels.data(), PixelType::UInt8, size, f.to_reference),
                   version, 9, {{"Key", "value"}, {"Empty", ""}}));
    EXPECT_EQ(m.header.type, "IMAGE");
    EXPECT_EQ(m.header.device, "Image_Reference");
    EXPECT_EQ(m.header.timestamp, 77u);
    EXPECT_EQ(m.message_id, version == 2 ? 9u : 0u);
    EXPECT_EQ(m.metadata.size(), version == 2 ? 2u : 0u);
    if (version == 2) {
      EXPECT_EQ(m.metadata[0], std::make_pair(std::string("Key"), std::string("value")));
    }
    igtl::Image image;
    ASSERT_EQ(igtl::parse_image(m.content, image), "");
    EXPECT_EQ(image.size[0], 5);
    EXPECT_EQ(image.size[1], 3);
    EXPECT_EQ(image.type, PixelType::UInt8);
    EXPECT_EQ(std::vector<uint8_t>(image.pixels, image.pixels + image.pixel_bytes), f.pixels);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c)  // float32 on the wire, and the centre ↔ corner round trip
        EXPECT_NEAR(image.ijk_to_world.m[r][c], f.to_reference.m[r][c], 1e-5) << r << c;

    Mat4 t;
    m = round_trip(igtl::pack("TRANSFORM", "ProbeToReference", 0,
                              igtl::transform_content(f.to_reference), version));
    ASSERT_EQ(igtl::parse_transform(m.content, t), "");
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) EXPECT_NEAR(t.m[r][c], f.to_reference.m[r][c], 1e-6);

    std::string text;
    m = round_trip(igtl::pack("STRING", "CMD_1", 0, igtl::string_content("<Command/>"), version));
    ASSERT_EQ(igtl::parse_string(m.content, text), "");
    EXPECT_EQ(text, "<Command/>");

    uint16_t code = 0;
    m = round_trip(
        igtl::pack("STATUS", "", 0, igtl::status_content(1, -3, "Err", "all fine"), version));
    EXPECT_EQ(m.content.size(), 30u + 9u);  // the status text ends with its zero byte
    ASSERT_EQ(igtl::parse_status(m.content, code, text), "");
    EXPECT_EQ(code, 1);
    EXPECT_EQ(text, "all fine");
  }
  igtl::Command c{42, "StartVolumeReconstruction", "<Command Name=\"StartVolumeReconstruction\"/>"};
  const Message m = round_trip(igtl::pack("COMMAND", "command", 0, igtl::command_content(c), 2, 5));
  EXPECT_EQ(m.content.size(), 138 + c.text.size());
  igtl::Command back;
  ASSERT_EQ(igtl::parse_command(m.content, back), "");
  EXPECT_EQ(back.id, 42u);
  EXPECT_EQ(back.name, c.name);
  EXPECT_EQ(back.text, c.text);
}

TEST(Igtl, ImagesBuiltInPlaceAreTheSameBytes) {
  const TestFrame f = test_frame(7, 5, 3);
  const int size[3] = {7, 5, 1};
  for (uint16_t version : {1, 2}) {
    const auto in_place = igtl::pack_image(
        "Image", 99, PixelType::UInt8, size, f.to_reference, version == 2,
        [&](uint8_t* out) { std::memcpy(out, f.pixels.data(), f.pixels.size()); }, version, 4);
    EXPECT_EQ(in_place, igtl::pack("IMAGE", "Image", 99,
                                   igtl::image_content(f.pixels.data(), PixelType::UInt8, size,
                                                       f.to_reference, version == 2),
                                   version, 4));
  }
}

TEST(Igtl, MalformedMessagesAreNamedNotTrusted) {
  const TestFrame f = test_frame(4, 4, 0);
  const int size[3] = {4, 4, 1};
  std::vector<uint8_t> bytes =
      igtl::pack("IMAGE", "x", 0,
                 igtl::image_content(f.pixels.data(), PixelType::UInt8, size, f.to_reference));
  Message m;
  igtl::Header h = igtl::parse_header(bytes.data());
  std::vector<uint8_t> body(bytes.begin() + igtl::kHeaderBytes, bytes.end());
  body[80] ^= 1;  // one pixel bit: the CRC says so
  EXPECT_NE(igtl::parse_body(h, body.data(), body.size(), m).find("CRC"), std::string::npos);
  // Absurd sizes, unknown header versions and unprintable types are refused from the header alone.
  h.body_bytes = uint64_t(1) << 40;
  EXPECT_NE(igtl::header_problem(h).find("limit"), std::string::npos);
  h = igtl::parse_header(bytes.data());
  h.version = 7;
  EXPECT_NE(igtl::header_problem(h).find("header version 7"), std::string::npos);
  // Image contents: short, an unknown scalar type, pixels of the wrong size, a sub-volume, NaN.
  igtl::Image image;
  std::vector<uint8_t> c =
      igtl::image_content(f.pixels.data(), PixelType::UInt8, size, f.to_reference);
  EXPECT_NE(igtl::parse_image(std::vector<uint8_t>(c.begin(), c.begin() + 40), image), "");
  auto bad = c;
  bad[3] = 99;
  EXPECT_NE(igtl::parse_image(bad, image).find("scalar type 99"), std::string::npos);
  bad = c;
  bad.pop_back();
  EXPECT_NE(igtl::parse_image(bad, image).find("needs 16"), std::string::npos);
  bad = c;
  bad[61] = 1;  // sub-volume offset i = 1
  EXPECT_NE(igtl::parse_image(bad, image).find("sub-volume"), std::string::npos);
  bad = c;
  const float nan = NAN;
  uint32_t bits;
  std::memcpy(&bits, &nan, 4);
  for (int b = 0; b < 4; ++b) bad[12 + b] = uint8_t(bits >> (24 - 8 * b));
  EXPECT_NE(igtl::parse_image(bad, image).find("non-finite"), std::string::npos);
  // Header v2 bodies whose metadata sizes overrun the body.
  bytes = igtl::pack("STRING", "x", 0, igtl::string_content("hi"), 2, 0, {{"a", "b"}});
  body.assign(bytes.begin() + igtl::kHeaderBytes, bytes.end());
  body[7] = 200;  // metadata size
  h = igtl::parse_header(bytes.data());
  h.crc = igtl::crc64(body.data(), body.size());
  EXPECT_NE(igtl::parse_body(h, body.data(), body.size(), m).find("larger than the body"),
            std::string::npos);
  Mat4 t;
  EXPECT_NE(igtl::parse_transform(std::vector<uint8_t>(47), t), "");
  std::string s;
  EXPECT_NE(igtl::parse_string({0, 3, 0, 9, 'a'}, s), "");
  igtl::Command cmd;
  EXPECT_NE(igtl::parse_command(std::vector<uint8_t>(100), cmd), "");
}

TEST(Igtl, RandomBytesNeverCrashTheParsers) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 2000; ++trial) {
    std::vector<uint8_t> b(size_t(rng() % 300));
    for (auto& v : b) v = uint8_t(rng());
    igtl::Image image;
    Mat4 t;
    std::string s;
    uint16_t code;
    igtl::Command c;
    igtl::parse_image(b, image);
    igtl::parse_transform(b, t);
    igtl::parse_string(b, s);
    igtl::parse_status(b, code, s);
    igtl::parse_command(b, c);
    if (b.size() >= igtl::kHeaderBytes) {
      igtl::Header h = igtl::parse_header(b.data());
      h.version = uint16_t(1 + trial % 2);
      h.body_bytes = b.size() - igtl::kHeaderBytes;
      h.crc = igtl::crc64(b.data() + igtl::kHeaderBytes, size_t(h.body_bytes));
      Message m;
      igtl::parse_body(h, b.data() + igtl::kHeaderBytes, size_t(h.body_bytes), m);
    }
  }
}

ReconstructionOptions grid_options(const Vec3& origin, std::array<int64_t, 3> extent) {
  ReconstructionOptions o;
  o.spacing_mm = Vec3{{0.5, 0.5, 0.5}};
  o.origin_mm = origin;
  o.extent = extent;
  return o;
}

bool same_voxels(const Volume& a, const Volume& b) {
  return a.grid().dims == b.grid().dims && a.pixel_type() == b.pixel_type() &&
         std::memcmp(a.data(), b.data(),
                     size_t(a.grid().voxel_count()) * pixel_size(a.pixel_type())) == 0;
}

TEST(LiveCompounder, FramesPushedOneByOneGiveTheBatchReconstructionsBytes) {
  // A fixed grid: the live volume is the Compounder's batch result, byte for byte.
  const ReconstructionOptions o = grid_options({{-6, -4, -1}}, {{40, 40, 30}});
  LiveCompounder live(nullptr, o);
  Compounder batch(*plan_stream(PixelType::UInt8, 24, 16, nullptr, o).grid, CompoundSettings{});
  for (int k = 0; k < 20; ++k) {
    const TestFrame f = test_frame(24, 16, k);
    EXPECT_EQ(live.push(f.pixels.data(), PixelType::UInt8, 24, 16, f.to_reference, k), "");
    batch.add_image(f.pixels.data(), PixelType::UInt8, 24, 16, f.to_reference);
  }
  const Volume v = live.finish();
  EXPECT_TRUE(same_voxels(v, batch.volume(PixelType::UInt8)));
  const LiveStats s = live.stats();
  EXPECT_EQ(s.received, 20);
  EXPECT_EQ(s.compounded, 20);
  EXPECT_EQ(s.dropped + s.rejected, 0);
  EXPECT_GE(s.latency_ms.max, s.latency_ms.p99);
  EXPECT_GE(s.latency_ms.p99, s.latency_ms.p50);
  EXPECT_GT(s.latency_ms.p50, 0);
  const Latencies l = Latencies::of({5, 1, 4, 2, 3});  // nearest rank
  EXPECT_EQ(l.p50, 3);
  EXPECT_EQ(l.p95, 5);
  EXPECT_EQ(l.max, 5);
}

TEST(LiveCompounder, AGrowingGridEndsAsTheOfflineReconstructionOnItsGrid) {
  LiveOptions keep;
  keep.keep_frames = true;
  ReconstructionOptions o;
  o.spacing_mm = Vec3{{0.5, 0.5, 0.5}};
  LiveCompounder live(nullptr, o, keep);
  for (int k = 0; k < 25; ++k) {  // the frames move 10 mm: the grid grows several times
    const TestFrame f = test_frame(24, 16, k);
    ASSERT_EQ(live.push(f.pixels.data(), PixelType::UInt8, 24, 16, f.to_reference), "");
    if (k % 7 == 0) live.drain();
  }
  const Volume v = live.finish();
  // The grid is fitted around the frames as the offline recipe fits it: the recording compounded
  // offline with the same settings (no grid given) is the same volume.
  const PlusSequence recorded = live.recorded();
  ASSERT_EQ(recorded.frame_count, 25);
  Reconstruction offline(FrameSource::plus(recorded), nullptr, o);
  EXPECT_EQ(offline.grid().dims, live.stats().grid->dims);
  EXPECT_TRUE(same_voxels(v, offline.run().volume));
}

TEST(LiveCompounder, RefusesFramesItCannotPlaceAndCountsWhy) {
  LiveCompounder live(nullptr, grid_options({{0, 0, 0}}, {{8, 8, 8}}));
  const TestFrame f = test_frame(6, 4, 0);
  Mat4 nan = f.to_reference;
  nan.m[1][3] = NAN;
  Mat4 singular = f.to_reference;
  for (int r = 0; r < 3; ++r) singular.m[r][1] = singular.m[r][0];
  const std::vector<float> floats(24, 1.f);
  EXPECT_NE(live.push(f.pixels.data(), PixelType::UInt8, 6, 4, nan), "");
  EXPECT_NE(live.push(f.pixels.data(), PixelType::UInt8, 6, 4, singular).find("singular"),
            std::string::npos);
  EXPECT_NE(live.push(f.pixels.data(), PixelType::Float64, 3, 1, f.to_reference), "");
  EXPECT_EQ(live.push(f.pixels.data(), PixelType::UInt8, 6, 4, f.to_reference), "");
  EXPECT_NE(
      live.push(floats.data(), PixelType::Float32, 6, 4, f.to_reference).find("after frames of"),
      std::string::npos);
  // A transform beyond any scanner is named as broken, not as the grid it would need.
  Mat4 far = f.to_reference;
  far.m[0][3] = 1e38;
  EXPECT_EQ(live.push(f.pixels.data(), PixelType::UInt8, 6, 4, far),
            "a frame at 1e+38 mm along x (beyond any scanner's extent, at most 1e9 mm): a broken "
            "transform");
  live.drain();
  const LiveStats s = live.stats();
  EXPECT_EQ(s.received, 6);
  EXPECT_EQ(s.compounded, 1);
  EXPECT_EQ(s.rejected, 5);
  EXPECT_EQ(s.rejected_by_reason.size(), 5u);
  EXPECT_THROW(LiveCompounder(nullptr, ReconstructionOptions{}), InputError);  // no spacing
  ReconstructionOptions half = grid_options({{0, 0, 0}}, {{8, 8, 8}});
  half.extent.reset();
  EXPECT_THROW(LiveCompounder(nullptr, half), InputError);
}

TEST(LiveCompounder, NewestKeepsOnlyTheNewestWaitingFrameAndCountsTheRest) {
  LiveOptions newest;
  newest.queue = QueuePolicy::Newest;
  LiveCompounder live(nullptr, grid_options({{-6, -4, -1}}, {{40, 40, 60}}), newest);
  const int n = 200;
  for (int k = 0; k < n; ++k) {
    const TestFrame f = test_frame(96, 64, k % 20);
    ASSERT_EQ(live.push(f.pixels.data(), PixelType::UInt8, 96, 64, f.to_reference), "");
  }
  live.drain();
  const LiveStats s = live.stats();
  EXPECT_EQ(s.received, n);
  EXPECT_EQ(s.compounded + s.dropped, n);  // every frame is either in the volume or counted
  EXPECT_GT(s.dropped, 0);
  EXPECT_EQ(s.waiting, 0);
}

TEST(LiveCompounder, SuspendedFramesAreCountedNotCompounded) {
  LiveCompounder live(nullptr, grid_options({{-6, -4, -1}}, {{40, 40, 30}}));
  const TestFrame f = test_frame(24, 16, 1);
  live.suspend();
  EXPECT_EQ(live.push(f.pixels.data(), PixelType::UInt8, 24, 16, f.to_reference), "");
  live.resume();
  EXPECT_EQ(live.push(f.pixels.data(), PixelType::UInt8, 24, 16, f.to_reference), "");
  live.drain();
  EXPECT_EQ(live.stats().suspended, 1);
  EXPECT_EQ(live.stats().compounded, 1);
  live.reset();
  EXPECT_EQ(live.snapshot().grid().voxel_count(), 0);
}

// A raw TCP client of the endpoint, for byte-level abuse.
int connect_to(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(uint16_t(port));
  inet_pton(AF_INET, "127.0.0.1", &a.sin_addr);
  EXPECT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)), 0);
  return fd;
}
void send_all(int fd, const std::vector<uint8_t>& b) {
  size_t off = 0;
  while (off < b.size()) {
    const ssize_t n = ::send(fd, b.data() + off, b.size() - off, MSG_NOSIGNAL);
    if (n <= 0) return;
    off += size_t(n);
  }
}

TEST(LiveServer, MalformedMessagesAreCountedAndTheVolumeStaysCorrect) {
  const ReconstructionOptions o = grid_options({{-6, -4, -1}}, {{40, 40, 30}});
  LiveCompounder live(nullptr, o);
  std::atomic<int> port{0};
  LiveCompoundRun run;
  run.endpoint.port = 0;
  run.limits.max_frames = 10;
  run.limits.max_seconds = 60;
  run.on_ready = [&](const IgtlEndpoint& e) { port = e.port(); };
  LiveCompoundResult result;
  std::thread server([&] { result = run_live_compound(live, run); });
  while (port == 0) std::this_thread::sleep_for(std::chrono::milliseconds(5));

  const int size[3] = {24, 16, 1};
  const auto frame_message = [&](int k) {
    const TestFrame f = test_frame(24, 16, k);
    return igtl::pack("IMAGE", "Image_Reference", 0,
                      igtl::image_content(f.pixels.data(), PixelType::UInt8, size, f.to_reference));
  };
  const int idle = connect_to(port);  // connects and sends nothing
  int a = connect_to(port);
  // A bad CRC (the stream goes on), then a good frame.
  std::vector<uint8_t> bad = frame_message(0);
  bad.back() ^= 0xFF;
  send_all(a, bad);
  // Frame 0 as a video grabber sends it, RGB, with colour in one pixel: compounded by its first
  // component (the grey frame), and the colour counted.
  const TestFrame first = test_frame(24, 16, 0);
  std::vector<uint8_t> rgb =
      igtl::image_content(first.pixels.data(), PixelType::UInt8, size, first.to_reference);
  const size_t header = rgb.size() - first.pixels.size();  // the IMAGE header (72 bytes)
  rgb[2] = 3;
  rgb.resize(header);
  for (uint8_t v : first.pixels) rgb.insert(rgb.end(), {v, v, v});
  rgb[header + 3 * 5 + 2] ^= 0x5a;  // pixel 5's blue
  send_all(a, igtl::pack("IMAGE", "Image_Reference", 0, rgb));
  // A two-component image and a 3-D image: rejected frames.
  std::vector<uint8_t> c = igtl::image_content(test_frame(24, 16, 1).pixels.data(),
                                               PixelType::UInt8, size, Mat4::identity());
  c[2] = 2;  // two components: twice the pixel bytes
  c.resize(c.size() + 24 * 16, 0);
  send_all(a, igtl::pack("IMAGE", "x", 0, c));
  const int size3[3] = {4, 3, 2};
  send_all(a, igtl::pack("IMAGE", "x", 0,
                         igtl::image_content(std::vector<uint8_t>(24).data(), PixelType::UInt8,
                                             size3, Mat4::identity())));
  // An unknown type is ignored; a client that disconnects mid-message loses only that message.
  send_all(a, igtl::pack("POINT", "x", 0, {1, 2, 3}));
  const std::vector<uint8_t> half = frame_message(2);
  send_all(a, std::vector<uint8_t>(half.begin(), half.begin() + long(half.size() / 2)));
  const auto settle = [] { std::this_thread::sleep_for(std::chrono::milliseconds(100)); };
  settle();
  ::close(a);
  // Five reconnects, one frame each; then a header announcing an absurd body closes that client.
  for (int k = 1; k <= 5; ++k) {
    a = connect_to(port);
    send_all(a, frame_message(k));
    settle();
    ::close(a);
  }
  a = connect_to(port);
  std::vector<uint8_t> absurd = frame_message(6);
  for (int b = 0; b < 8; ++b) absurd[42 + b] = 0xFF;
  send_all(a, std::vector<uint8_t>(absurd.begin(), absurd.begin() + igtl::kHeaderBytes));
  settle();
  ::close(a);
  a = connect_to(port);
  for (int k = 6; k < 10; ++k) send_all(a, frame_message(k));
  server.join();
  ::close(a);
  ::close(idle);

  EXPECT_EQ(result.stopped_by, "--max-frames");
  // 1 + 5 + 4 good frames went in; the malformed images do not count as frames.
  EXPECT_EQ(result.stats.compounded, 10);
  const auto count = [&](const std::string& key) {
    const auto it = result.network.find(key);
    return it == result.network.end() ? 0 : it->second;
  };
  EXPECT_EQ(count("rejected: a CRC that does not match its body"), 1);
  EXPECT_EQ(count("rejected: an image of 2 components (frames have 1, or 3 or 4: RGB, RGBA)"), 1);
  EXPECT_EQ(count("colour frames (first component compounded)"), 1);
  EXPECT_EQ(count("rejected: a 3-D image (frames are 2-D)"), 1);
  EXPECT_EQ(count("ignored: POINT message"), 1);
  EXPECT_GE(count("connections"), 8);
  int absurd_count = 0;
  for (const auto& [key, n] : result.network)
    if (key.find("limit is") != std::string::npos) absurd_count += int(n);
  EXPECT_EQ(absurd_count, 1);
  // The volume holds exactly the good frames, in order, with the matrices as the wire carried
  // them (float32).
  Compounder batch(*plan_stream(PixelType::UInt8, 24, 16, nullptr, o).grid, CompoundSettings{});
  for (int k = 0; k < 10; ++k) {
    const Message m = round_trip(frame_message(k));
    igtl::Image image;
    ASSERT_EQ(igtl::parse_image(m.content, image), "");
    batch.add_image(image.pixels, PixelType::UInt8, 24, 16, image.ijk_to_world);
  }
  EXPECT_TRUE(same_voxels(result.volume, batch.volume(PixelType::UInt8)));
}

}  // namespace
}  // namespace sonoslice
