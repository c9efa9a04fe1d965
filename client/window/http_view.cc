#include "client/window/http_view.h"

#include <sys/socket.h>

#include <algorithm>
#include <atomic>
#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <cmath>
#include <condition_variable>
#include <map>
#include <mutex>
#include <set>
#include <thread>

namespace exo {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;
using Clock = std::chrono::steady_clock;

constexpr char kPage[] = R"HTML(<!doctype html>
<html><head><meta charset="utf-8"><title>Exoview</title>
<style>
body{margin:0;background:#111;color:#ddd;font:13px monospace}
#v{width:100vw;height:calc(100vh - 44px);object-fit:contain;display:block;background:#000;cursor:grab}
#o{position:absolute;left:0;top:0;pointer-events:none}
#s{padding:4px 8px;white-space:pre}
</style></head>
<body><img id="v" alt="Exoview live view"><canvas id="o"></canvas><div id="s">connecting...</div>
<button id="dr" style="position:absolute;right:8px;bottom:8px">DR view (V): off</button>
<script>
"use strict";
let seq = 0, drSeq = 0;
// The live DR view (the server's camera stream with the marked regions removed): button / key V.
let dr = new URLSearchParams(location.search).get("dr") === "1", drMeta = "";
const drButton = document.getElementById("dr");
function setDr(on) { dr = on; drButton.textContent = "DR view (V): " + (on ? "on" : "off"); }
drButton.onclick = () => setDr(!dr);
setDr(dr);
// ?frames=N: stop after N frames (a still snapshot, e.g. for a headless browser's screenshot).
const maxFrames = Number(new URLSearchParams(location.search).get("frames") || 0);
let shown = 0;
const img = document.getElementById("v");
const sleep = ms => new Promise(r => setTimeout(r, ms));
async function frames() {
  for (;;) {
    try {
      const live = dr;
      const r = await fetch(live ? "/dr.jpg?after=" + drSeq : "/frame.jpg?after=" + seq);
      if (live && r.status !== 200) { drMeta = await r.text(); await sleep(500); continue; }
      if (r.status === 200) {
        if (live) { drSeq = Number(r.headers.get("X-Frame-Seq")); drMeta = r.headers.get("X-Dr-Meta") || ""; }
        else seq = Number(r.headers.get("X-Frame-Seq"));
        const u = URL.createObjectURL(await r.blob());
        img.onload = () => URL.revokeObjectURL(u);
        img.src = u;
        if (maxFrames > 0 && ++shown >= maxFrames) return;
      }
    } catch (e) { await sleep(500); }
  }
}
// Overlays (the drone, its camera, target, route, flight zones; cells by coverage): lines and
// dots in the frame's pixels (/overlay.json), drawn on a canvas over the picture.
const cv = document.getElementById("o");
let overlay = null;
function drawOverlay() {
  const r = img.getBoundingClientRect();
  cv.style.left = r.left + window.scrollX + "px"; cv.style.top = r.top + window.scrollY + "px";
  cv.width = r.width; cv.height = r.height;
  const g = cv.getContext("2d");
  g.clearRect(0, 0, cv.width, cv.height);
  if (dr || !overlay || !overlay.width) return;  // the overlays belong to the rendered view
  const k = Math.min(r.width / overlay.width, r.height / overlay.height);
  const ox = (r.width - k * overlay.width) / 2, oy = (r.height - k * overlay.height) / 2;
  for (const [x0, y0, x1, y1, c, w] of overlay.lines) {
    g.strokeStyle = c; g.lineWidth = w; g.beginPath();
    g.moveTo(ox + k * x0, oy + k * y0); g.lineTo(ox + k * x1, oy + k * y1); g.stroke();
  }
  for (const [x, y, c] of overlay.dots) {
    g.fillStyle = c; g.beginPath(); g.arc(ox + k * x, oy + k * y, 3, 0, 2 * Math.PI); g.fill();
  }
  if (press && onDrone && cursor && overlay.drone_px) {  // the drag: drone -> where it goes
    const [dx, dy] = overlay.drone_px;
    g.strokeStyle = "rgb(80,200,255)"; g.lineWidth = 2; g.beginPath();
    g.moveTo(ox + k * dx, oy + k * dy); g.lineTo(ox + k * cursor.x, oy + k * cursor.y); g.stroke();
    g.beginPath(); g.arc(ox + k * cursor.x, oy + k * cursor.y, 10, 0, 2 * Math.PI); g.stroke();
  }
}
async function overlays() {
  for (;;) {
    try { overlay = await (await fetch("/overlay.json")).json(); drawOverlay(); } catch (e) {}
    if (maxFrames > 0 && shown >= maxFrames) return;
    await sleep(200);
  }
}
onresize = drawOverlay;
async function stats() {
  for (;;) {
    try {
      const j = await (await fetch("/status")).json();
      document.getElementById("s").textContent =
        `frame ${j.frame_ms.toFixed(1)} ms  resolution 1/${j.stage}  model v${j.model_version}  ` +
        `views ${j.views}  cells ${j.cells}  ${j.sync}  frames ${j.frames}  browsers ${j.clients}  ` +
        (j.control ? `\n${j.control}  ` : "") + (dr ? `\nlive DR view: ${drMeta}  ` : "") +
        (j.drone_controls && j.drone_controls.operator && j.drone_controls.operator.last
           ? `${j.drone_controls.operator.last.summary}  ` : "") +
        (j.drone_controls && j.drone_controls.xray
           ? `X-RAY cut at ${j.drone_controls.xray_clip_m.toFixed(2)} m  ` : "") +
        (j.completion && j.completion.hud ? `\n${j.completion.hud}  ` : "") +
        (droneMode ? "DRONE MODE  " : "") +
        `| WASD QE move, drag/arrows look, wheel speed, R reset, F follow, G drone, 3 cells, 4 tau/refs, 5 drone, V DR view, C complete the holes` +
        `\n| drone: ctrl/M + click = gaze-to-see, + drag from the drone = pick-and-place, ` +
        `IJKL UO YH joypad, X x-ray ([ ] plane)`;
      if (maxFrames > 0 && shown >= maxFrames) return;
    } catch (e) {}
    await sleep(500);
  }
}
const keys = {KeyW:"w",KeyA:"a",KeyS:"s",KeyD:"d",KeyQ:"q",KeyE:"e",ArrowLeft:"left",
  ArrowRight:"right",ArrowUp:"up",ArrowDown:"down",KeyR:"r",KeyF:"f",Digit1:"1",Digit2:"2",
  Digit3:"3",Digit4:"4",Digit5:"5",KeyG:"g",KeyI:"i",KeyJ:"j",KeyK:"k",KeyL:"l",KeyU:"u",
  KeyO:"o",KeyY:"y",KeyH:"h",KeyX:"x",BracketLeft:"xnear",BracketRight:"xfar",KeyC:"c"};
// Steering the drone: ctrl (or drone mode, M) + click = gaze-to-see at that pixel; + drag that
// starts on the drone = pick-and-place (the mouse as the hand, docs/viewer.md).
let droneMode = false, press = null, onDrone = false, cursor = null;
// X-ray: the hole is around the pointer (sent with X and, while on, as it moves: 10 Hz at most).
let xray = false, pointer = null, xatSent = 0;
function framePx(e) {
  const r = img.getBoundingClientRect();
  if (!overlay || !overlay.width) return null;
  const k = Math.min(r.width / overlay.width, r.height / overlay.height);
  return {x: (e.clientX - r.left - (r.width - k * overlay.width) / 2) / k,
          y: (e.clientY - r.top - (r.height - k * overlay.height) / 2) / k};
}
const held = new Set();
// One-shot keys (the viewer acts on each press): sent once per press, never re-sent as held
// (re-sending them every 200 ms toggled X-ray, overlays, follow ... again while the key was down);
// the X-ray cut's [ ] step on each auto-repeat.
const once = new Set(["r", "f", "g", "1", "2", "3", "4", "5", "x", "xnear", "xfar", "c"]);
const send = q => fetch("/input?" + q, {method: "POST"}).catch(() => {});
onkeydown = e => { if (e.code === "KeyM" && !e.repeat) { droneMode = !droneMode; return; }
  if (e.code === "KeyV") { setDr(!dr); e.preventDefault(); return; }
  const k = keys[e.code]; if (!k) return; e.preventDefault();
  if (k === "x") { if (e.repeat) return; xray = !xray; if (pointer) { send(`key=x&down=1&xat=${pointer.x},${pointer.y}`); return; } }
  if (once.has(k)) { if (!e.repeat || k === "xnear" || k === "xfar") send("key=" + k + "&down=1"); return; }
  if (!held.has(k)) { held.add(k); send("key=" + k + "&down=1"); } };
onkeyup = e => { const k = keys[e.code]; if (!k || once.has(k)) return; held.delete(k); send("key=" + k + "&down=0"); };
setInterval(() => held.forEach(k => send("key=" + k + "&down=1")), 200);
let drag = false;
img.onmousedown = e => {
  e.preventDefault();
  if (droneMode || e.ctrlKey) {
    press = framePx(e);
    const d = overlay && overlay.drone_px;
    onDrone = !!(press && d && Math.hypot(press.x - d[0], press.y - d[1]) <= 40);
    return;
  }
  drag = true;
};
onmouseup = e => {
  drag = false;
  if (!press) return;
  const p = framePx(e) || press;
  if (onDrone && Math.hypot(p.x - press.x, p.y - press.y) >= 1)
    send(`pick=${press.x},${press.y},${p.x},${p.y}`);
  else if (!onDrone && Math.hypot(p.x - press.x, p.y - press.y) <= 5)
    send(`gaze=${p.x},${p.y}`);
  press = null; cursor = null; drawOverlay();
};
onmousemove = e => {
  pointer = framePx(e) || pointer;
  if (xray && pointer && !press && performance.now() - xatSent > 100) {
    xatSent = performance.now(); send(`xat=${pointer.x},${pointer.y}`); }
  if (press) { if (onDrone) { cursor = framePx(e); drawOverlay(); } return; }
  if (drag) send("dx=" + e.movementX + "&dy=" + e.movementY);
};
img.onwheel = e => { e.preventDefault(); send("wheel=" + (e.deltaY < 0 ? 1 : -1)); };
frames();
stats();
overlays();
</script></body></html>
)HTML";

std::map<std::string, std::string> Query(std::string_view target) {
  std::map<std::string, std::string> q;
  const size_t qm = target.find('?');
  if (qm == std::string_view::npos) return q;
  std::string_view rest = target.substr(qm + 1);
  while (!rest.empty()) {
    const size_t amp = rest.find('&');
    std::string_view kv = rest.substr(0, amp);
    const size_t eq = kv.find('=');
    if (eq != std::string_view::npos)
      q[std::string(kv.substr(0, eq))] = std::string(kv.substr(eq + 1));
    if (amp == std::string_view::npos) break;
    rest = rest.substr(amp + 1);
  }
  return q;
}

double ToDouble(const std::string& s) {
  try {
    const double v = std::stod(s);
    return std::isfinite(v) ? std::clamp(v, -1000.0, 1000.0) : 0.0;
  } catch (...) {
    return 0.0;
  }
}

}  // namespace

class HttpView::Impl {
 public:
  ~Impl() { Stop(); }

  absl::Status Start(const std::string& host_port) {
    const size_t colon = host_port.rfind(':');
    if (colon == std::string::npos)
      return absl::InvalidArgumentError("--http wants HOST:PORT, got '" + host_port + "'");
    boost::system::error_code ec;
    const auto addr = asio::ip::make_address(host_port.substr(0, colon), ec);
    if (ec) return absl::InvalidArgumentError("--http: bad address '" + host_port + "'");
    int port = 0;
    try {
      port = std::stoi(host_port.substr(colon + 1));
    } catch (...) {
      return absl::InvalidArgumentError("--http: bad port in '" + host_port + "'");
    }
    if (port < 0 || port > 65535) return absl::InvalidArgumentError("--http: port out of range");
    acceptor_.open(addr.is_v6() ? tcp::v6() : tcp::v4(), ec);
    if (!ec) acceptor_.set_option(asio::socket_base::reuse_address(true), ec);
    if (!ec) acceptor_.bind(tcp::endpoint(addr, uint16_t(port)), ec);
    if (!ec) acceptor_.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) return absl::UnavailableError("--http " + host_port + ": " + ec.message());
    port_ = acceptor_.local_endpoint().port();
    accept_thread_ = std::thread([this] { AcceptLoop(); });
    return absl::OkStatus();
  }

  void Stop() {
    if (stop_.exchange(true)) return;
    boost::system::error_code ec;
    acceptor_.cancel(ec);
    ::shutdown(acceptor_.native_handle(), SHUT_RDWR);
    acceptor_.close(ec);
    {
      std::lock_guard lock(conn_mu_);
      for (int fd : fds_) ::shutdown(fd, SHUT_RDWR);
    }
    frame_cv_.notify_all();
    if (accept_thread_.joinable()) accept_thread_.join();
    std::unique_lock lock(conn_mu_);
    conn_cv_.wait(lock, [&] { return active_ == 0; });
  }

  void AcceptLoop() {
    while (!stop_.load()) {
      tcp::socket socket(io_);
      boost::system::error_code ec;
      acceptor_.accept(socket, ec);
      if (ec || stop_.load()) break;
      {
        std::lock_guard lock(conn_mu_);
        if (active_ >= max_clients_) {
          // Over the limit: answer 503 and close (the viewer keeps serving the others).
          http::response<http::string_body> res{http::status::service_unavailable, 11};
          res.set(http::field::content_type, "text/plain");
          res.body() = "too many clients\n";
          res.prepare_payload();
          http::write(socket, res, ec);
          continue;
        }
        ++active_;
        fds_.insert(socket.native_handle());
      }
      std::thread([this, s = std::move(socket)]() mutable { Serve(std::move(s)); }).detach();
    }
  }

  void Serve(tcp::socket socket) {
    const int fd = socket.native_handle();
    boost::system::error_code ec;
    beast::flat_buffer buffer;
    while (!stop_.load()) {
      http::request<http::string_body> req;
      http::read(socket, buffer, req, ec);
      if (ec) break;
      if (!Handle(socket, req)) break;
      if (!req.keep_alive()) break;
    }
    socket.shutdown(tcp::socket::shutdown_both, ec);
    socket.close(ec);
    std::lock_guard lock(conn_mu_);
    fds_.erase(fd);
    --active_;
    conn_cv_.notify_all();
  }

  template <typename Body>
  bool Send(tcp::socket& socket, http::response<Body>& res,
            const http::request<http::string_body>& req) {
    res.set(http::field::cache_control, "no-store");
    res.keep_alive(req.keep_alive());
    res.prepare_payload();
    boost::system::error_code ec;
    http::write(socket, res, ec);
    return !ec;
  }

  bool Text(tcp::socket& socket, const http::request<http::string_body>& req, http::status st,
            const char* type, std::string body) {
    http::response<http::string_body> res{st, req.version()};
    res.set(http::field::content_type, type);
    res.body() = std::move(body);
    return Send(socket, res, req);
  }

  bool Handle(tcp::socket& socket, const http::request<http::string_body>& req) {
    const std::string target(req.target());
    const std::string path = target.substr(0, target.find('?'));
    if (req.method() == http::verb::get && (path == "/" || path == "/index.html"))
      return Text(socket, req, http::status::ok, "text/html; charset=utf-8", kPage);
    if (req.method() == http::verb::get && path == "/status")
      return Text(socket, req, http::status::ok, "application/json", status_());
    if (req.method() == http::verb::get && path == "/metrics")
      return Text(socket, req, http::status::ok, "text/plain; version=0.0.4", metrics_());
    if (req.method() == http::verb::get && path == "/overlay.json") {
      std::string body;
      {
        std::lock_guard lock(frame_mu_);
        body = overlay_;
      }
      return Text(socket, req, http::status::ok, "application/json", std::move(body));
    }
    if (req.method() == http::verb::get && path == "/frame.jpg") {
      const auto q = Query(target);
      uint64_t after = 0;
      if (auto it = q.find("after"); it != q.end())
        after = uint64_t(std::max(0.0, ToDouble(it->second)));
      std::shared_ptr<const std::vector<uint8_t>> jpeg;
      uint64_t seq = 0;
      {
        std::unique_lock lock(frame_mu_);
        frame_cv_.wait_for(lock, std::chrono::seconds(2),
                           [&] { return stop_.load() || (latest_ && seq_ > after); });
        jpeg = latest_;
        seq = seq_;
      }
      if (!jpeg)
        return Text(socket, req, http::status::service_unavailable, "text/plain", "no frame yet\n");
      http::response<http::vector_body<uint8_t>> res{http::status::ok, req.version()};
      res.set(http::field::content_type, "image/jpeg");
      res.set("X-Frame-Seq", std::to_string(seq));
      res.body() = *jpeg;
      frames_sent_.fetch_add(1);
      return Send(socket, res, req);
    }
    if (req.method() == http::verb::get && path == "/dr.jpg") return DrFrame(socket, req, target);
    if (req.method() == http::verb::get && path == "/stream") return Stream(socket, req);
    if (req.method() == http::verb::post && path == "/input") {
      Input(Query(target));
      return Text(socket, req, http::status::no_content, "text/plain", "");
    }
    return Text(socket, req, http::status::not_found, "text/plain", "not found: " + path + "\n");
  }

  bool DrFrame(tcp::socket& socket, const http::request<http::string_body>& req,
               const std::string& target) {
    std::function<std::string()> status;
    {
      std::lock_guard lock(frame_mu_);
      if (!dr_request_)
        return Text(socket, req, http::status::not_found, "text/plain",
                    "no live DR view: the viewer shows a model file, not a server (--server)\n");
      dr_request_();
      status = dr_status_;
    }
    const auto q = Query(target);
    uint64_t after = 0;
    if (auto it = q.find("after"); it != q.end())
      after = uint64_t(std::max(0.0, ToDouble(it->second)));
    std::shared_ptr<const std::vector<uint8_t>> jpeg;
    std::string meta;
    uint64_t seq = 0;
    {
      std::unique_lock lock(frame_mu_);
      frame_cv_.wait_for(lock, std::chrono::seconds(2),
                         [&] { return stop_.load() || (dr_latest_ && dr_seq_ > after); });
      jpeg = dr_latest_;
      meta = dr_meta_;
      seq = dr_seq_;
    }
    if (!jpeg)
      return Text(socket, req, http::status::service_unavailable, "text/plain",
                  "no live DR frame yet (" + (status ? status() : std::string()) + ")\n");
    http::response<http::vector_body<uint8_t>> res{http::status::ok, req.version()};
    res.set(http::field::content_type, "image/jpeg");
    res.set("X-Frame-Seq", std::to_string(seq));
    res.set("X-Dr-Meta", meta);
    res.body() = *jpeg;
    return Send(socket, res, req);
  }

  bool Stream(tcp::socket& socket, const http::request<http::string_body>& req) {
    http::response<http::empty_body> res{http::status::ok, req.version()};
    res.set(http::field::content_type, "multipart/x-mixed-replace; boundary=exoviewframe");
    res.set(http::field::cache_control, "no-store");
    res.keep_alive(false);
    http::response_serializer<http::empty_body> sr{res};
    boost::system::error_code ec;
    http::write_header(socket, sr, ec);
    if (ec) return false;
    uint64_t last = 0;
    while (!stop_.load()) {
      std::shared_ptr<const std::vector<uint8_t>> jpeg;
      {
        std::unique_lock lock(frame_mu_);
        frame_cv_.wait_for(lock, std::chrono::milliseconds(500),
                           [&] { return stop_.load() || (latest_ && seq_ > last); });
        if (!latest_ || seq_ <= last) continue;
        jpeg = latest_;
        last = seq_;
      }
      const std::string head = "--exoviewframe\r\nContent-Type: image/jpeg\r\nContent-Length: " +
                               std::to_string(jpeg->size()) + "\r\n\r\n";
      asio::write(socket, asio::buffer(head), ec);
      if (!ec) asio::write(socket, asio::buffer(*jpeg), ec);
      if (!ec) asio::write(socket, asio::buffer("\r\n", 2), ec);
      if (ec) return false;  // the browser went away; the others keep their frames
      frames_sent_.fetch_add(1);
    }
    return false;
  }

  void Input(const std::map<std::string, std::string>& q) {
    std::lock_guard lock(input_mu_);
    if (auto k = q.find("key"); k != q.end()) {
      const bool down = q.count("down") && q.at("down") == "1";
      static const std::set<std::string> kHeld = {"w", "a",    "s",     "d",  "q",
                                                  "e", "left", "right", "up", "down",
                                                  "i", "j",    "k",     "l",  "u",
                                                  "o", "y",    "h"};
      static const std::set<std::string> kOnce = {"r", "f", "g", "tab", "1", "2", "3",
                                                  "4", "5", "x", "xnear", "xfar", "c"};
      if (kHeld.count(k->second)) {
        if (down)
          held_[k->second] = Clock::now();
        else
          held_.erase(k->second);
      } else if (kOnce.count(k->second) && down) {
        presses_.push_back(k->second);
      }
    }
    if (auto it = q.find("dx"); it != q.end()) dx_ += ToDouble(it->second);
    if (auto it = q.find("dy"); it != q.end()) dy_ += ToDouble(it->second);
    if (auto it = q.find("wheel"); it != q.end()) wheel_ += ToDouble(it->second);
    // Drone gestures (bounded: a page cannot queue more than 16 of each between two frames).
    auto numbers = [](const std::string& csv) {
      std::vector<double> v;
      size_t start = 0;
      while (start <= csv.size() && v.size() < 8) {
        const size_t comma = csv.find(',', start);
        v.push_back(ToDouble(csv.substr(start, comma - start)));
        if (comma == std::string::npos) break;
        start = comma + 1;
      }
      return v;
    };
    if (auto it = q.find("gaze"); it != q.end() && gazes_.size() < 16) {
      const auto v = numbers(it->second);
      if (v.size() == 2) gazes_.push_back({v[0], v[1]});
    }
    if (auto it = q.find("xat"); it != q.end()) {
      const auto v = numbers(it->second);
      if (v.size() == 2 && std::isfinite(v[0]) && std::isfinite(v[1])) xray_at_ = {v[0], v[1]};
    }
    if (auto it = q.find("pick"); it != q.end() && picks_.size() < 16) {
      const auto v = numbers(it->second);
      auto hand = [&](const char* k) { return q.count(k) ? ToDouble(q.at(k)) : -1.0; };
      if (v.size() == 4) picks_.push_back({v[0], v[1], v[2], v[3], hand("hand0"), hand("hand1")});
    }
  }

  HttpInput Take() {
    std::lock_guard lock(input_mu_);
    HttpInput in;
    const auto now = Clock::now();
    for (auto it = held_.begin(); it != held_.end();) {
      if (now - it->second > std::chrono::milliseconds(600)) {
        it = held_.erase(it);  // not refreshed: the browser went away or lost focus
        continue;
      }
      const std::string& k = it->first;
      in.forward |= k == "w";
      in.back |= k == "s";
      in.left |= k == "a";
      in.right |= k == "d";
      in.up |= k == "e";
      in.down |= k == "q";
      in.turn_left |= k == "left";
      in.turn_right |= k == "right";
      in.turn_up |= k == "up";
      in.turn_down |= k == "down";
      in.held.push_back(k);
      ++it;
    }
    in.look_dx_px = std::exchange(dx_, 0.0);
    in.look_dy_px = std::exchange(dy_, 0.0);
    in.wheel = std::exchange(wheel_, 0.0);
    in.presses = std::exchange(presses_, {});
    in.gazes = std::exchange(gazes_, {});
    in.picks = std::exchange(picks_, {});
    in.xray_at = std::exchange(xray_at_, std::nullopt);
    return in;
  }

  void Publish(std::vector<uint8_t> jpeg) {
    auto p = std::make_shared<const std::vector<uint8_t>>(std::move(jpeg));
    {
      std::lock_guard lock(frame_mu_);
      latest_ = std::move(p);
      ++seq_;
    }
    frame_cv_.notify_all();
  }

  asio::io_context io_;
  tcp::acceptor acceptor_{io_};
  int port_ = 0;
  int max_clients_ = 64;
  std::function<std::string()> status_, metrics_;
  std::atomic<bool> stop_{false};
  std::thread accept_thread_;
  std::mutex conn_mu_;
  std::condition_variable conn_cv_;
  int active_ = 0;
  std::set<int> fds_;
  std::mutex frame_mu_;
  std::condition_variable frame_cv_;
  std::shared_ptr<const std::vector<uint8_t>> latest_;
  std::string overlay_ = R"({"width":0,"height":0,"lines":[],"dots":[]})";
  uint64_t seq_ = 0;
  // The live DR view (under frame_mu_).
  std::shared_ptr<const std::vector<uint8_t>> dr_latest_;
  std::string dr_meta_;
  uint64_t dr_seq_ = 0;
  std::function<void()> dr_request_;
  std::function<std::string()> dr_status_;
  std::atomic<uint64_t> frames_sent_{0};
  std::mutex input_mu_;
  std::map<std::string, Clock::time_point> held_;
  std::vector<std::string> presses_;
  std::vector<std::array<double, 2>> gazes_;
  std::vector<std::array<double, 6>> picks_;
  std::optional<std::array<double, 2>> xray_at_;
  double dx_ = 0, dy_ = 0, wheel_ = 0;
};

absl::StatusOr<std::unique_ptr<HttpView>> HttpView::Start(const std::string& host_port,
                                                          std::function<std::string()> status_json,
                                                          std::function<std::string()> metrics_text,
                                                          int max_clients) {
  auto impl = std::make_unique<Impl>();
  impl->status_ = std::move(status_json);
  impl->metrics_ = std::move(metrics_text);
  impl->max_clients_ = max_clients;
  EXO_RETURN_IF_ERROR(impl->Start(host_port));
  return std::unique_ptr<HttpView>(new HttpView(std::move(impl)));
}

HttpView::HttpView(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
HttpView::~HttpView() = default;
int HttpView::port() const { return impl_->port_; }
void HttpView::PublishFrame(std::vector<uint8_t> jpeg) { impl_->Publish(std::move(jpeg)); }
HttpInput HttpView::TakeInput() { return impl_->Take(); }
void HttpView::SetOverlay(std::string json) {
  std::lock_guard lock(impl_->frame_mu_);
  impl_->overlay_ = std::move(json);
}
void HttpView::PublishDrFrame(std::vector<uint8_t> jpeg, std::string meta_json) {
  auto p = std::make_shared<const std::vector<uint8_t>>(std::move(jpeg));
  {
    std::lock_guard lock(impl_->frame_mu_);
    impl_->dr_latest_ = std::move(p);
    impl_->dr_meta_ = std::move(meta_json);
    ++impl_->dr_seq_;
  }
  impl_->frame_cv_.notify_all();
}
void HttpView::SetDrSource(std::function<void()> on_request, std::function<std::string()> status) {
  std::lock_guard lock(impl_->frame_mu_);
  impl_->dr_request_ = std::move(on_request);
  impl_->dr_status_ = std::move(status);
}
uint64_t HttpView::frames_sent() const { return impl_->frames_sent_.load(); }
int HttpView::clients() const {
  std::lock_guard lock(impl_->conn_mu_);
  return impl_->active_;
}

}  // namespace exo
