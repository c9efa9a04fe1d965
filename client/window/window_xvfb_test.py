#!/usr/bin/env python3
"""The viewer window under Xvfb with lavapipe, driven like a person would (issue 17).

Builds a small synthetic model (exoview_render --synthetic), starts exoview_window on it in a
virtual X display, injects keys with xdotool, takes screenshots with ImageMagick's `import -window
root` and checks that the view changed in the expected direction:
  - W (forward): the centre pixel's proxy depth decreased by the distance moved (same surface
    point along the optical axis), and the picture changed;
  - Right arrow: the camera turned right (the new forward has a positive component along the old
    right axis);
  - R: the pose is the nearest stored view's, and the screenshot equals an offline render of that
    pose (exoview_window --path, no window) within a PSNR floor (the presentation is exact);
  - the recorded session path (--record, TUM) renders offline and its last frame matches too;
  - Esc closes the window with exit code 0.
Skips (exit 0 with a clear message) where Xvfb, xdotool or ImageMagick is not installed.
With --docs_dir it also writes screenshots (with the HUD and overlays) there.
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
from PIL import Image

from xvfb_display import Display, missing_tools

W, H = 320, 240


def log(msg):
    print(f"[window_xvfb_test] {msg}", flush=True)


def fail(msg):
    log(f"FAIL: {msg}")
    sys.exit(1)


def psnr(a, b):
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10 * math.log10(255.0 ** 2 / mse)


def quat_rotate(q_wxyz, v):
    w, x, y, z = q_wxyz
    u = np.array([x, y, z])
    v = np.asarray(v, dtype=float)
    return v + 2 * np.cross(u, np.cross(u, v) + w * v)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--window_bin", required=True)
    ap.add_argument("--render_bin", required=True)
    ap.add_argument("--server_bin", default="")
    ap.add_argument("--uploader_bin", default="")
    ap.add_argument("--work_dir", default="")
    ap.add_argument("--docs_dir", default="")
    ap.add_argument("--timeout_s", type=float, default=90)
    args = ap.parse_args()
    missing = missing_tools()
    if missing:
        log(f"SKIPPED: {', '.join(missing)} not installed (apt-get install xvfb xdotool imagemagick)")
        return 0
    work = args.work_dir or tempfile.mkdtemp(prefix="window_xvfb_")
    os.makedirs(work, exist_ok=True)
    env = dict(os.environ, LP_NUM_THREADS="2", SDL_VIDEODRIVER="x11")
    model = os.path.join(work, "apt.exomodel")
    subprocess.run([args.render_bin, "--synthetic=apartment", "--synth_frames=24", "--store=10",
                    "--orbit=1", f"--width={W // 2}", f"--height={H // 2}",
                    f"--save_model={model}"], check=True, env=env, stdout=subprocess.DEVNULL)
    disp = Display(W, H)
    env["DISPLAY"] = disp.name
    status = os.path.join(work, "status.json")
    record = os.path.join(work, "session.tum")
    for stale in (status, record):  # a reused work dir must not answer for this run
        if os.path.exists(stale):
            os.remove(stale)
    win = subprocess.Popen([args.window_bin, f"--model={model}", f"--width={W}", f"--height={H}",
                            "--no_overlays", f"--status_file={status}", f"--record={record}",
                            "--max_seconds=120"], env=env,
                           stdout=open(os.path.join(work, "window_stdout.txt"), "w"))
    shot_n = [0]

    def xdo(*a):
        subprocess.run(["xdotool", *a], check=True, env=env)

    def shot(name):
        shot_n[0] += 1
        path = os.path.join(work, f"{shot_n[0]:02d}_{name}.png")
        subprocess.run(["import", "-window", "root", path], check=True, env=env)
        return path, np.asarray(Image.open(path).convert("RGB"))

    def wait_status(after_frame, what):
        t0 = time.time()
        while time.time() - t0 < args.timeout_s:
            if win.poll() is not None:
                fail(f"the window exited ({win.returncode}) while waiting for {what}")
            try:
                with open(status) as f:
                    s = json.load(f)
                if s["frame"] > after_frame and s["stage"] == 1:
                    time.sleep(0.3)  # the full-resolution frame is presented after the write
                    with open(status) as f:
                        s2 = json.load(f)
                    if s2["frame"] == s["frame"]:
                        return s
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(0.1)
        fail(f"no full-resolution frame for {what} within {args.timeout_s} s")

    try:
        s0 = wait_status(0, "the first frame")
        log(f"first frame: centre depth {s0['centre_depth_m']}, pose {s0['pose_local']}")
        xdo("mousemove", str(W // 2), str(H // 2))  # focus follows the pointer (no WM)
        _, img0 = shot("start")
        if img0.shape[:2] != (H, W):
            fail(f"screenshot is {img0.shape}, expected {H}x{W}")
        if img0.std() < 5:
            fail("the window shows a flat image")
        # ---- W: forward ----
        xdo("keydown", "w")
        time.sleep(0.4)
        xdo("keyup", "w")
        s1 = wait_status(s0["frame"], "moving forward")
        _, img1 = shot("forward")
        p0, p1 = np.array(s0["pose_local"]["t"]), np.array(s1["pose_local"]["t"])
        moved = float(np.linalg.norm(p1 - p0))
        d0, d1 = s0["centre_depth_m"], s1["centre_depth_m"]
        log(f"W: moved {moved:.3f} m, centre depth {d0:.3f} -> {d1:.3f} m, "
            f"PSNR to the start {psnr(img0, img1):.1f} dB")
        if not moved > 0.05:
            fail("W did not move the camera")
        fwd0 = quat_rotate(s0["pose_local"]["q_wxyz"], [0, 0, 1])
        if np.dot(p1 - p0, fwd0) < 0.99 * moved:
            fail("W moved the camera off its view direction")
        if not (d1 < d0 and abs((d0 - d1) - moved) < 0.02):
            fail(f"after W the centre depth should drop by {moved:.3f} m: {d0:.3f} -> {d1:.3f}")
        if psnr(img0, img1) > 30:
            fail("the picture did not change after W")
        # ---- Right arrow: turn right ----
        xdo("keydown", "Right")
        time.sleep(0.3)
        xdo("keyup", "Right")
        s2 = wait_status(s1["frame"], "turning right")
        right1 = quat_rotate(s1["pose_local"]["q_wxyz"], [1, 0, 0])
        fwd2 = quat_rotate(s2["pose_local"]["q_wxyz"], [0, 0, 1])
        log(f"Right: new forward . old right = {np.dot(fwd2, right1):.3f}")
        if not np.dot(fwd2, right1) > 0.05:
            fail("the Right arrow did not turn the camera right")
        # ---- R: reset to the nearest stored view ----
        xdo("key", "r")
        s3 = wait_status(s2["frame"], "R")
        _, img3 = shot("reset")
        if s3.get("nearest_view_distance_m", 1) > 1e-6:
            fail(f"after R the camera is {s3.get('nearest_view_distance_m')} m from a stored view")
        tum = os.path.join(work, "reset.tum")
        t, q = s3["pose_world"]["t"], s3["pose_world"]["q_wxyz"]
        with open(tum, "w") as f:
            f.write(f"0 {t[0]!r} {t[1]!r} {t[2]!r} {q[1]!r} {q[2]!r} {q[3]!r} {q[0]!r}\n")
        ref_dir = os.path.join(work, "reset_ref")
        subprocess.run([args.window_bin, f"--model={model}", f"--path={tum}", f"--out_dir={ref_dir}",
                        f"--width={W}", f"--height={H}"], check=True, env=env,
                       stdout=subprocess.DEVNULL)
        ref = np.asarray(Image.open(os.path.join(ref_dir, "frame_00000.png")).convert("RGB"))
        p_ref = psnr(img3, ref)
        log(f"R: view {s3.get('nearest_view')}, screenshot vs offline render {p_ref:.1f} dB")
        if p_ref < 40:
            fail(f"after R the screenshot differs from the render of that view ({p_ref:.1f} dB)")
        # ---- right click: picking at the centre pixel = the status's centre point ----
        xdo("mousemove", str(W // 2), str(H // 2))
        xdo("click", "3")
        time.sleep(1.0)
        picks = [json.loads(l) for l in open(os.path.join(work, "window_stdout.txt"))
                 if l.startswith('{"')]
        picks = [p for p in picks if "pick" in p]
        if not picks:
            fail("right click printed no pick")
        origin = np.array(s3["pose_world"]["t"]) - np.array(s3["pose_local"]["t"])
        centre_world = np.array(s3["centre_point_local"]) + origin
        err = float(np.linalg.norm(np.array(picks[-1]["pick"]) - centre_world))
        log(f"pick at pixel {picks[-1]['pixel']}: {err * 1000:.1f} mm from the centre point, "
            f"cell {picks[-1]['cell']}")
        if err > 0.05:
            fail("the picked point is not the point under the cursor")
        # ---- overlays for the docs, then Esc ----
        if args.docs_dir:
            os.makedirs(args.docs_dir, exist_ok=True)
            xdo("key", "Tab")
            time.sleep(1.0)
            path, _ = shot("overlays")
            shutil.copy(path, os.path.join(args.docs_dir, "window_overlays.png"))
            shutil.copy(os.path.join(work, "02_forward.png"),
                        os.path.join(args.docs_dir, "window_forward.png"))
        xdo("key", "Escape")
        rc = win.wait(timeout=30)
        if rc != 0:
            fail(f"the window exited with {rc} after Esc")
        # ---- the recorded path renders offline; its last pose is the reset view ----
        rec_dir = os.path.join(work, "replay")
        out = subprocess.run([args.window_bin, f"--model={model}", f"--path={record}",
                              f"--out_dir={rec_dir}", f"--width={W}", f"--height={H}"],
                             check=True, env=env, capture_output=True, text=True)
        n = json.loads(out.stdout)["frames"]
        last = np.asarray(Image.open(os.path.join(rec_dir, f"frame_{n - 1:05d}.png")).convert("RGB"))
        log(f"recorded path: {n} poses, last vs the R screenshot {psnr(last, img3):.1f} dB")
        if n < 4 or psnr(last, img3) < 40:
            fail("the recorded path does not end at the reset view")
        if args.server_bin and args.uploader_bin:
            live_part(args, env, work, shot)
        log("PASS")
        return 0
    finally:
        if win.poll() is None:
            win.kill()
        disp.close()


def live_part(args, env, work, shot):
    """Live subscription: the window follows a real server on loopback; when the server goes
    away mid-session the window keeps the last model on screen and says it is reconnecting."""
    port_file = os.path.join(work, "server.port")
    if os.path.exists(port_file):
        os.remove(port_file)
    checkpoint = os.path.join(work, "server.checkpoint")
    if os.path.exists(checkpoint):
        os.remove(checkpoint)
    server = subprocess.Popen([args.server_bin, "--listen=127.0.0.1:0", f"--port_file={port_file}",
                               "--log_level=warning", f"--checkpoint_path={checkpoint}",
                               "--checkpoint_interval_s=1"], env=env)
    win = None
    try:
        t0 = time.time()
        while not os.path.exists(port_file) or not open(port_file).read().strip():
            if time.time() - t0 > 30:
                fail("the server did not start")
            time.sleep(0.1)
        addr = "127.0.0.1:" + open(port_file).read().strip()
        subprocess.run([args.uploader_bin, f"--server={addr}", "--synthetic=apartment",
                        "--trajectory=walk", "--frames=20", f"--width={W}", f"--height={H}",
                        "--rate_hz=0"], check=True, env=env, stdout=subprocess.DEVNULL)
        status = os.path.join(work, "live_status.json")
        if os.path.exists(status):
            os.remove(status)
        saved = os.path.join(work, "live_saved.exomodel")
        win = subprocess.Popen([args.window_bin, f"--server={addr}", f"--width={W}", f"--height={H}",
                                "--no_overlays", f"--status_file={status}",
                                f"--save_model={saved}", "--max_seconds=120"], env=env)

        def read_status(pred, what):
            t1 = time.time()
            while time.time() - t1 < args.timeout_s:
                if win.poll() is not None:
                    fail(f"the live window exited ({win.returncode}) waiting for {what}")
                try:
                    with open(status) as f:
                        st = json.load(f)
                    if pred(st):
                        return st
                except (OSError, ValueError, KeyError):
                    pass
                time.sleep(0.1)
            fail(f"live: no status for {what} within {args.timeout_s} s")

        st = read_status(lambda s: s["views"] > 0 and s["sync"].startswith("live: subscribed")
                         and s["stage"] == 1, "the first live frame")
        log(f"live: {st['views']} views, model v{st['model_version']}, '{st['sync']}'")
        time.sleep(2.0)  # >= one checkpoint interval after the upload ended
        # The reference is the model the window holds when the server goes away (deltas such as
        # refreshed chunks may still have arrived during the wait above).
        st = read_status(lambda s: s["views"] > 0, "the model before the server goes away")
        _, before = shot("live")
        server.kill()
        server.wait(timeout=10)
        st2 = read_status(lambda s: "reconnecting" in s["sync"], "reconnecting")
        time.sleep(1.0)
        _, after = shot("live_server_gone")
        log(f"live, server gone: '{st2['sync']}', {st2['views']} views kept, "
            f"screen vs before {psnr(before, after):.1f} dB")
        if st2["views"] != st["views"] or st2["model_version"] != st["model_version"]:
            fail("the window lost its model when the server went away")
        if after.std() < 5 or psnr(before, after) < 40:
            fail("the window stopped showing the last model when the server went away")
        subprocess.run(["xdotool", "key", "Escape"], check=True, env=env)
        if win.wait(timeout=30) != 0:
            fail("the live window did not exit cleanly after Esc")
        if not os.path.exists(saved) or os.path.getsize(saved) < 1000:
            fail("the live window did not save its model on exit (--save_model)")
        log(f"live: saved the model on exit ({os.path.getsize(saved)} bytes)")
        # The server's checkpoint is readable too: rendered at the live view's pose, it shows
        # what the live window showed.
        tum = os.path.join(work, "live.tum")
        t, q = st["pose_world"]["t"], st["pose_world"]["q_wxyz"]
        with open(tum, "w") as f:
            f.write(f"0 {t[0]!r} {t[1]!r} {t[2]!r} {q[1]!r} {q[2]!r} {q[3]!r} {q[0]!r}\n")
        ck_dir = os.path.join(work, "checkpoint_render")
        subprocess.run([args.window_bin, f"--checkpoint={checkpoint}", f"--path={tum}",
                        f"--out_dir={ck_dir}", f"--width={W}", f"--height={H}"], check=True,
                       env=env, stdout=subprocess.DEVNULL)
        ck = np.asarray(Image.open(os.path.join(ck_dir, "frame_00000.png")).convert("RGB"))
        log(f"checkpoint rendered at the live pose vs the live screenshot: {psnr(ck, before):.1f} dB")
        if psnr(ck, before) < 35:
            fail("the server checkpoint does not show what the live window showed")
        # The model the window saved (views' colour as JPEG 90, as exoview_viewer saves) shows
        # the same at that pose.
        sv_dir = os.path.join(work, "saved_render")
        subprocess.run([args.window_bin, f"--model={saved}", f"--path={tum}",
                        f"--out_dir={sv_dir}", f"--width={W}", f"--height={H}"], check=True,
                       env=env, stdout=subprocess.DEVNULL)
        sv = np.asarray(Image.open(os.path.join(sv_dir, "frame_00000.png")).convert("RGB"))
        log(f"saved model rendered at the live pose vs the live screenshot: {psnr(sv, before):.1f} dB")
        if psnr(sv, before) < 30:
            fail("the model the window saved does not show what the live window showed")
    finally:
        if win is not None and win.poll() is None:
            win.kill()
        if server.poll() is None:
            server.kill()


if __name__ == "__main__":
    sys.exit(main())
