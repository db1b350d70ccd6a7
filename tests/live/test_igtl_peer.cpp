// sonoslice's OpenIGTLink codec against an independent implementation: Debian's OpenIGTLink
// library (1.11, header version 1). The same messages packed by both are the same bytes; each
// unpacks what the other packs (with its CRC check); the library's sockets talk to
// `live compound` as a sender and command client, and as the server `--connect` reaches.
#include <gtest/gtest.h>
#include <igtlClientSocket.h>
#include <igtlImageMessage.h>
#include <igtlMessageHeader.h>
#include <igtlServerSocket.h>
#include <igtlStatusMessage.h>
#include <igtlStringMessage.h>
#include <igtlTransformMessage.h>

#include <atomic>
#include <cstring>
#include <thread>

#include "sonoslice/live/Igtl.h"
#include "sonoslice/live/LiveServers.h"

namespace lib = ::igtl;  // Debian's library (sonoslice's codec is sonoslice::igtl)

namespace sonoslice {
namespace {

constexpr int kW = 12, kH = 7;

std::vector<uint8_t> bytes_of(lib::MessageBase* m) {
  m->Pack();
  const auto* p = static_cast<const uint8_t*>(m->GetPackPointer());
  return std::vector<uint8_t>(p, p + m->GetPackSize());
}

std::vector<uint8_t> test_pixels() {
  std::vector<uint8_t> p(kW * kH);
  for (size_t k = 0; k < p.size(); ++k) p[k] = uint8_t(k * 37 % 256);
  return p;
}

// The library's IMAGE of the test frame: direction columns (0.6, 0.8, 0), (-0.8, 0.6, 0),
// (0, 0, 1), spacing 0.5, 0.25, 1 (exact in float32), centre (10.5, -3.25, 7).
lib::ImageMessage::Pointer library_image(const std::vector<uint8_t>& pixels) {
  auto img = lib::ImageMessage::New();
  img->SetDimensions(kW, kH, 1);
  img->SetSpacing(0.5f, 0.25f, 1.f);
  img->SetScalarTypeToUint8();
  img->SetEndian(lib::ImageMessage::ENDIAN_LITTLE);
  img->SetCoordinateSystem(lib::ImageMessage::COORDINATE_LPS);
  img->SetDeviceName("Image_Reference");
  img->SetTimeStamp(1234, 0x80000000u);
  lib::Matrix4x4 m = {{0.6f, -0.8f, 0, 10.5f}, {0.8f, 0.6f, 0, -3.25f}, {0, 0, 1, 7}, {0, 0, 0, 1}};
  img->SetMatrix(m);
  img->AllocateScalars();
  std::memcpy(img->GetScalarPointer(), pixels.data(), pixels.size());
  return img;
}

// The same frame as sonoslice describes it: pixel (i, j, 0) → mm, from the first pixel.
Mat4 our_matrix() {
  const Vec3 x{{double(0.6f) * 0.5, double(0.8f) * 0.5, 0}},
      y{{double(-0.8f) * 0.25, double(0.6f) * 0.25, 0}};
  const Vec3 z{{0, 0, 1}};
  Vec3 origin{{10.5, -3.25, 7}};
  for (int r = 0; r < 3; ++r) origin[r] -= x[r] * (kW - 1) / 2.0 + y[r] * (kH - 1) / 2.0;
  return Mat4::from_columns(x, y, z, origin);
}

TEST(IgtlPeer, ImageTransformStringStatusAreTheLibrarysBytes) {
  const std::vector<uint8_t> pixels = test_pixels();
  auto img = library_image(pixels);
  const int size[3] = {kW, kH, 1};
  const uint64_t stamp = (uint64_t(1234) << 32) | 0x80000000u;
  EXPECT_EQ(igtl::pack("IMAGE", "Image_Reference", stamp,
                       igtl::image_content(pixels.data(), PixelType::UInt8, size, our_matrix())),
            bytes_of(img));

  auto t = lib::TransformMessage::New();
  lib::Matrix4x4 m = {{0.6f, -0.8f, 0, 1.5f}, {0.8f, 0.6f, 0, -2}, {0, 0, 1, 30.25f}, {0, 0, 0, 1}};
  t->SetMatrix(m);
  t->SetDeviceName("ProbeToReference");
  t->SetTimeStamp(5, 0);
  Mat4 ours;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) ours.m[r][c] = m[r][c];
  EXPECT_EQ(
      igtl::pack("TRANSFORM", "ProbeToReference", uint64_t(5) << 32, igtl::transform_content(ours)),
      bytes_of(t));

  auto s = lib::StringMessage::New();
  s->SetString("<Command Name=\"StartVolumeReconstruction\" />");
  s->SetEncoding(3);
  s->SetDeviceName("CMD_1");
  s->SetTimeStamp(0, 0);
  EXPECT_EQ(igtl::pack("STRING", "CMD_1", 0,
                       igtl::string_content("<Command Name=\"StartVolumeReconstruction\" />")),
            bytes_of(s));

  auto st = lib::StatusMessage::New();
  st->SetCode(lib::StatusMessage::STATUS_OK);
  st->SetSubCode(-2);
  st->SetErrorName("None");
  st->SetStatusString("300 frames");
  st->SetDeviceName("Stats");
  st->SetTimeStamp(0, 0);
  EXPECT_EQ(igtl::pack("STATUS", "Stats", 0, igtl::status_content(1, -2, "None", "300 frames")),
            bytes_of(st));
}

// The library unpacks `bytes` (header, then body with its CRC check) into `body`.
bool library_unpacks(const std::vector<uint8_t>& bytes, lib::MessageBase* body) {
  auto header = lib::MessageHeader::New();
  header->InitPack();
  std::memcpy(header->GetPackPointer(), bytes.data(), header->GetPackSize());
  header->Unpack();
  body->SetMessageHeader(header);
  body->AllocatePack();
  std::memcpy(body->GetPackBodyPointer(), bytes.data() + igtl::kHeaderBytes,
              body->GetPackBodySize());
  return body->Unpack(1) & lib::MessageHeader::UNPACK_BODY;
}

TEST(IgtlPeer, TheLibraryUnpacksWhatSonoslicePacksAndBack) {
  const std::vector<uint8_t> pixels = test_pixels();
  const int size[3] = {kW, kH, 1};
  const auto ours =
      igtl::pack("IMAGE", "Image_Reference", 0,
                 igtl::image_content(pixels.data(), PixelType::UInt8, size, our_matrix()));
  auto img = lib::ImageMessage::New();
  ASSERT_TRUE(library_unpacks(ours, img));
  int dims[3];
  img->GetDimensions(dims);
  EXPECT_EQ(dims[0], kW);
  EXPECT_EQ(dims[1], kH);
  float spacing[3];
  img->GetSpacing(spacing);
  EXPECT_FLOAT_EQ(spacing[0], 0.5f);
  EXPECT_FLOAT_EQ(spacing[1], 0.25f);
  lib::Matrix4x4 m;
  img->GetMatrix(m);
  EXPECT_NEAR(m[0][3], 10.5, 1e-5);  // the centre
  EXPECT_NEAR(m[1][0], 0.8, 1e-6);
  EXPECT_EQ(std::memcmp(img->GetScalarPointer(), pixels.data(), pixels.size()), 0);
  // A corrupted body fails the library's CRC check as it fails ours.
  auto bad = ours;
  bad[igtl::kHeaderBytes + 100] ^= 1;
  auto img2 = lib::ImageMessage::New();
  EXPECT_FALSE(library_unpacks(bad, img2));

  auto st = lib::StatusMessage::New();
  ASSERT_TRUE(library_unpacks(
      igtl::pack("STATUS", "", 0, igtl::status_content(1, 0, "", "{\"frames\": 3}")), st));
  EXPECT_EQ(st->GetCode(), 1);
  EXPECT_STREQ(st->GetStatusString(), "{\"frames\": 3}");

  // And sonoslice parses the library's image to the same placement.
  const auto theirs = bytes_of(library_image(pixels));
  igtl::Message msg;
  const igtl::Header h = igtl::parse_header(theirs.data());
  ASSERT_EQ(igtl::parse_body(h, theirs.data() + igtl::kHeaderBytes,
                             theirs.size() - igtl::kHeaderBytes, msg),
            "");
  igtl::Image image;
  ASSERT_EQ(igtl::parse_image(msg.content, image), "");
  const Mat4 want = our_matrix();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) EXPECT_NEAR(image.ijk_to_world.m[r][c], want.m[r][c], 1e-5);
  EXPECT_EQ(igtl::seconds_of_timestamp(h.timestamp), 1234.5);
}

ReconstructionOptions small_grid() {
  ReconstructionOptions o;
  o.spacing_mm = Vec3{{0.5, 0.5, 0.5}};
  o.origin_mm = Vec3{{0, -12, 0}};
  o.extent = std::array<int64_t, 3>{{40, 40, 30}};
  return o;
}

// Reads one message with the library: its type, device and (for STRING) text.
struct Received {
  std::string type, device, text;
  int dims[3] = {0, 0, 0};
};
Received library_receive(lib::Socket* socket) {
  Received r;
  auto header = lib::MessageHeader::New();
  header->InitPack();
  if (socket->Receive(header->GetPackPointer(), header->GetPackSize()) != header->GetPackSize())
    return r;
  header->Unpack();
  r.type = header->GetDeviceType();
  r.device = header->GetDeviceName();
  lib::MessageBase::Pointer body;
  if (r.type == "STRING") {
    body = lib::StringMessage::New();
  } else if (r.type == "IMAGE") {
    body = lib::ImageMessage::New();
  } else {
    socket->Skip(header->GetBodySizeToRead(), 0);
    return r;
  }
  body->SetMessageHeader(header);
  body->AllocatePack();
  socket->Receive(body->GetPackBodyPointer(), body->GetPackBodySize());
  EXPECT_TRUE(body->Unpack(1) & lib::MessageHeader::UNPACK_BODY) << r.type;
  if (r.type == "STRING") r.text = static_cast<lib::StringMessage*>(body.GetPointer())->GetString();
  if (r.type == "IMAGE") static_cast<lib::ImageMessage*>(body.GetPointer())->GetDimensions(r.dims);
  return r;
}

TEST(IgtlPeer, TheLibrarysClientStreamsFramesAndStopsTheReconstruction) {
  LiveCompounder live(nullptr, small_grid());
  std::atomic<int> port{0};
  LiveCompoundRun run;
  run.endpoint.port = 0;
  run.limits.max_seconds = 60;
  run.on_ready = [&](const IgtlEndpoint& e) { port = e.port(); };
  LiveCompoundResult result;
  std::thread server([&] { result = run_live_compound(live, run); });
  while (port == 0) std::this_thread::sleep_for(std::chrono::milliseconds(5));

  auto socket = lib::ClientSocket::New();
  ASSERT_EQ(socket->ConnectToServer("127.0.0.1", port), 0);
  const std::vector<uint8_t> pixels = test_pixels();
  for (int k = 0; k < 3; ++k) {
    auto img = library_image(pixels);
    img->Pack();
    socket->Send(img->GetPackPointer(), img->GetPackSize());
  }
  auto cmd = lib::StringMessage::New();
  cmd->SetDeviceName("CMD_007");
  cmd->SetString("<Command Name=\"StopVolumeReconstruction\" OutputVolDeviceName=\"Volume\" />");
  cmd->Pack();
  socket->Send(cmd->GetPackPointer(), cmd->GetPackSize());
  // PlusServer's order: the volume to the asking client, then the reply (uid read as a number).
  const Received volume = library_receive(socket);
  EXPECT_EQ(volume.type, "IMAGE");
  EXPECT_EQ(volume.device, "Volume");
  EXPECT_EQ(volume.dims[0], 40);
  EXPECT_EQ(volume.dims[2], 30);
  const Received ack = library_receive(socket);
  EXPECT_EQ(ack.type, "STRING");
  EXPECT_EQ(ack.device, "ACK_7");
  EXPECT_NE(ack.text.find("<CommandReply Status=\"SUCCESS\""), std::string::npos) << ack.text;
  server.join();
  socket->CloseSocket();
  EXPECT_EQ(result.stopped_by, "StopVolumeReconstruction");
  EXPECT_EQ(result.stats.compounded, 3);
}

TEST(IgtlPeer, ConnectReachesTheLibrarysServer) {
  // A free port for the library's server (it takes a fixed one).
  int port = 0;
  {
    IgtlEndpointOptions probe;
    probe.port = 0;
    IgtlEndpoint e(probe);
    port = e.port();
  }
  auto server_socket = lib::ServerSocket::New();
  ASSERT_EQ(server_socket->CreateServer(port), 0);
  LiveCompounder live(nullptr, small_grid());
  LiveCompoundRun run;
  run.endpoint.listen = false;
  run.endpoint.port = port;
  run.limits.max_frames = 4;
  run.limits.max_seconds = 60;
  LiveCompoundResult result;
  std::thread client([&] { result = run_live_compound(live, run); });
  lib::ClientSocket::Pointer peer;
  for (int tries = 0; tries < 100 && !peer; ++tries) peer = server_socket->WaitForConnection(100);
  ASSERT_TRUE(peer);
  const std::vector<uint8_t> pixels = test_pixels();
  for (int k = 0; k < 4; ++k) {
    auto img = library_image(pixels);
    img->Pack();
    peer->Send(img->GetPackPointer(), img->GetPackSize());
  }
  client.join();
  peer->CloseSocket();
  server_socket->CloseSocket();
  EXPECT_EQ(result.stopped_by, "--max-frames");
  EXPECT_EQ(result.stats.compounded, 4);
}

}  // namespace
}  // namespace sonoslice
