// exoview_window: the interactive viewer window (issue 17) on a saved model file or a live server
// subscription; also scripted renders along a TUM path (no window) and the window's frame-time
// benchmark. Keys and modes: client/window/window_app.h; docs/viewer.md.
#include "client/window/window_app.h"
#include "common/cli/cli.h"

int main(int argc, char** argv) {
  exo::WindowAppOptions o;
  CLI::App app{"Interactive viewer window: fly through a saved or live Exoview model.",
               "exoview_window"};
  exo::cli::Setup(app);
  app.add_option("--model", o.model_file, "model file to show (exoview_viewer --save_model)");
  app.add_option("--checkpoint", o.checkpoint, "or: a server checkpoint file (--checkpoint_path)");
  app.add_option("--server", o.server, "or: subscribe to this server HOST:PORT (live)");
  app.add_option("--journal", o.journal, "delta journal of the live subscription (resume)");
  app.add_option("--tls_ca", o.security.tls_ca, "CA certificate (PEM) of the server's certificate: TLS");
  app.add_option("--tls_cert", o.security.tls_cert, "client certificate (PEM), for mutual TLS");
  app.add_option("--tls_key", o.security.tls_key, "client private key (PEM)");
  app.add_option("--tls_server_name", o.security.server_name, "name to verify in the server certificate");
  app.add_option("--token_file", o.security.token_file,
                 "file holding this client's bearer token (a viewer's; an operator's to steer the drone)");
  app.add_option("--save_model", o.save_model, "write the model here on P and on exit (live)");
  app.add_option("--save_model_jpeg_quality", o.save_model_jpeg_quality,
                 "JPEG quality of the saved views' colour (0 = raw, 13x larger on 7-Scenes)")
      ->check(CLI::Range(0, 100));
  app.add_option("--width", o.width, "window width (px)")->check(CLI::Range(16, 8192));
  app.add_option("--height", o.height, "window height (px)")->check(CLI::Range(16, 8192));
  app.add_option("--hfov_deg", o.hfov_deg, "horizontal field of view (degrees)")
      ->check(CLI::Range(5.0, 170.0));
  app.add_option("--n_best", o.n_best, "views blended per pixel")->check(CLI::Range(1, 16));
  app.add_flag("!--no_adaptive", o.adaptive, "always render at full resolution");
  app.add_option("--moving_divisor", o.moving_divisor,
                 "resolution divisor per side while moving (1, 2, 4, 8)")
      ->check(CLI::IsMember({1, 2, 4, 8}));
  app.add_option("--target_ms", o.target_ms,
                 "frame budget while moving: the divisor adapts (0 = fixed --moving_divisor)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--start_view", o.start_view, "start at this stored view id");
  app.add_flag("!--no_overlays", o.overlays, "start with the HUD and overlays hidden (Tab)");
  app.add_option("--record", o.record, "write the session's camera path (TUM) here at exit");
  app.add_option("--replay", o.replay, "play this camera path (TUM) in the window");
  app.add_option("--status_file", o.status_file,
                 "write the viewer's state (JSON) after each full-resolution frame");
  app.add_option("--max_seconds", o.max_seconds, "close the window after this long (0 = never)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--path", o.path, "render every pose of this TUM path to --out_dir (no window)");
  app.add_option("--out_dir", o.out_dir, "folder of the --path frames");
  app.add_option("--http", o.http,
                 "serve the view to browsers on HOST:PORT instead of a window (port 0 = free)");
  app.add_option("--port_file", o.port_file, "with --http: write the port here");
  app.add_option("--jpeg_quality", o.jpeg_quality, "with --http: JPEG quality of the frames")
      ->check(CLI::Range(1, 100));
  app.add_flag("--bench", o.bench, "frame-time benchmark (moving/still, adaptive on/off) -> JSON");
  app.add_option("--bench_frames", o.bench_frames, "moving frames per benchmark mode")
      ->check(CLI::Range(2, 10000));
  app.add_option("--bench_json", o.bench_json, "also write the benchmark JSON here");
  app.add_option("--bench_label", o.bench_label, "label of the benchmark run (e.g. the scene)");
  app.add_option("--moving_candidates", o.moving_candidates,
                 "references evaluated per pixel while the camera moves (0 = all, exact; frames "
                 "after it stops are always exact)")
      ->check(CLI::Range(0, 1024));
  app.add_option("--bench_modes", o.bench_modes,
                 "comma-separated benchmark modes (adaptive_budget,adaptive_fixed,full_always)");
  app.add_option("--control", o.control,
                 "control service for the drone overlays: HOST:PORT, 'none' (default: the "
                 "--server of a live model)");
  app.add_option("--drone_id", o.drone_id, "the drone shown (control service drone id)");
  app.add_flag("!--cells_by_refs", o.cells_by_tau,
               "colour cells by their reference count instead of the coverage τ (key 4)");
  app.add_option("--operator_id", o.operator_id,
                 "operator id of the drone commands (default window-PID)");
  app.add_option("--hand_m", o.hand_m,
                 "pick-and-place by drag: the mouse-hand's distance from the eye (m; 0 = at the "
                 "eye, guarded)")
      ->check(CLI::Range(0.0, 10.0));
  app.add_option("--xray_margin_m", o.xray_margin_m,
                 "X-ray: the cut-away plane this far behind the point under the cursor (m)")
      ->check(CLI::Range(0.0, 100.0));
  app.add_option("--xray_default_m", o.xray_default_m,
                 "X-ray: the plane's distance in front of the camera when no surface is under "
                 "the cursor (m)")
      ->check(CLI::Range(0.05, 1000.0));
  app.add_option("--xray_radius", o.xray_radius,
                 "X-ray: the hole's radius around the cursor, a fraction of the picture's height "
                 "(2 or more: the whole picture is cut)")
      ->check(CLI::Range(0.01, 10.0));
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  return exo::RunWindowApp(o);
}
