// The live workflows: an IgtlEndpoint loop around a LiveCompounder (with PlusServer's volume
// reconstruction commands) or around a renderer (the virtual probe).
#include "sonoslice/live/LiveServers.h"

#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <vector>

#include <nlohmann/json.hpp>

#ifdef SONOSLICE_HAVE_PUGIXML
#include <pugixml.hpp>
#endif

#include "../core/Clock.h"
#include "../io/ByteOrder.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/VolumeFile.h"
#include "sonoslice/plus/PlusConfig.h"

namespace sonoslice {
namespace {

uint64_t wall_timestamp() {
  return igtl::timestamp_of_seconds(
      std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count());
}

// The stop conditions every live run shares.
struct Limiter {
  LiveLimits limits;
  double start = now_seconds();
  std::string reason(int64_t frames) const {
    if (limits.stop && limits.stop->load()) return "a signal";
    if (limits.max_frames > 0 && frames >= limits.max_frames) return "--max-frames";
    if (limits.max_seconds > 0 && now_seconds() - start >= limits.max_seconds)
      return "--max-seconds";
    return "";
  }
};

std::string xml_escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

// A volume as a 3-D IMAGE message (its index → world matrix; PLUS sends the reconstruction in
// the reference frame).
std::vector<uint8_t> volume_message(const Volume& v, const std::string& device) {
  const VolumeGrid& g = v.grid();
  Mat4 m = Mat4::identity();
  for (int r = 0; r < 3; ++r) {
    for (int a = 0; a < 3; ++a) m.m[r][a] = g.direction.m[r][a] * g.spacing_mm[a];
    m.m[r][3] = g.origin_mm[r];
  }
  const int size[3] = {int(g.dims[0]), int(g.dims[1]), int(g.dims[2])};
  const size_t bytes = size_t(g.voxel_count()) * pixel_size(v.pixel_type());
  return igtl::pack_image(device, wall_timestamp(), v.pixel_type(), size, m, false,
                          [&](uint8_t* out) { std::memcpy(out, v.data(), bytes); });
}

// One PlusServer command: its name, attributes and XML.
struct PlusCommand {
  std::string name, xml;
  std::map<std::string, std::string> attributes;
  std::string attribute(const std::string& key) const {
    const auto it = attributes.find(key);
    return it == attributes.end() ? "" : it->second;
  }
};

std::string parse_plus_command(const std::string& xml, PlusCommand& out) {
#ifdef SONOSLICE_HAVE_PUGIXML
  pugi::xml_document doc;
  if (!doc.load_buffer(xml.data(), xml.size())) return "command XML that does not parse";
  const pugi::xml_node root = doc.document_element();
  if (std::string(root.name()) != "Command") return "command XML without a Command element";
  for (const pugi::xml_attribute& a : root.attributes()) out.attributes[a.name()] = a.value();
  out.name = out.attribute("Name");
  // Names are identifiers (PlusServer's commands): other bytes would be echoed into the reply's
  // XML and the log.
  for (const char ch : out.name)
    if (ch < 0x20 || ch > 0x7e) return "a command Name that is not printable text";
  out.xml = xml;
  return "";
#else
  (void)xml;
  (void)out;
  return "a command (sonoslice was built without pugixml)";
#endif
}

// PlusServer's OutputSpacing / OutputOrigin / OutputExtent attributes → options, read by the
// configuration's reader. As PlusServer, a command sets only what it gives: a Start without them
// keeps the grid (given by --origin/--extent or the configuration, or growing).
std::string apply_grid_attributes(const PlusCommand& c, ReconstructionOptions& o) {
  PlusReconstructionConfig given;
  try {
    given = read_plus_output_grid(c.xml, "command " + c.name);
  } catch (const Error& e) {
    return e.what();
  }
  if (given.output_spacing_mm) o.spacing_mm = given.output_spacing_mm;
  if (given.output_origin_mm.has_value() != given.output_extent.has_value())
    return "give OutputOrigin and OutputExtent together";
  if (given.output_origin_mm) {
    if (!o.spacing_mm) return "OutputOrigin/OutputExtent need OutputSpacing";
    given.output_spacing_mm = o.spacing_mm;
    const VolumeGrid grid = *given.output_grid();
    // Checked here, so that the reply names the command's attributes (the grid's own check
    // would name the command line's --origin/--extent, which this client never gave).
    try {
      grid.validate("OutputOrigin/OutputExtent");
    } catch (const Error& e) {
      return e.what();
    }
    for (int a = 0; a < 3; ++a)
      if (grid.dims[a] > (int64_t(1) << 20))
        return "OutputExtent: at most 1048576 voxels per axis, got " +
               std::to_string(grid.dims[a]) + " along " + "xyz"[a];
    o.origin_mm = grid.origin_mm;
    o.extent = grid.dims;
  }
  return "";
}

class CompoundServer {
 public:
  CompoundServer(LiveCompounder& c, const LiveCompoundRun& run)
      : compounder_(&c), run_(run), endpoint_(run.endpoint) {}
  LiveCompoundResult serve();

 private:
  void on_message(int client, igtl::Message&& m, double arrival);
  void on_image(const igtl::Message& m, double arrival);
  // Runs a PlusServer command; true on success, `message` says what happened.
  bool on_command(int client, const PlusCommand& c, std::string& message);
  void reply(int client, const igtl::Message& request, const std::string& name, bool ok,
             const std::string& message);
  void log(const std::string& line) {
    if (run_.log) run_.log(line);
  }
  void ignore(const std::string& why) { ++network_counts_["ignored: " + why]; }
  // NaN and infinite pixels are compounded as they are, as `compound` does with a file's: said
  // once on the log and counted, rather than discovered in the volume.
  void note_non_finite(const uint8_t* pixels, PixelType type, int64_t count) {
    if (count_non_finite(pixels, type, count) == 0) return;
    if (network_counts_[kNonFinite]++ == 0)
      log("a frame with NaN or infinite pixels: they are compounded as they are (counted as '" +
          std::string(kNonFinite) + "')");
  }
  static constexpr const char* kNonFinite = "frames with NaN or infinite pixels";
  // RGB and RGBA frames are compounded by their first component (first_component(), as PLUS
  // writes them); colour in them is said once and counted.
  void note_colour(int64_t differing) {
    if (differing == 0) return;
    if (network_counts_[kColour]++ == 0)
      log("a frame whose pixels' colour components differ: the first component is compounded "
          "(counted as '" +
          std::string(kColour) + "')");
  }
  static constexpr const char* kColour = "colour frames (first component compounded)";

  LiveCompounder* compounder_;
  const LiveCompoundRun& run_;
  IgtlEndpoint endpoint_;
  std::map<std::string, int64_t> network_counts_;  // ignored messages, NaN frames
  // A frame's own values when they are not the message's: byte-swapped, or the first component
  // of several; kept between frames so that a stream of such frames allocates once.
  std::vector<uint8_t> frame_copy_;
  int64_t frames_ = 0;
  std::string stopped_by_;
};

void CompoundServer::on_image(const igtl::Message& m, double arrival) {
  if (!run_.image_device.empty() && m.header.device != run_.image_device)
    return ignore("IMAGE of another device");
  igtl::Image image;
  std::string problem = igtl::parse_image(m.content, image);
  if (problem.empty() && image.components != 1 && image.components != 3 && image.components != 4)
    problem = "an image of " + std::to_string(image.components) +
              " components (frames have 1, or 3 or 4: RGB, RGBA)";
  if (problem.empty() && image.size[2] != 1) problem = "a 3-D image (frames are 2-D)";
  if (!problem.empty()) {
    endpoint_.reject(problem);
    return;
  }
  const int64_t count = int64_t(image.size[0]) * image.size[1];
  const uint8_t* pixels = image.pixels;
  std::vector<uint8_t>& copy = frame_copy_;
  int64_t coloured = 0;
  if (image.components > 1) {
    copy.resize(size_t(count) * pixel_size(image.type));
    coloured = first_component(image.pixels, image.type, count, image.components, copy.data());
    pixels = copy.data();
  }
  if (image.big_endian && pixel_size(image.type) > 1) {
    if (pixels != copy.data()) copy.assign(image.pixels, image.pixels + image.pixel_bytes);
    byteswap(copy.data(), copy.size() / pixel_size(image.type), pixel_size(image.type));
    pixels = copy.data();
  }
  ++frames_;  // --max-frames counts the frames handed to the compounder
  const std::string refused =
      compounder_->push(pixels, image.type, image.size[0], image.size[1], image.ijk_to_world,
                        igtl::seconds_of_timestamp(m.header.timestamp), arrival);
  if (refused.empty()) {  // what is said of a frame's pixels is said of frames compounded
    note_colour(coloured);
    note_non_finite(pixels, image.type, count);
  }
  if (run_.on_frame)
    run_.on_frame(pixels, image.type, image.size[0], image.size[1], image.ijk_to_world);
}

void CompoundServer::reply(int client, const igtl::Message& request, const std::string& name,
                           bool ok, const std::string& message) {
  const char* status = ok ? "SUCCESS" : "FAIL";
  if (request.header.type == "COMMAND") {
    igtl::Command c;
    c.id = 0;
    igtl::parse_command(request.content, c);
    const std::string text = "<CommandReply Name=\"" + xml_escape(name) + "\" Status=\"" + status +
                             "\"" + (ok ? "" : " Error=\"" + xml_escape(message) + "\"") +
                             " Message=\"" + xml_escape(message) + "\"></CommandReply>";
    std::vector<std::pair<std::string, std::string>> meta = {{"Message", message},
                                                             {"Status", status}};
    if (!ok) meta.emplace_back("Error", message);
    endpoint_.send(client, igtl::pack("RTS_COMMAND", request.header.device, wall_timestamp(),
                                      igtl::command_content({c.id, c.name, text}), 2,
                                      request.message_id, meta));
    return;
  }
  // STRING CMD_<uid> → STRING ACK_<uid> (PlusServer reads the uid as a number).
  const std::string uid = request.header.device.substr(4);
  char* end = nullptr;
  const long id = std::strtol(uid.c_str(), &end, 10);
  const std::string device = uid.empty() || *end ? "ACK" : "ACK_" + std::to_string(id);
  const std::string text = std::string("<CommandReply Status=\"") + status + "\" Message=\"" +
                           xml_escape(message) + "\" />";
  endpoint_.send(client, igtl::pack("STRING", device, wall_timestamp(), igtl::string_content(text),
                                    request.header.version, request.message_id));
}

bool CompoundServer::on_command(int client, const PlusCommand& c, std::string& message) {
  const std::string file = c.attribute("OutputVolFilename");
  const std::string device = c.attribute("OutputVolDeviceName");
  // Snapshot and Stop: the volume to the file and/or to the asking client, as PlusServer does.
  // False (a FAIL reply) when no frame was compounded: nothing to save or send.
  const auto deliver = [&](const Volume& v) {
    if (v.grid().voxel_count() == 0) {
      if (file.empty() && device.empty()) return true;
      message += " no frame compounded yet: no volume to save or send";
      return false;
    }
    if (!file.empty()) {
      write_volume(file, v);
      message += " saved reconstructed volume to file: " + file + ";";
    }
    if (!device.empty()) {
      endpoint_.send(client, volume_message(v, device));
      message += " image sent as: " + device + ";";
    }
    return true;
  };
  if (c.name == "StartVolumeReconstruction") {
    // PlusServer's Start clears the volume and applies the command's grid attributes.
    ReconstructionOptions o = compounder_->options();
    const std::string problem = apply_grid_attributes(c, o);
    if (!problem.empty()) {
      message = problem;
      return false;
    }
    compounder_->reset(o);
    compounder_->resume();
    message = "Volume reconstruction from live frames started.";
    return true;
  }
  if (c.name == "SuspendVolumeReconstruction") {
    if (compounder_->is_suspended()) {
      message = "reconstruction is not running";
      return false;
    }
    compounder_->suspend();
    message = "Volume reconstruction from live frames suspended.";
    return true;
  }
  if (c.name == "ResumeVolumeReconstruction") {
    if (!compounder_->is_suspended()) {
      message = "reconstruction is already running";
      return false;
    }
    compounder_->resume();
    message = "Volume reconstruction from live frames resumed.";
    return true;
  }
  if (c.name == "GetVolumeReconstructionSnapshot") {
    compounder_->drain();  // every frame received before the command is in it
    message = "Snapshot:";
    return deliver(compounder_->snapshot());
  }
  if (c.name == "StopVolumeReconstruction") {
    stopped_by_ = "StopVolumeReconstruction";
    message = "Volume reconstruction stopped:";
    return file.empty() && device.empty() ? true : deliver(compounder_->finish());
  }
  message = "unknown command " + c.name;
  endpoint_.reject(message);  // counted, as a malformed message is
  return false;
}

void CompoundServer::on_message(int client, igtl::Message&& m, double arrival) {
  const std::string& type = m.header.type;
  if (type == "IMAGE") return on_image(m, arrival);
  const bool string_command = type == "STRING" && m.header.device.rfind("CMD_", 0) == 0;
  if (string_command || type == "COMMAND") {
    std::string text, problem;
    igtl::Command command;
    if (string_command) {
      problem = igtl::parse_string(m.content, text);
    } else {
      problem = igtl::parse_command(m.content, command);
      text = command.text;
    }
    PlusCommand c;
    if (problem.empty()) problem = parse_plus_command(text, c);
    if (problem.empty() && !command.name.empty() && command.name != c.name)
      problem = "a COMMAND named " + command.name + " holding a " + c.name + " command";
    if (!problem.empty()) {
      endpoint_.reject(problem);
      reply(client, m, c.name, false, problem);
      return;
    }
    std::string message;
    bool ok = false;
    try {
      ok = on_command(client, c, message);
    } catch (const std::exception& e) {
      message = e.what();
    }
    log(c.name + (ok ? ": " : " failed: ") + message);
    reply(client, m, c.name, ok, message);
    return;
  }
  if (type == "GET_STATUS") {
    endpoint_.send(client, igtl::pack("STATUS", m.header.device, wall_timestamp(),
                                      igtl::status_content(igtl::kStatusOk, 0, "",
                                                           compounder_->stats().json()),
                                      m.header.version, m.message_id));
    return;
  }
  ignore(type + " message");
}

LiveCompoundResult CompoundServer::serve() {
  if (run_.on_ready) run_.on_ready(endpoint_);
  Limiter limiter{run_.limits};
  const auto handler = [this](int client, igtl::Message&& m, double arrival) {
    on_message(client, std::move(m), arrival);
  };
  while (stopped_by_.empty()) {
    endpoint_.poll(10, !compounder_->full(), handler);
    if (stopped_by_.empty()) stopped_by_ = limiter.reason(frames_);
  }
  LiveCompoundResult r;
  r.volume = compounder_->finish();
  endpoint_.flush(1000);  // replies and volumes still on their way
  r.stats = compounder_->stats();
  r.network = endpoint_.counts();
  for (const auto& [k, n] : network_counts_) r.network[k] += n;
  r.stopped_by = stopped_by_;
  return r;
}

}  // namespace

LiveCompoundResult run_live_compound(LiveCompounder& compounder, const LiveCompoundRun& run) {
  CompoundServer server(compounder, run);
  return server.serve();
}

std::string LiveCompoundResult::json() const {
  nlohmann::ordered_json j = nlohmann::ordered_json::parse(stats.json());
  struct rusage usage {};
  getrusage(RUSAGE_SELF, &usage);
  j["peak_memory_mb"] = usage.ru_maxrss / 1024;  // what a flood or a long session cost
  j["stopped_by"] = stopped_by;
  j["network"] = network;
  return j.dump(2);
}

std::string VirtualProbeResult::json() const {
  nlohmann::ordered_json j;
  j["poses_received"] = poses;
  j["images_sent"] = images;
  j["rejected"] = rejected;
  j["network"] = network;
  j["seconds"] = seconds;
  j["images_per_second"] = seconds > 0 ? double(images) / seconds : 0.0;
  j["latency_ms"] = {{"p50", latency_ms.p50},
                     {"p95", latency_ms.p95},
                     {"p99", latency_ms.p99},
                     {"max", latency_ms.max}};
  j["stopped_by"] = stopped_by;
  return j.dump(2);
}

VirtualProbeResult run_virtual_probe(const ProbeRenderer& renderer, const VirtualProbeRun& run) {
  IgtlEndpoint endpoint(run.endpoint);
  if (run.on_ready) run.on_ready(endpoint);
  Limiter limiter{run.limits};
  VirtualProbeResult r;
  std::vector<float> latencies;
  const int size[3] = {renderer.width, renderer.height, 1};
  const auto handler = [&](int client, igtl::Message&& m, double arrival) {
    if (m.header.type != "TRANSFORM") {
      ++r.network["ignored: " + m.header.type + " message"];
      return;
    }
    if (!run.pose_device.empty() && m.header.device != run.pose_device) {
      ++r.network["ignored: TRANSFORM of another device"];
      return;
    }
    ++r.poses;
    Mat4 pose;
    std::string problem = igtl::parse_transform(m.content, pose);
    if (problem.empty()) {
      pose = pose_to_lps(pose, run.world);
      try {
        // A mirror image, a scale or a shear is a tracker or calibration fault, not a place to
        // image.
        require_rigid_pose(pose, "TRANSFORM " + m.header.device);
      } catch (const InputError& e) {
        problem = e.what();
      }
    }
    if (!problem.empty()) {
      ++r.rejected;
      endpoint.reject(problem);
      return;
    }
    const Mat4 placed = pose_to_lps(pose * renderer.pixel_to_probe, run.world);
    // The image is rendered straight into the message that carries it.
    endpoint.send(client, igtl::pack_image(
                              run.image_device, m.header.timestamp, renderer.type, size, placed,
                              run.world == WorldFrame::RAS,
                              [&](uint8_t* out) {
                                renderer.render(pose, out);
                                if (run.on_image)
                                  run.on_image(pose, out, (now_seconds() - arrival) * 1e3);
                              },
                              m.header.version, m.message_id));
    ++r.images;
    latencies.push_back(float((now_seconds() - arrival) * 1e3));
  };
  while (r.stopped_by.empty()) {
    endpoint.poll(10, true, handler);
    r.stopped_by = limiter.reason(r.images);
  }
  endpoint.flush(1000);
  r.seconds = now_seconds() - limiter.start;
  for (const auto& [k, n] : endpoint.counts()) r.network[k] += n;
  r.latency_ms = Latencies::of(std::move(latencies));
  return r;
}

}  // namespace sonoslice
