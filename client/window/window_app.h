// The interactive viewer (issue 17): a window on a saved model file or a live subscription,
// fly navigation (WASD + mouse look with the left button held, arrow keys turn, Q/E down/up,
// scroll = speed, R = reset to the nearest stored view, F = follow the live camera (the newest
// stored view), Tab = overlays, P = save the model, Esc = quit), rendering on its own thread
// (nav::RenderScheduler: input and the HUD never wait for a render), adaptive resolution (⅛-¼ of
// the window per side while moving, with at most moving_candidates references per pixel; ½ then
// the exact full frame once the camera stops, the last frame reused while nothing changes), a HUD
// and scene overlays (stored-view frusta coloured by age, the live
// camera, the proxy wireframe, cells coloured by the server's coverage τ or their reference
// count, the drone with its camera frustum, target, route and flight zones), and steering the
// drone (issue 19 item 5: Ctrl/M + click = gaze-to-see, + drag from the drone = pick-and-place,
// I K J L U O Y H = joypad, X [ ] = the X-ray cut-away; client/window/drone_operator.h), and
// T = tint the pixels rendered from inpainted views, C = scene completion at the camera,
// V = the live DR view (issue 18: the server's WatchDrView frames, the camera with the marked
// regions removed, instead of the render; subscribed only while on). Also the scripted
// modes that need no window: renders along a TUM path, and the frame-time benchmark (which
// does need a window: it measures what the person sees, presentation included).
#pragma once

#include <string>

#include "client/uploader/upload_client.h"  // ChannelSecurity

namespace exo {

struct WindowAppOptions {
  // Model: a file (model_io.h) or a server subscription.
  std::string model_file, server, journal;
  // TLS and the bearer token for every channel to the server (the live model, the control
  // service, the live DR view), as exoview_viewer's --tls_* / --token_file; empty = plain text.
  ChannelSecurity security;
  std::string checkpoint;  // or a server checkpoint (exoview_server --checkpoint_path)
  std::string save_model;  // written on P and on exit (live sessions)
  int save_model_jpeg_quality = 90;  // its views' colour: JPEG quality, 0 = raw (as exoview_viewer)
  int width = 1280, height = 720;
  double hfov_deg = 65.0;
  int n_best = 3;
  bool adaptive = true;
  int moving_divisor = 4;   // start divisor while moving
  double target_ms = 33.3;  // moving frame budget (0 = keep moving_divisor)
  // References a pixel evaluates in a reduced-resolution moving frame (RenderApprox::
  // max_candidates; 0 = all, exact). Frames after the camera stops and every full-resolution
  // frame are exact.
  int moving_candidates = 8;
  int start_view = -1;      // initial pose: this stored view (default: the smallest id)
  bool overlays = true;     // HUD + scene overlays at start (Tab toggles)
  std::string record;       // TUM path of the session, written at exit
  std::string replay;       // TUM path played back in the window (at its timestamps)
  std::string status_file;  // JSON of the viewer's state after each full-resolution frame
  double max_seconds = 0;   // close after this long (0 = when the window is closed)
  // Scripted render (no window): every pose of `path` (TUM) to out_dir/frame_NNNNN.png.
  std::string path, out_dir;
  // Browser view (no window): serve the view on HOST:PORT (http_view.h); port_file gets the port.
  std::string http, port_file;
  int jpeg_quality = 80;
  // Benchmark (window): moving vs still frame times, adaptive on and off, stage SSIM -> JSON.
  bool bench = false;
  int bench_frames = 40;
  std::string bench_json, bench_label;
  std::string bench_modes = "adaptive_budget,adaptive_fixed,full_always";
  // Drone overlays (issue 19): the control service polled (GetControlState, 10 Hz) for the
  // drone, its camera, target, route and zones. "" = the --server of a live model (none for a
  // file), "none" = off, else HOST:PORT.
  std::string control;
  std::string drone_id = "drone";
  bool cells_by_tau = true;  // cells coloured by coverage τ when the model has it (key 4)
  // Steering the drone (issue 19 item 5; docs/viewer.md): the operator id sent with the
  // commands ("" = window-<pid>), the mouse-hand's distance from the eye, the X-ray plane's
  // margin behind the point under the cursor and its distance when there is none.
  std::string operator_id;
  double hand_m = 0.5;
  double xray_margin_m = 0.3, xray_default_m = 1.5;
  double xray_radius = 0.22;  // the X-ray hole's radius, a fraction of the picture's height
};

// Runs the app; returns the process exit code (0 ok, 1 runtime error, 2 bad input).
int RunWindowApp(const WindowAppOptions& options);

}  // namespace exo
