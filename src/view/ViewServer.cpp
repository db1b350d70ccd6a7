// The viewer's server: scene geometry as JSON, planes and images as raw float32, sliced on demand
// with the library's Slicer. The page (web/) does all drawing; see docs/view.md for the API.
#include "sonoslice/view/ViewServer.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <random>
#include <thread>

#include <arpa/inet.h>
#include <httplib.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>
#include <nlohmann/json.hpp>

#include "../io/TextParse.h"
#include "ViewDetail.h"
#include "WebAssets.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/StackWriter.h"
#include "sonoslice/slice/Slicer.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

using nlohmann::json;
using view_detail::box_corners;

namespace {

json vec_json(const Vec3& v) {
  return json::array({v[0], v[1], v[2]});
}

json mat_json(const Mat4& m) {
  json a = json::array();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) a.push_back(m.m[r][c]);
  return a;
}

// The level and width a user first sees: the stack writers' robust auto window (0.5–99.5 %) on
// at most ~1 M voxels taken at a regular stride, so a 100 M-voxel CT answers in milliseconds.
std::pair<double, double> auto_volume_window(const Volume& v) {
  // uint8: B-mode (compounded ultrasound, labels' own scale aside) is shown over its whole range,
  // as a scanner shows it; the voxels no frame reached (0) would otherwise set the window.
  if (v.pixel_type() == PixelType::UInt8) return {127.5, 255.0};
  const int64_t n = v.grid().voxel_count();
  const int64_t stride = std::max<int64_t>(1, n / 1000000);
  std::vector<float> sample;
  sample.reserve(size_t(n / stride + 1));
  visit_pixel_type(v.pixel_type(), [&](auto zero) {
    const auto* p = static_cast<const decltype(zero)*>(v.data());
    for (int64_t i = 0; i < n; i += stride) sample.push_back(float(p[i]));
  });
  return auto_window(sample.data(), PixelType::Float32, 1, sample.size(), nullptr);
}

// The probe's outline in probe mm (closed, last point not repeated) and its four corners
// (near-left, near-right, far-right, far-left), from the same shape `inside` tests.
void probe_outline(const ProbeGeometry& p, json& outline, json& corners) {
  outline = json::array();
  std::vector<std::array<double, 2>> pts;
  if (p.type == ProbeType::Curvilinear) {
    const double apex_y = p.face_y_mm - p.radius_mm, half = p.sector_deg * kPi / 360.0;
    const int n = 32;
    for (int k = 0; k <= n; ++k) {  // near arc, left to right
      const double a = -half + 2 * half * k / n;
      pts.push_back({p.radius_mm * std::sin(a), apex_y + p.radius_mm * std::cos(a)});
    }
    const double far = p.radius_mm + p.depth_mm;
    for (int k = n; k >= 0; --k) {  // far arc, right to left
      const double a = -half + 2 * half * k / n;
      pts.push_back({far * std::sin(a), apex_y + far * std::cos(a)});
    }
    corners = json::array({json::array({pts[0][0], pts[0][1]}),
                           json::array({pts[size_t(n)][0], pts[size_t(n)][1]}),
                           json::array({pts[size_t(n) + 1][0], pts[size_t(n) + 1][1]}),
                           json::array({pts.back()[0], pts.back()[1]})});
  } else {
    const ImageGrid& g = p.image;
    double x0 = g.origin_mm[0], x1 = g.origin_mm[0] + (g.width - 1) * g.spacing_mm[0];
    double y0 = g.origin_mm[1], y1 = g.origin_mm[1] + (g.height - 1) * g.spacing_mm[1];
    if (p.has_width) x0 = std::max(x0, -p.width_mm / 2), x1 = std::min(x1, p.width_mm / 2);
    if (p.has_depth) y0 = std::max(y0, p.face_y_mm), y1 = std::min(y1, p.face_y_mm + p.depth_mm);
    pts = {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
    corners = json::array();
    for (const auto& q : pts) corners.push_back(json::array({q[0], q[1]}));
  }
  for (const auto& q : pts) outline.push_back(json::array({q[0], q[1]}));
}

void send_floats(httplib::Response& res, std::vector<float> values) {
  res.set_content(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(float),
                  "application/octet-stream");
}

// localhost, ::1 or an address of 127.0.0.0/8 written as one: a name that merely starts with
// "127." (127.0.0.1.attacker.example) is a name, which DNS rebinding can point here.
bool is_loopback_name(const std::string& h) {
  in_addr address{};
  return h == "localhost" || h == "::1" || h == "[::1]" ||
         (inet_pton(AF_INET, h.c_str(), &address) == 1 && (ntohl(address.s_addr) >> 24) == 127);
}

// A query parameter as a whole number or a finite number: the whole text, or an InputError naming
// it (std::stoi would take "3xyz" as 3 and answer "stoi" for "").
int64_t whole_param(const httplib::Request& req, const char* name, const std::string& what) {
  const std::string text = req.get_param_value(name);
  int64_t value = 0;
  if (!req.has_param(name) || !text::parse_int64(text, &value))
    throw InputError(what + ": " + name + " " + text::quote_value(text) + " is not a whole number");
  return int64_t(value);
}

double number_param(const httplib::Request& req, const char* name, const std::string& what) {
  const std::string text = req.get_param_value(name);
  double value = 0;
  if (!req.has_param(name) || !text::parse_double(text, &value))
    throw InputError(what + ": " + name + " " + text::quote_value(text) +
                     " is not a finite number");
  return value;
}

// A query parameter of `count` finite numbers separated by commas.
std::vector<double> numbers_param(const httplib::Request& req, const char* name,
                                  const std::string& what, size_t count) {
  const std::string text = req.get_param_value(name);
  std::vector<double> values;
  if (!req.has_param(name) || !text::parse_number_list(text, &values) || values.size() != count)
    throw InputError(what + ": " + name + " " + text::quote_value(text) + ": " +
                     std::to_string(count) + " finite numbers separated by commas");
  return values;
}

// "name:port" or "[v6]:port" to the name.
std::string host_without_port(const std::string& h) {
  if (!h.empty() && h[0] == '[') return h.substr(0, h.find(']') + 1);
  return h.substr(0, h.find(':'));
}

// 128 random bits as hex: the key a page served on a network address must show.
std::string random_token() {
  std::random_device device;
  std::string token;
  for (int i = 0; i < 4; ++i) {
    char word[9];
    std::snprintf(word, sizeof word, "%08x", unsigned(device()));
    token += word;
  }
  return token;
}

// Whether `given` is the token, in a time that does not depend on where they differ (so that
// the token cannot be guessed character by character from answer times).
bool same_token(const std::string& given, const std::string& token) {
  if (given.size() != token.size()) return false;
  unsigned char differ = 0;
  for (size_t i = 0; i < token.size(); ++i) differ |= uint8_t(given[i] ^ token[i]);
  return differ == 0;
}

// Whether a Cookie header ("a=1; b=2") gives `name` the token.
bool has_cookie(const std::string& header, const std::string& name, const std::string& token) {
  size_t at = 0;
  while (at < header.size()) {
    size_t end = header.find(';', at);
    if (end == std::string::npos) end = header.size();
    const size_t first = header.find_first_not_of(' ', at);
    if (first != std::string::npos && first < end) {
      const std::string item = header.substr(first, end - first);
      if (item.size() > name.size() && item.compare(0, name.size(), name) == 0 &&
          item[name.size()] == '=' && same_token(item.substr(name.size() + 1), token))
        return true;
    }
    at = end + 1;
  }
  return false;
}

}  // namespace

// ------------------------------------------------------------------------------------ server --

struct ViewServer::Impl {
  ViewContent content;
  std::shared_ptr<LiveFeed> live;
  httplib::Server http;
  std::thread thread;
  std::string host;
  // Served on a network address: the token its URL carries (then kept by the page as a
  // cookie); every request without it is refused. Empty on loopback.
  std::string token;
  int port = 0;
  // The shown volume: the content's, or the live run's newest snapshot.
  std::shared_ptr<const Volume> volume;
  std::optional<std::pair<double, double>> volume_window, volume_range;
  int64_t volume_version = -1;
  std::array<ViewPlane, 3> planes;
  // Slicers (one caller at a time each): planes of the volume and of the labels, per axis.
  std::mutex slice_mutex;
  std::map<std::pair<int, int>, std::unique_ptr<Slicer>> plane_slicers;  // (layer, axis)
  std::mutex render_mutex;
  std::vector<uint8_t> probe_mask;

  // The volume the planes show now (under slice_mutex): picks up a newer live snapshot.
  std::shared_ptr<const Volume> current_volume(int64_t* version) {
    if (live) {
      std::lock_guard<std::mutex> lock(live->impl_->mutex);
      if (live->impl_->volume_version != volume_version && live->impl_->volume) {
        const bool regrid = !volume || volume->grid().dims != live->impl_->volume->grid().dims ||
                            volume->grid().origin_mm != live->impl_->volume->grid().origin_mm;
        volume = live->impl_->volume;
        volume_version = live->impl_->volume_version;
        plane_slicers.erase(plane_slicers.lower_bound({0, 0}), plane_slicers.lower_bound({1, 0}));
        if (regrid) planes = view_planes(volume->grid());
        volume_window.reset();  // the range and the auto window follow the live volume
      }
    }
    *version = volume_version;
    return volume;
  }

  const Slicer& plane_slicer(int layer, int axis, const Volume& v) {
    auto& s = plane_slicers[{layer, axis}];
    if (!s) {
      const ViewPlane& p = planes[size_t(axis)];
      ImageGrid g;
      g.width = p.width;
      g.height = p.height;
      g.spacing_mm[0] = g.spacing_mm[1] = p.spacing;
      SliceSettings settings;
      settings.output_type = PixelType::Float32;
      settings.interpolation = layer == 0 ? Interpolation::Linear : Interpolation::Nearest;
      s = std::make_unique<Slicer>(v, ProbeGeometry::linear(g), settings);
    }
    return *s;
  }

  json scene_json() {
    std::lock_guard<std::mutex> lock(slice_mutex);
    int64_t version = 0;
    const std::shared_ptr<const Volume> v = current_volume(&version);
    json j;
    j["title"] = content.title;
    j["mode"] = !live ? "view" : live->impl_->snapshot ? "live-compound" : "live-probe";
    j["volume"] = nullptr;
    j["planes"] = json::array();
    const Volume* shown = v ? v.get() : content.labels ? &*content.labels : nullptr;
    if (v) {
      const VolumeGrid& g = v->grid();
      if (!volume_window) {
        volume_window = auto_volume_window(*v);
        volume_range = v->value_range();
      }
      const auto [lo, hi] = *volume_range;
      json dir = json::array();
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) dir.push_back(g.direction.m[r][c]);
      json presets = json::array();
      // CT presets only where the values look like Hounsfield units.
      if (lo <= -500 && hi >= 300) {
        presets.push_back({"CT soft tissue", 40, 400});
        presets.push_back({"CT abdomen", 60, 350});
        presets.push_back({"CT bone", 400, 1800});
        presets.push_back({"CT lung", -600, 1500});
      }
      presets.push_back({"Auto", volume_window->first, volume_window->second});
      presets.push_back({"Full range", (lo + hi) / 2, std::max(hi - lo, 1e-6)});
      json corners = json::array();
      for (const Vec3& c : box_corners(g)) corners.push_back(vec_json(c));
      j["volume"] = {{"name", content.volume_name},
                     {"dims", {g.dims[0], g.dims[1], g.dims[2]}},
                     {"spacing", vec_json(g.spacing_mm)},
                     {"origin", vec_json(g.origin_mm)},
                     {"direction", dir},
                     {"type", to_string(v->pixel_type())},
                     {"range", {lo, hi}},
                     {"window", {volume_window->first, volume_window->second}},
                     {"presets", presets},
                     {"corners", corners}};
    }
    if (shown) {
      if (!v) {  // labels alone: their box
        json corners = json::array();
        for (const Vec3& c : box_corners(shown->grid())) corners.push_back(vec_json(c));
        j["volume"] = {{"name", content.labels_name},
                       {"corners", corners},
                       {"window", {0.5, 1.0}},
                       {"presets", json::array()},
                       {"labels_only", true}};
      }
      for (const ViewPlane& p : planes)
        j["planes"].push_back({{"axis", p.axis},
                               {"name", p.name()},
                               {"width", p.width},
                               {"height", p.height},
                               {"spacing", p.spacing},
                               {"origin", vec_json(p.origin)},
                               {"u", vec_json(p.u)},
                               {"v", vec_json(p.v)},
                               {"min", p.min},
                               {"max", p.max},
                               {"step", p.step},
                               {"position", (p.min + p.max) / 2}});
    }
    j["labels"] = nullptr;
    if (content.labels) {
      json colors = json::array();
      for (const auto& c : content.label_colors) colors.push_back({c[0], c[1], c[2]});
      j["labels"] = {{"name", content.labels_name}, {"colors", colors}};
    }
    j["meshes"] = json::array();
    for (size_t i = 0; i < content.meshes.size(); ++i) {
      const ViewMesh& m = content.meshes[i];
      j["meshes"].push_back({{"name", m.mesh.name},
                             {"color", {m.color[0], m.color[1], m.color[2]}},
                             {"url", "/api/mesh/" + std::to_string(i)},
                             {"triangles", m.mesh.triangles.size()}});
    }
    j["probe"] = nullptr;
    if (content.probe) {
      const ProbeGeometry& p = *content.probe;
      json outline, corners;
      probe_outline(p, outline, corners);
      j["probe"] = {{"type", to_string(p.type)}, {"width", p.image.width},
                    {"height", p.image.height},  {"pixel_to_probe", mat_json(p.pixel_to_probe())},
                    {"outline", outline},        {"corners", corners}};
    }
    j["poses"] = {{"count", content.poses.size()}, {"url", "/api/poses"}};
    j["image_source"] = content.render ? json(content.image_source) : json(nullptr);
    std::pair<double, double> iw = content.image_window.value_or(
        volume_window ? *volume_window : std::make_pair(127.5, 255.0));
    j["image_window"] = {iw.first, iw.second};
    j["live"] = live ? json{{"url", "/api/live"}} : json(nullptr);
    return j;
  }

  // The layer a plane shows: 0 the volume (a live run's newest snapshot), 1 the labels.
  static int layer_param(const httplib::Request& req, const std::string& what) {
    const std::string layer = req.has_param("layer") ? req.get_param_value("layer") : "volume";
    if (layer != "volume" && layer != "labels")
      throw InputError(what + ": layer " + text::quote_value(layer) + ": volume or labels");
    return layer == "volume" ? 0 : 1;
  }
  // The plane's place, not a pose: beyond any scanner it is no place in the volume.
  static void check_plane_position(double pos, const std::string& shown, const std::string& what) {
    if (std::fabs(pos) > kMaxGeometryMm)
      throw InputError(what + ": pos " + text::quote_value(shown) +
                       " is beyond any scanner (at most 1e9 mm)");
  }

  // Plane `axis` at `pos` into out (under slice_mutex; `v` from current_volume).
  void slice_plane(int layer, int axis, double pos, const std::shared_ptr<const Volume>& v,
                   float* out, const std::string& what) {
    const Volume* source = layer == 0 ? v.get() : content.labels ? &*content.labels : nullptr;
    if (!source) throw InputError(what + ": no " + (layer == 0 ? "volume" : "labels") + " to show");
    const Pose pose = planes[size_t(axis)].pose_at(pos);
    plane_slicer(layer, axis, *source).slice(&pose, 1, out);
  }

  void plane(const httplib::Request& req, httplib::Response& res) {
    const int64_t axis = whole_param(req, "axis", "plane");
    const double pos = number_param(req, "pos", "plane");
    const int layer = layer_param(req, "plane");
    if (axis < 0 || axis > 2) throw InputError("plane: axis 0..2, not " + std::to_string(axis));
    check_plane_position(pos, req.get_param_value("pos"), "plane");
    std::lock_guard<std::mutex> lock(slice_mutex);
    int64_t version = 0;
    const std::shared_ptr<const Volume> v = current_volume(&version);
    const ViewPlane& p = planes[size_t(axis)];
    std::vector<float> out(size_t(p.width) * size_t(p.height));
    slice_plane(layer, int(axis), pos, v, out.data(), "plane");
    res.set_header("X-Volume-Version", std::to_string(version));
    send_floats(res, std::move(out));
  }

  // The three planes at once, one after another (axis 0, 1, 2), all of one volume version: a
  // live page refreshes them with one request instead of three.
  void all_planes(const httplib::Request& req, httplib::Response& res) {
    const std::vector<double> pos = numbers_param(req, "pos", "planes", 3);
    const int layer = layer_param(req, "planes");
    for (double p : pos) check_plane_position(p, req.get_param_value("pos"), "planes");
    std::lock_guard<std::mutex> lock(slice_mutex);
    int64_t version = 0;
    const std::shared_ptr<const Volume> v = current_volume(&version);
    size_t starts[4] = {0};
    for (size_t axis = 0; axis < 3; ++axis)
      starts[axis + 1] = starts[axis] + size_t(planes[axis].width) * size_t(planes[axis].height);
    std::vector<float> out(starts[3]);
    for (int axis = 0; axis < 3; ++axis)
      slice_plane(layer, axis, pos[size_t(axis)], v, out.data() + starts[axis], "planes");
    res.set_header("X-Volume-Version", std::to_string(version));
    send_floats(res, std::move(out));
  }

  void image(const httplib::Request& req, httplib::Response& res) {
    if (!content.render || !content.probe) throw InputError("image: no image source");
    Pose pose;
    int64_t index = -1;
    if (req.has_param("pose")) {
      const int64_t k = whole_param(req, "pose", "image");
      if (k < 0 || uint64_t(k) >= content.poses.size())
        throw InputError("image: pose " + std::to_string(k) + " out of range");
      pose = content.poses[size_t(k)];
      index = k;
    } else {
      const std::vector<double> m = numbers_param(req, "matrix", "image", 16);
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) pose.m[r][c] = m[size_t(4 * r + c)];
      require_rigid_pose(pose, "image: matrix");  // as live slice takes a probe's pose
    }
    std::vector<float> out(size_t(content.probe->image.pixel_count()));
    const double t0 = now_seconds();
    {
      std::lock_guard<std::mutex> lock(render_mutex);
      content.render(pose, index, out.data());
    }
    res.set_header("X-Elapsed-Ms", std::to_string((now_seconds() - t0) * 1e3));
    send_floats(res, std::move(out));
  }

  void live_state(httplib::Response& res) {
    LiveFeed::Impl& f = *live->impl_;
    std::lock_guard<std::mutex> lock(f.mutex);
    f.wanted = true;  // a page is looking: the refresher may take the next snapshot
    f.wake.notify_all();
    // The run's statistics (LiveStats::json) under the short names the page shows.
    json j = f.stats ? json::parse(f.stats()) : json::object();
    for (const char* key : {"received", "compounded", "dropped", "rejected"})
      j[key] = j.value(std::string("frames_") + key, 0);
    j["images"] = j["compounded"];
    j["running"] = f.running;
    j["volume_version"] = f.volume_version;
    j["scene_version"] = f.scene_version;
    j["frame"] = nullptr;
    if (f.seq > 0)
      j["frame"] = {{"seq", f.seq},
                    {"width", f.width},
                    {"height", f.height},
                    {"matrix", mat_json(f.to_world)}};
    res.set_content(j.dump(), "application/json; charset=utf-8");
  }

  void live_frame(httplib::Response& res) {
    LiveFeed::Impl& f = *live->impl_;
    std::lock_guard<std::mutex> lock(f.mutex);
    res.set_header("X-Frame-Seq", std::to_string(f.seq));
    // B-mode frames travel as they came (a quarter of the bytes); other types as float32.
    if (f.type == PixelType::UInt8) {
      res.set_header("X-Pixel-Type", "uint8");
      res.set_content(reinterpret_cast<const char*>(f.pixels.data()), f.pixels.size(),
                      "application/octet-stream");
      return;
    }
    std::vector<float> out(size_t(f.width) * size_t(f.height));
    for_each_value(f.pixels.data(), f.type, out.size(),
                   [&](size_t i, double x) { out[i] = float(x); });
    res.set_header("X-Pixel-Type", "float32");
    send_floats(res, std::move(out));
  }

  void mesh(size_t i, httplib::Response& res) {
    if (i >= content.meshes.size())
      throw InputError("mesh " + std::to_string(i) + ": no such mesh");
    const TriangleMesh& m = content.meshes[i].mesh;
    std::string body(8 + 12 * m.vertices.size() + 12 * m.triangles.size(), '\0');
    char* at = body.data();
    const uint32_t counts[2] = {uint32_t(m.vertices.size()), uint32_t(m.triangles.size())};
    std::memcpy(at, counts, 8);
    at += 8;
    for (const Vec3& p : m.vertices) {
      const float xyz[3] = {float(p[0]), float(p[1]), float(p[2])};
      std::memcpy(at, xyz, 12);
      at += 12;
    }
    for (const auto& t : m.triangles) {
      const uint32_t idx[3] = {uint32_t(t[0]), uint32_t(t[1]), uint32_t(t[2])};
      std::memcpy(at, idx, 12);
      at += 12;
    }
    res.set_content(std::move(body), "application/octet-stream");
  }

  // Whether a request is turned away before anything of it is read beyond its headers (here a
  // body would be read next, and cpp-httplib reads a chunked one whole whatever its size).
  bool refused(const httplib::Request& req, httplib::Response& res) const {
    const auto refuse = [&](int status, const std::string& why) {
      res.status = status;
      res.set_header("Connection", "close");
      res.set_content("view: " + why, "text/plain");
      return true;
    };
    if (req.method != "GET" && req.method != "HEAD")
      return refuse(405, "only GET is served, not " + text::quote_value(req.method));
    if (req.has_header("Transfer-Encoding") ||
        (req.has_header("Content-Length") && req.get_header_value("Content-Length") != "0"))
      return refuse(413, "a request body is not taken here");
    if (req.get_header_value_count("Host") > 1) return refuse(400, "more than one Host header");
    if (is_loopback_name(host)) {
      // Served on loopback, a page of any web site could still reach it by DNS rebinding (its
      // own name re-pointed at 127.0.0.1); its requests carry that name as Host, and are refused.
      const std::string h = req.get_header_value("Host");
      if (h.empty() || is_loopback_name(host_without_port(h))) return false;
      return refuse(403, "served on loopback; Host " + text::quote_value(h) + " refused");
    }
    // On a network address anyone who reaches it could read the data: as Jupyter does, the
    // printed URL carries a token; the page's first request trades it for a cookie that the
    // browser sends with every later one (same host and port only, never to other sites).
    const std::string cookie = "sonoslice_view_" + std::to_string(port);
    if (req.has_param("token") && same_token(req.get_param_value("token"), token)) {
      res.set_header("Set-Cookie", cookie + "=" + token + "; Path=/; HttpOnly; SameSite=Strict");
      return false;
    }
    if (has_cookie(req.get_header_value("Cookie"), cookie, token)) return false;
    return refuse(403, "served on " + host + "; open the URL printed at start, with its token");
  }

  void routes() {
    // Every answer is for this machine's page only: no caching of data that changes live.
    http.set_default_headers({{"Cache-Control", "no-store"}});
    http.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
      return refused(req, res) ? httplib::Server::HandlerResponse::Handled
                               : httplib::Server::HandlerResponse::Unhandled;
    });
    http.Get("/", [](const httplib::Request&, httplib::Response& res) {
      const WebAsset* a = find_web_asset("index.html");
      res.set_content(a->data, a->size, a->mime);
    });
    http.Get(R"(/([a-z0-9_.\-]+\.(?:js|css|html)))",
             [](const httplib::Request& req, httplib::Response& res) {
               const WebAsset* a = find_web_asset(req.matches[1].str());
               if (!a) {
                 res.status = 404;
                 return;
               }
               res.set_content(a->data, a->size, a->mime);
             });
    http.Get("/favicon.ico", [](const httplib::Request&, httplib::Response& res) {
      res.status = 204;  // none: a 404 would be a console error in the browser
    });
    // JSON goes out as "application/json; charset=utf-8": only the exact "application/json" is
    // brotli-compressed by cpp-httplib, at a cost (tens of ms) far above loopback's transfer.
    http.Get("/api/scene", [this](const httplib::Request&, httplib::Response& res) {
      res.set_content(scene_json().dump(), "application/json; charset=utf-8");
    });
    http.Get("/api/plane",
             [this](const httplib::Request& q, httplib::Response& r) { plane(q, r); });
    http.Get("/api/planes",
             [this](const httplib::Request& q, httplib::Response& r) { all_planes(q, r); });
    http.Get("/api/image",
             [this](const httplib::Request& q, httplib::Response& r) { image(q, r); });
    http.Get("/api/poses", [this](const httplib::Request&, httplib::Response& res) {
      std::vector<float> out;
      out.reserve(content.poses.size() * 16);
      for (const Pose& p : content.poses)
        for (int r = 0; r < 4; ++r)
          for (int c = 0; c < 4; ++c) out.push_back(float(p.m[r][c]));
      send_floats(res, std::move(out));
    });
    http.Get("/api/mask", [this](const httplib::Request&, httplib::Response& res) {
      if (!content.probe) throw InputError("mask: no probe");
      res.set_content(reinterpret_cast<const char*>(probe_mask.data()), probe_mask.size(),
                      "application/octet-stream");
    });
    http.Get(R"(/api/mesh/(\d{1,9}))", [this](const httplib::Request& req, httplib::Response& res) {
      mesh(size_t(std::stoul(req.matches[1].str())), res);
    });
    if (live) {
      http.Get("/api/live",
               [this](const httplib::Request&, httplib::Response& r) { live_state(r); });
      http.Get("/api/live/frame",
               [this](const httplib::Request&, httplib::Response& r) { live_frame(r); });
    }
    // A bad request gets a 400 with the library's one-line message; the server keeps serving.
    http.set_exception_handler(
        [](const httplib::Request&, httplib::Response& res, std::exception_ptr ep) {
          std::string message = "error";
          try {
            std::rethrow_exception(ep);
          } catch (const std::exception& e) {
            message = e.what();
          }
          res.status = 400;
          res.set_content(message, "text/plain");
        });
    // cpp-httplib's own refusals (no such path, a method other than GET, a URI or header too
    // long) come without a body: one line that says which.
    http.set_error_handler([](const httplib::Request& req, httplib::Response& res) {
      if (!res.body.empty()) return;
      const std::string path = text::quote_value(req.path);
      // The status first: a refused request line (414) has no method to name.
      const std::string why = res.status == 414   ? "the URI is too long"
                              : res.status == 413 ? "a request body is not taken here"
                              : req.method != "GET" && req.method != "HEAD"
                                  ? "only GET is served, not " + text::quote_value(req.method)
                              : res.status == 404 ? "no such page " + path
                                                  : "a bad request";
      res.set_content("view: " + std::to_string(res.status) + ": " + why, "text/plain");
    });
  }
};

ViewServer::ViewServer(ViewContent content, const std::string& host, int port,
                       std::shared_ptr<LiveFeed> live)
    : impl_(std::make_unique<Impl>()) {
  Impl& im = *impl_;
  im.content = std::move(content);
  im.live = std::move(live);
  im.host = host;
  if (!is_loopback_name(host)) im.token = random_token();
  if (im.content.volume) {
    im.volume = std::make_shared<Volume>(*im.content.volume);
    im.volume_version = 0;
  }
  if (im.volume)
    im.planes = view_planes(im.volume->grid());
  else if (im.content.labels)
    im.planes = view_planes(im.content.labels->grid());
  if (im.content.probe) im.probe_mask = im.content.probe->mask();
  if (im.volume) {  // the scene's window and range now, not while the page waits for them
    im.volume_window = auto_volume_window(*im.volume);
    im.volume_range = im.volume->value_range();
  }
  if (port < 0 || port > 65535)
    throw InputError("--port " + std::to_string(port) + ": expected 0 to 65535");
  im.routes();
  // The page only GETs. Bodies are refused unread beyond a few kB (a 3 GiB POST was held in
  // memory whole); idle and slow connections hold one of many workers for at most a few seconds
  // each (8 workers and 5 s let a handful of idle sockets stall the page).
  im.http.set_payload_max_length(64 * 1024);
  im.http.new_task_queue = [] { return new httplib::ThreadPool(64); };
  im.http.set_read_timeout(2, 0);
  im.http.set_keep_alive_timeout(2);
  // Small answers go out at once (no Nagle delay against the browser's delayed ACKs); accepted
  // sockets inherit the option from the listening one.
  im.http.set_socket_options([](socket_t sock) {
    int yes = 1;
    ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
    ::setsockopt(sock, IPPROTO_TCP, TCP_NODELAY, &yes, sizeof(yes));
  });
  im.port = port == 0                          ? im.http.bind_to_any_port(host)
            : im.http.bind_to_port(host, port) ? port
                                               : -1;
  if (im.port < 0)
    throw Error("view: cannot listen on " + host + ":" + std::to_string(port) +
                " (in use, or not an address of this machine)");
  im.thread = std::thread([&im] { im.http.listen_after_bind(); });
}

ViewServer::~ViewServer() {
  stop();
}

int ViewServer::port() const {
  return impl_->port;
}

std::string ViewServer::url() const {
  const std::string& h = impl_->host;
  const std::string shown = h == "0.0.0.0" || h.empty() ? "127.0.0.1" : h;
  const std::string key = impl_->token.empty() ? "" : "?token=" + impl_->token;
  return "http://" + shown + ":" + std::to_string(impl_->port) + "/" + key;
}

void ViewServer::stop() {
  if (impl_->thread.joinable()) {
    impl_->http.stop();
    impl_->thread.join();
  }
}

}  // namespace sonoslice
