// The browser view of the viewer (issue 17): a small HTTP server (Boost.Beast, one thread per
// connection, at most `max_clients`) that serves
//   GET /             the page (no external assets): the live view, keyboard/mouse navigation,
//   stats
//                     (/?frames=N stops after N frames: a still snapshot)
//   GET /frame.jpg?after=N   the newest JPEG frame, waiting (up to 2 s) for one newer than N;
//                            its sequence number in the X-Frame-Seq header
//   GET /stream       the same frames as MJPEG (multipart/x-mixed-replace), for <img> or players
//   GET /status       read-only JSON of the viewer's state
//   GET /metrics      Prometheus text (frame time, bytes received, model version, clients)
//   GET /dr.jpg?after=N      the live DR view (issue 18: the server's camera stream with the
//                     marked regions removed, WatchDrView), waiting up to 2 s for a frame newer
//                     than N; X-Frame-Seq as above, X-Dr-Meta: JSON of the frame (sequence,
//                     composited, roi_px, latency_ms); 503 with the reason while there is none.
//                     Each request is a demand (SetDrDemand): the viewer watches only while asked.
//                     The page's "DR view" button (key V) switches the picture to it.
//   GET /overlay.json the overlays of the newest frame (drone, camera, target, route, zones;
//                     cells by coverage), drawn by the page on a canvas over the picture
//   POST /input?key=K&down=0|1   held keys (w a s d q e, arrows; expire 0.6 s after the last
//                     refresh, so a browser that goes away never leaves a key held), one-shot
//                     keys (r f g tab 1 2 3 4 5), POST /input?dx=..&dy=.. mouse look, &wheel=..
//                     steering the drone: held i j k l u o y h (joypad), one-shot x xnear xfar
//                     (X-ray), gaze=X,Y (a click), pick=X0,Y0,X1,Y1[&hand0=M&hand1=M] (a drag)
// Frames are shared: the renderer publishes one JPEG and every client takes the newest (a slow
// client skips frames, nothing queues up per client).
#pragma once

#include <array>
#include <optional>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "common/status.h"

namespace exo {

struct HttpInput {
  bool forward = false, back = false, left = false, right = false, up = false, down = false;
  bool turn_left = false, turn_right = false, turn_up = false, turn_down = false;
  double look_dx_px = 0, look_dy_px = 0, wheel = 0;
  std::vector<std::string> presses;  // one-shot keys since the last TakeInput
  // Steering the drone (issue 19 item 5): held keys (also the joypad's i j k l u o y h),
  // clicks (gaze-to-see) and drags from the drone (pick-and-place) in the frame's pixels since
  // the last TakeInput: {x, y} and {x0, y0, x1, y1, hand0_m, hand1_m} (hand < 0: the default).
  std::vector<std::string> held;
  std::vector<std::array<double, 2>> gazes;
  std::vector<std::array<double, 6>> picks;
  // The pointer's last position over the picture (frame pixels), sent with X and while the
  // X-ray hole is on: the hole is around it.
  std::optional<std::array<double, 2>> xray_at;
};

class HttpView {
 public:
  // host_port "127.0.0.1:8080" (port 0 = a free one). `status_json` / `metrics_text` are called
  // from connection threads.
  static absl::StatusOr<std::unique_ptr<HttpView>> Start(const std::string& host_port,
                                                         std::function<std::string()> status_json,
                                                         std::function<std::string()> metrics_text,
                                                         int max_clients = 64);
  ~HttpView();
  int port() const;
  void PublishFrame(std::vector<uint8_t> jpeg);
  // GET /overlay.json: what the page draws over the picture, in the frame's full-size pixels:
  // {"width", "height", "lines": [[x0, y0, x1, y1, css colour, width], ...],
  //  "dots": [[x, y, css colour], ...]}.
  void SetOverlay(std::string json);
  // The live DR view: the newest frame (JPEG) and its metadata (one-line JSON); `on_request` is
  // called on every GET /dr.jpg (start / keep the subscription), `status` gives the 503's reason.
  void PublishDrFrame(std::vector<uint8_t> jpeg, std::string meta_json);
  void SetDrSource(std::function<void()> on_request, std::function<std::string()> status);
  HttpInput TakeInput();
  // Counters for the metrics.
  uint64_t frames_sent() const;
  int clients() const;

  class Impl;

 private:
  explicit HttpView(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace exo
