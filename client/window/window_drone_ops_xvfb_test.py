#!/usr/bin/env python3
"""Steering the drone from the viewer (issue 19, item 5), against a real server, under Xvfb.

A real exoview_server with the control service (the apartment's flight zone) on loopback, a walk
and a drone flight uploaded (30 + 60 frames), the uploader's simulated drone (--drone=sim), the
live window (exoview_window --server). Input is injected with xdotool:
  - gaze-to-see: ctrl + click on a surface -> the server's P_gaze is the point under the cursor
    (the window's own pick), the control state has the window's command, the drone flies there
    and its camera sees P_gaze in the central third of its image;
  - gaze at the sky (the camera above the model looking up): NOT_FOUND with the reason, shown,
    the drone's command unchanged;
  - pick-and-place: ctrl + drag from the drone: the preview target follows the cursor (the
    mouse is the hand, eq. 5.1), the server sets that target, the drone flies there;
  - two operators: a second operator (this test, over gRPC) and the window send in turn: the
    newest command wins (command sequence), the window's overlay shows the other's target;
  - joypad keys: I held -> the setpoint moves forward along the heading; U -> the yaw turns left;
  - X-ray: X with the cursor on a wall -> a hole around the cursor cut 0.3 m behind the wall:
    the centre pixel shows a surface farther than the plane (the interior behind the wall) and
    the picture changes there; outside the hole it equals the picture without X-ray (PSNR in a
    ring beyond the rim); the hole follows the cursor (moved away: the wall at the centre again);
  - the browser view (--http): the same gestures posted the way the page sends them: a click
    (gaze), a drag with the hand at the eye (the server's division guard: a finite target and
    the note), joypad keys, X-ray.
Skips (exit 0 with a clear message) where Xvfb, xdotool, ImageMagick or grpc_tools is missing.
With --docs_dir: screenshots for docs/.
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
import urllib.request

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
import window_drone_xvfb_test as base  # noqa: E402  (Display, control_stubs)
from local_procs import (fresh_port_file, scene_control_zones, start_server,  # noqa: E402
                         wait_port)

W, H = base.W, base.H
OPERATOR = "window-test"


def log(msg):
    print(f"[window_drone_ops_xvfb_test] {msg}", flush=True)


def fail(msg):
    log(f"FAIL: {msg}")
    sys.exit(1)


def v3(p):
    return np.array([p.x, p.y, p.z], dtype=float)


def drone_camera_sees(state, point, hfov_deg=65.0, width=160, height=120):
    """Pixel of `point` in the sim drone's camera (heading yaw about up, gimbal pitch; the
    uploader's 160x120, 65° camera) and whether it is within the central third."""
    up = v3(state.up)
    up = up / np.linalg.norm(up) if np.linalg.norm(up) > 0 else np.array([0, 0, 1.0])
    e1 = np.array([1.0, 0, 0]) - up[0] * up
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([0, 1.0, 0]) - up[1] * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    yaw, pitch = state.drone.yaw, state.drone.camera_pitch
    heading = math.cos(yaw) * e1 + math.sin(yaw) * e2
    fwd = math.cos(pitch) * heading + math.sin(pitch) * up
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    d = np.asarray(point) - v3(state.drone.position)
    z = d @ fwd
    if z <= 0:
        return None, False
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    u = f * (d @ right) / z + (width - 1) / 2
    v = f * (d @ down) / z + (height - 1) / 2
    return (u, v), (width / 3 <= u < 2 * width / 3) and (height / 3 <= v < 2 * height / 3)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--window_bin", required=True)
    ap.add_argument("--server_bin", required=True)
    ap.add_argument("--uploader_bin", required=True)
    ap.add_argument("--work_dir", default="")
    ap.add_argument("--docs_dir", default="")
    ap.add_argument("--timeout_s", type=float, default=90)
    args = ap.parse_args()
    missing = base.missing_tools()
    if missing:
        log(f"SKIPPED: {', '.join(missing)} not installed (apt-get install xvfb xdotool imagemagick)")
        return 0
    try:
        import grpc  # noqa: F401
        import grpc_tools  # noqa: F401
    except ImportError:
        log("SKIPPED: python3-grpcio / python3-grpc-tools not installed")
        return 0
    work = args.work_dir or tempfile.mkdtemp(prefix="window_drone_ops_")
    os.makedirs(work, exist_ok=True)
    env = dict(os.environ, LP_NUM_THREADS="2", SDL_VIDEODRIVER="x11")
    zones, uploader_log = scene_control_zones(args.uploader_bin, env)
    if not zones:
        fail(f"the uploader did not print the scene's control_zones: {uploader_log[-300:]}")
    server, port_file = start_server(args.server_bin, work, env,
                                     [f"--control_zones={zones}", "--control_cell_m=0.15"])
    drone = win = disp = None
    try:
        try:
            addr = "127.0.0.1:" + wait_port(server, port_file, 30, "the server")
        except RuntimeError as e:
            fail(str(e))
        drone = base.model_and_fly(args, env, work, addr, flight_s=240, camera_hz=2)
        import grpc
        pb, pb_grpc = base.control_stubs(work)
        stub = pb_grpc.ControlStub(grpc.insecure_channel(addr))

        def cstate():
            return stub.GetControlState(pb.ControlStateRequest(drone_id="drone"), timeout=10)

        disp = base.Display(W, H)
        env["DISPLAY"] = disp.name
        status = os.path.join(work, "status.json")
        if os.path.exists(status):
            os.remove(status)
        win = subprocess.Popen([args.window_bin, f"--server={addr}", f"--width={W}", f"--height={H}",
                                f"--status_file={status}", "--max_seconds=400",
                                f"--operator_id={OPERATOR}"], env=env, stdout=subprocess.DEVNULL)

        def read_status(pred, what, timeout=None, full=False, after=-1):
            t1 = time.time()
            while time.time() - t1 < (timeout or args.timeout_s):
                if win.poll() is not None:
                    fail(f"the window exited ({win.returncode}) waiting for {what}")
                try:
                    with open(status) as f:
                        st = json.load(f)
                    if (not full or st["stage"] == 1) and st["frame"] > after and pred(st):
                        return st
                except (OSError, ValueError, KeyError, TypeError):
                    pass
                time.sleep(0.2)
            fail(f"no status for {what} within {timeout or args.timeout_s} s")

        def ops(st):
            return st.get("drone_controls", {})

        def last(st, action):
            return ops(st).get("operator", {}).get("last_" + action)

        def xdo(*a):
            subprocess.run(["xdotool", *a], check=True, env=env)

        def shot(name):
            path = os.path.join(work, f"{name}.png")
            subprocess.run(["import", "-window", "root", path], check=True, env=env)
            return path, np.asarray(Image.open(path).convert("RGB"))

        def docs(path, name):
            if args.docs_dir:
                os.makedirs(args.docs_dir, exist_ok=True)
                shutil.copy(path, os.path.join(args.docs_dir, name))

        def wait_still(what, timeout=40):
            t1 = time.time()
            while time.time() - t1 < timeout:
                s = cstate()
                if s.drone_known and np.linalg.norm(v3(s.drone.velocity)) < 0.05:
                    return s
                time.sleep(0.2)
            fail(f"the drone did not come to rest ({what})")

        def wait_arrived(target, what, tol=0.1, timeout=45):
            t1 = time.time()
            while time.time() - t1 < timeout:
                s = cstate()
                if (np.linalg.norm(v3(s.drone.position) - target) < tol and
                        np.linalg.norm(v3(s.drone.velocity)) < 0.1):
                    return s, time.time() - t1
                time.sleep(0.2)
            s = cstate()
            fail(f"the drone did not reach {what}: at {v3(s.drone.position)}, target {target}")

        def seq_of(st, action):
            r = last(st, action)
            return r["operator_sequence"] if r else 0

        st = read_status(lambda s: s["views"] >= 1 and "drone 'drone'" in s.get("control", ""),
                         "a live model and the drone", full=True)
        log(f"live: {st['views']} views, {st['cells']} cells; {st['control']}")
        wait_still("at start")

        def chase():
            """Key G: the window looks at the drone from behind; a fresh full frame."""
            before = read_status(lambda s: True, "a status").get("frame", -1)
            xdo("mousemove", str(W // 2), str(H // 2))
            xdo("key", "g")
            return read_status(lambda s: s["overlay"].get("drone_px") is not None, "the chase view",
                               full=True, after=before)

        # ---- gaze-to-see: ctrl + click on a surface ----
        st = chase()
        gaze = None
        for px, py in ((W // 2, H // 2), (W // 2, H // 3), (W // 3, H // 2), (2 * W // 3, H // 2)):
            n0 = seq_of(st, "gaze")
            xdo("mousemove", str(px), str(py))
            xdo("keydown", "ctrl", "click", "1", "keyup", "ctrl")
            st = read_status(lambda s: seq_of(s, "gaze") > n0, "the gaze reply", timeout=20)
            gaze, gesture = last(st, "gaze"), ops(st)["last_gesture"]
            log(f"gaze click at ({px}, {py}): {gaze['summary']}; the window's pick "
                f"{gesture.get('local_hit')}")
            if gaze["ok"] and gesture.get("local_hit"):
                break
        if not gaze["ok"]:
            fail(f"no gaze-to-see click got a target: {gaze}")
        if args.docs_dir:  # the route while the drone flies it
            time.sleep(0.7)
            docs(shot("gaze")[0], "window_drone_gaze.png")
        if gesture["px"] != [px, py]:
            fail(f"the click was not at the pixel clicked: {gesture['px']}")
        err = np.linalg.norm(np.array(gaze["gaze_point"]) - np.array(gesture["local_hit"]))
        log(f"P_gaze {np.round(gaze['gaze_point'], 3)} vs the point under the cursor: {err * 100:.1f} cm "
            f"(GazeToSee round trip {gaze['rtt_ms']:.1f} ms)")
        if err > 0.10:
            fail("the server's P_gaze is not the surface point under the cursor")
        cs = cstate()
        if (cs.interaction != pb.GAZE_TO_SEE or cs.operator_id != OPERATOR or
                cs.command_sequence != gaze["command_sequence"]):
            fail(f"the control state is not the window's gaze command: {cs.interaction} "
                 f"{cs.operator_id} {cs.command_sequence}")
        target = v3(cs.target)
        if np.linalg.norm(target - np.array(gaze["target"])) > 1e-6:
            fail("the control state's target is not the reply's")
        cs, fly_s = wait_arrived(target, "the gaze target")
        uv, central = drone_camera_sees(cs, gaze["gaze_point"])
        log(f"the drone arrived in {fly_s:.1f} s, {len(gaze['waypoints'])} waypoints "
            f"(clamped {gaze['clamped']}); P_gaze at drone-camera pixel "
            f"{None if uv is None else tuple(round(x, 1) for x in uv)} of 160x120: "
            f"central third {central}")
        if not central:
            fail("after gaze-to-see the drone's camera does not see P_gaze in the central third")
        st = read_status(lambda s: s["overlay"].get("target") is not None and np.linalg.norm(
            np.array(s["overlay"]["target"]) - target) < 1e-6, "the target in the window's overlay")

        # ---- gaze at the sky: above the model, looking up ----
        before_seq = cstate().command_sequence
        xdo("keydown", "e")
        time.sleep(3.0)
        xdo("keyup", "e")
        xdo("keydown", "Up")
        time.sleep(2.0)
        xdo("keyup", "Up")
        st = read_status(lambda s: s["centre_depth_m"] is None, "no surface under the centre",
                         full=True)
        n0 = seq_of(st, "gaze")
        xdo("mousemove", str(W // 2), str(H // 2))
        xdo("keydown", "ctrl", "click", "1", "keyup", "ctrl")
        st = read_status(lambda s: seq_of(s, "gaze") > n0, "the sky gaze's reply", timeout=20)
        sky = last(st, "gaze")
        log(f"gaze at the sky: {sky['summary']} (the window's pick: "
            f"{ops(st)['last_gesture'].get('local_hit')})")
        if sky["ok"] or sky["code"] != "NOT_FOUND" or "no modelled surface" not in sky["message"]:
            fail("a gaze at the sky is not a clear NOT_FOUND")
        if cstate().command_sequence != before_seq:
            fail("a gaze at the sky changed the drone's command")

        # ---- pick-and-place: ctrl + drag from the drone ----
        wait_still("before the drag")
        st = chase()
        time.sleep(0.3)
        st = read_status(lambda s: s["overlay"].get("drone_px") is not None, "the drone on screen")
        dx, dy = st["overlay"]["drone_px"]
        ex, ey = dx + 110, dy - 30
        n0 = seq_of(st, "pick")
        xdo("mousemove", str(round(dx)), str(round(dy)))
        xdo("keydown", "ctrl", "mousedown", "1")
        for k in range(1, 6):
            xdo("mousemove", str(round(dx + (ex - dx) * k / 5)), str(round(dy + (ey - dy) * k / 5)))
            time.sleep(0.1)
        st = read_status(lambda s: ops(s).get("dragging") and s["overlay"].get("drag_preview_px"),
                         "the drag's preview", timeout=20)
        time.sleep(0.4)
        st = read_status(lambda s: ops(s).get("dragging") and s["overlay"].get("drag_preview_px"),
                         "the drag's preview", timeout=20)
        pvx, pvy = st["overlay"]["drag_preview_px"]
        path_drag, _ = shot("drag")
        docs(path_drag, "window_drone_drag.png")
        xdo("mouseup", "1", "keyup", "ctrl")
        log(f"drag from the drone at ({dx:.0f}, {dy:.0f}) to ({round(ex)}, {round(ey)}): preview "
            f"target drawn at ({pvx:.1f}, {pvy:.1f})")
        if math.hypot(pvx - 0.5 - round(ex), pvy - 0.5 - round(ey)) > 3:
            fail("the pick-and-place preview does not follow the cursor (the mouse as the hand)")
        st = read_status(lambda s: seq_of(s, "pick") > n0, "the pick-and-place reply", timeout=20)
        pick, gesture = last(st, "pick"), ops(st)["last_gesture"]
        log(f"pick-and-place: {pick['summary']}; scale {gesture['preview_scale']:.2f} "
            f"(|drone - eye| / |hand - eye| with the hand {gesture['hand0_m']} m from the eye)")
        if not pick["ok"]:
            fail("the pick-and-place was refused")
        off = np.linalg.norm(np.array(pick["target"]) - np.array(gesture["preview_target"]))
        log(f"server target vs the window's preview: {off * 100:.1f} cm (clamped {pick['clamped']}; "
            f"PickAndPlace round trip {pick['rtt_ms']:.1f} ms)")
        if not pick["clamped"] and off > 0.05:
            fail("the server's pick-and-place target is not eq. (5.1) of the drag")
        cs = cstate()
        if cs.interaction != pb.PICK_AND_PLACE or cs.operator_id != OPERATOR:
            fail("the control state is not the window's pick-and-place")
        moved = np.linalg.norm(v3(cs.target) - np.array(gesture["drone"]))
        if moved < 0.1:
            fail(f"the drag did not move the target ({moved:.3f} m)")
        cs, fly_s = wait_arrived(v3(cs.target), "the placed target", tol=0.12)
        log(f"the drone was placed {moved:.2f} m away in {fly_s:.1f} s")

        # ---- two operators: last writer wins, both see the outcome ----
        other_seq = int(time.time() * 1e6)
        p0, yaw0 = v3(cs.drone.position), cs.drone.yaw
        other = None
        for k in range(8):
            a = yaw0 + math.pi + k * math.pi / 4
            try:
                other = stub.GazeToSee(pb.GazeToSeeRequest(
                    header=pb.OperatorHeader(operator_id="other-operator",
                                             operator_sequence=other_seq + k, drone_id="drone"),
                    eye=pb.Vec3(x=p0[0], y=p0[1], z=p0[2]),
                    direction=pb.Vec3(x=math.cos(a), y=math.sin(a), z=-0.1)), timeout=10)
                break
            except grpc.RpcError as e:
                log(f"other operator's gaze {k}: {e.code().name}")
        if other is None:
            fail("the second operator's gaze found no target")
        cs = cstate()
        if cs.operator_id != "other-operator" or cs.command_sequence != other.command_sequence:
            fail("the second operator's newer command did not win")
        if other.command_sequence <= pick["command_sequence"]:
            fail("command sequences do not increase across operators")
        st = read_status(lambda s: s["overlay"].get("target") is not None and np.linalg.norm(
            np.array(s["overlay"]["target"]) - v3(other.target)) < 1e-6,
            "the other operator's target in the window")
        log(f"two operators: the window's #{pick['command_sequence']}, then the other's "
            f"#{other.command_sequence} wins; the window's overlay shows its target")

        # ---- joypad keys: I forward, U turn left ----
        # Where the earlier steps left the drone, a zone border or a wall may block both I and K
        # (the clamp then slides or stops the setpoint and says "boundary"); the drone is turned
        # by ~90 degrees with U and the pair tried again, up to four headings.
        def heading_of(cs):
            up = v3(cs.up) / np.linalg.norm(v3(cs.up))
            e1 = np.array([1.0, 0, 0]) - up[0] * up
            e1 /= np.linalg.norm(e1)
            return math.cos(cs.drone.yaw) * e1 + math.sin(cs.drone.yaw) * np.cross(up, e1)

        cs_held = None
        moved = False
        for turn in range(4):
            cs = wait_still("before the joypad", timeout=60)
            p0 = v3(cs.drone.position)
            heading = heading_of(cs)
            for key, sign in (("i", 1.0), ("k", -1.0)):  # forward; back when a wall is ahead
                st = read_status(lambda s: True, "a status")
                n0 = seq_of(st, "joypad")
                xdo("keydown", key)
                time.sleep(1.0)
                cs_held = cstate()
                xdo("keyup", key)
                st = read_status(lambda s: seq_of(s, "joypad") > n0, "joypad replies", timeout=20)
                ahead = float((v3(cs_held.target) - p0) @ heading)
                side = float(np.linalg.norm((v3(cs_held.target) - p0) - ahead * heading))
                log(f"{key.upper()} held 1 s: {ops(st)['operator']['joypad_sent']} joypad commands "
                    f"so far, setpoint {ahead:.2f} m along the heading ({side:.2f} m off it); "
                    f"{last(st, 'joypad')['summary']}")
                if cs_held.interaction != pb.JOYPAD or cs_held.operator_id != OPERATOR:
                    fail(f"holding {key.upper()} did not give a joypad command")
                # 1 s of a key moves the setpoint ~1 m in open space; next to a zone border or a
                # wall the clamp shortens it (seen: 0.22-0.32 m), so 0.2 m the right way is enough.
                if sign * ahead >= 0.2 and side <= 0.2:
                    moved = True
                    break
                if "boundary" not in last(st, "joypad")["summary"]:
                    fail(f"holding {key.upper()} did not move the setpoint along the heading")
                cs = wait_still("after a blocked joypad", timeout=30)
                p0 = v3(cs.drone.position)
            if moved:
                break
            log("both I and K blocked at this heading: turning ~90 degrees with U")
            xdo("keydown", "u")
            time.sleep(1.5)
            xdo("keyup", "u")
        if not moved:
            fail("neither I nor K moved the setpoint along the heading at four headings")
        wait_still("after I", timeout=30)
        xdo("keydown", "u")
        time.sleep(0.8)
        cs_u = cstate()
        xdo("keyup", "u")
        turned = math.remainder(cs_u.target_yaw - cs_held.target_yaw, 2 * math.pi)
        log(f"U held 0.8 s: the yaw setpoint turned {math.degrees(turned):.0f}° (left = +)")
        if turned < 0.3:
            fail("holding U did not turn the yaw setpoint left")

        xdo("key", "Escape")
        if win.wait(timeout=30) != 0:
            fail("the window did not exit cleanly after Esc")
        win = None

        browser_part(args, env, work, addr, pb, cstate)
        # ---- X-ray: a window at a known pose facing an inner wall, X with the cursor on it ----
        # The sim drone stops first: the pictures with and without the hole are compared
        # outside it, so the model must not change between them.
        drone.terminate()
        drone.wait(timeout=30)
        time.sleep(1.0)
        for pose in XRAY_POSES:
            if xray_part(args, env, work, addr, pose, docs):
                break
        else:
            fail("X-ray: no pose showed a modelled interior behind the wall")
        log("PASS")
        return 0
    finally:
        for p in (win, drone, server):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(timeout=10)
        if disp is not None:
            disp.close()


# Camera poses (world = the apartment's scene frame, z up) facing an inner wall with a room
# behind it: from the east part towards the wall x = 7 (the living room behind), from the living
# room towards it (the east part behind), from the bedroom towards the wall y = 5.
XRAY_POSES = [((9.5, 3.5, 1.4), (-1, 0, 0)), ((3.5, 3.5, 1.4), (1, 0, 0)),
              ((5.0, 7.0, 1.4), (0, -1, 0))]


def look_quat(fwd):
    """q (x, y, z, w) of a camera (x right, y down, z forward) looking along `fwd`, z up."""
    z = np.asarray(fwd, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.stack([x, y, z], axis=1)
    w = math.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    if w > 1e-6:
        return ((m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w),
                (m[1, 0] - m[0, 1]) / (4 * w), w)
    # 180° turns: from the largest diagonal element.
    i = int(np.argmax(np.diag(m)))
    j, k = (i + 1) % 3, (i + 2) % 3
    r = math.sqrt(max(0.0, 1 + m[i, i] - m[j, j] - m[k, k]))
    q = [0.0, 0.0, 0.0]
    q[i] = r / 2
    q[j] = (m[j, i] + m[i, j]) / (2 * r)
    q[k] = (m[k, i] + m[i, k]) / (2 * r)
    return (q[0], q[1], q[2], (m[k, j] - m[j, k]) / (2 * r))


def xray_part(args, env, work, addr, pose, docs):
    """X with the cursor on the wall: the cut-away plane 0.3 m behind it; the centre pixel then
    shows a surface beyond the plane (the modelled interior), the picture changes there; ]
    moves the plane; X again: the wall. False when nothing is modelled behind this wall."""
    (px, py, pz), fwd = pose
    qx, qy, qz, qw = look_quat(fwd)
    path = os.path.join(work, "xray_pose.txt")
    with open(path, "w") as f:
        f.write(f"0 {px} {py} {pz} {qx} {qy} {qz} {qw}\n")
    status = os.path.join(work, "xray_status.json")
    if os.path.exists(status):
        os.remove(status)
    win = subprocess.Popen([args.window_bin, f"--server={addr}", f"--width={W}", f"--height={H}",
                            f"--status_file={status}", "--max_seconds=200", f"--replay={path}",
                            "--control=none"], env=env, stdout=subprocess.DEVNULL)
    try:
        def read_status(pred, what, after=-1):
            t1 = time.time()
            while time.time() - t1 < args.timeout_s:
                if win.poll() is not None:
                    fail(f"the X-ray window exited ({win.returncode}) waiting for {what}")
                try:
                    with open(status) as f:
                        st = json.load(f)
                    if st["stage"] == 1 and st["frame"] > after and pred(st):
                        return st
                except (OSError, ValueError, KeyError, TypeError):
                    pass
                time.sleep(0.2)
            fail(f"X-ray: no status for {what} within {args.timeout_s} s")

        def xdo(*a):
            subprocess.run(["xdotool", *a], check=True, env=env)

        def shot(name):
            p = os.path.join(work, f"{name}.png")
            subprocess.run(["import", "-window", "root", p], check=True, env=env)
            return p, np.asarray(Image.open(p).convert("RGB"))

        def xr(st):
            return st.get("drone_controls", {})

        at = np.array([px, py, pz])
        st = read_status(lambda s: np.linalg.norm(np.array(s["pose_world"]["t"]) - at) < 1e-6,
                         "the replayed pose")
        d0 = st["centre_depth_m"]
        if d0 is None:
            log(f"X-ray at {pose}: no surface under the centre")
            return False
        def settled_shot(name, pred, what):
            """A screenshot of a finished full-resolution frame (no newer frame since)."""
            for _ in range(10):
                s1 = read_status(pred, what)
                time.sleep(0.3)
                p, img = shot(name)
                s2 = read_status(pred, what)
                if s2["frame"] == s1["frame"]:
                    return s2, p, img
            fail(f"X-ray: the picture did not settle ({what})")

        xdo("mousemove", str(W // 2), str(H // 2))
        st, p_off, img_off = settled_shot("xray_off", lambda s: not xr(s).get("xray"), "no X-ray")
        xdo("key", "x")
        st = read_status(lambda s: xr(s).get("xray"), "X-ray on", after=st["frame"])
        # The frame with the hole (its centre pick); a wall with nothing behind keeps d0.
        t_hole = time.time()
        while time.time() - t_hole < 5:
            st = read_status(lambda s: xr(s).get("xray"), "X-ray on", after=st["frame"] - 1)
            if st["centre_depth_m"] is None or abs(st["centre_depth_m"] - d0) > 0.05:
                break
            time.sleep(0.3)
        clip, d1 = xr(st)["xray_clip_m"], st["centre_depth_m"]
        hc, hr = xr(st)["xray_centre"], xr(st)["xray_radius"]
        log(f"X-ray at {pose}: wall at {d0:.2f} m, a hole of radius {hr * H:.0f} px around the "
            f"cursor ({hc[0] * W:.1f}, {hc[1] * H:.1f}) px cut at {clip:.2f} m; the centre now "
            f"shows {'nothing' if d1 is None else f'a surface at {d1:.2f} m'}")
        if abs(clip - (d0 + 0.3)) > 0.02:
            fail("the cut-away plane is not 0.3 m behind the point under the cursor")
        if abs(hc[0] * W - (W // 2 + 0.5)) > 1 or abs(hc[1] * H - (H // 2 + 0.5)) > 1:
            fail("the X-ray hole is not around the cursor")
        if d1 is None or d1 <= clip:
            xdo("key", "Escape")
            win.wait(timeout=30)
            return False
        st, p_on, img_on = settled_shot("xray_on", lambda s: xr(s).get("xray"), "X-ray on")
        c = img_on[H // 2 - 20:H // 2 + 20, W // 2 - 20:W // 2 + 20].astype(int)
        c0 = img_off[H // 2 - 20:H // 2 + 20, W // 2 - 20:W // 2 + 20].astype(int)
        changed = float((np.abs(c - c0).max(axis=2) > 30).mean())
        log(f"X-ray: {changed * 100:.0f} % of the 40x40 px around the cursor changed")
        if changed < 0.2:
            fail("the X-ray picture did not change inside the hole")
        # Outside the hole the picture is the normal one: a ring 25..110 px beyond the rim (the
        # rim is drawn), below the HUD (its text and width change with X-ray: y < 220).
        yy, xx = np.mgrid[0:H, 0:W]
        dist = np.hypot(xx + 0.5 - hc[0] * W, yy + 0.5 - hc[1] * H)
        ring = (dist > hr * H + 25) & (dist < hr * H + 110) & (yy >= 220)
        diff = img_on.astype(float) - img_off.astype(float)
        mse = float((diff[ring] ** 2).mean())
        psnr = float("inf") if mse == 0 else 10 * math.log10(255.0 ** 2 / mse)
        off_px = float((np.abs(diff[ring]).max(axis=1) > 8).mean())
        log(f"X-ray: outside the hole (ring of {int(ring.sum())} px) PSNR {psnr:.1f} dB against "
            f"the picture without X-ray, {off_px * 100:.2f} % of its pixels differ by > 8")
        if psnr < 40 or off_px > 0.005:
            fail("the X-ray changed the picture outside the hole")
        docs(p_off, "window_xray_off.png")
        docs(p_on, "window_xray_on.png")
        # The hole follows the cursor: 300 px to the right, the centre shows the wall again.
        xdo("mousemove", str(W // 2 + 300), str(H // 2))
        st = read_status(lambda s: abs(xr(s)["xray_centre"][0] * W - (W // 2 + 300.5)) < 1 and
                         s["centre_depth_m"] is not None and abs(s["centre_depth_m"] - d0) < 0.02,
                         "the hole moved with the cursor, the wall at the centre", after=st["frame"])
        st, p_moved, img_moved = settled_shot("xray_moved", lambda s: xr(s).get("xray"),
                                              "the hole moved")
        docs(p_moved, "window_xray_moved.png")
        c1 = img_moved[H // 2 - 20:H // 2 + 20, W // 2 - 20:W // 2 + 20].astype(int)
        back = float((np.abs(c1 - c0).max(axis=2) > 8).mean())
        log(f"X-ray: the cursor 300 px right: the centre depth {st['centre_depth_m']:.2f} m (the "
            f"wall), {back * 100:.1f} % of the 40x40 px around the centre differ from no X-ray")
        if back > 0.02:
            fail("the picture at the centre is not the normal one after the hole moved away")
        xdo("key", "bracketright")
        st = read_status(lambda s: abs((xr(s).get("xray_clip_m") or 0) - (clip + 0.25)) < 1e-6,
                         "] moves the plane 0.25 m farther")
        xdo("key", "x")
        st = read_status(lambda s: not xr(s).get("xray") and s["centre_depth_m"] is not None and
                         abs(s["centre_depth_m"] - d0) < 0.02, "X-ray off: the wall again",
                         after=st["frame"])
        xdo("key", "Escape")
        if win.wait(timeout=30) != 0:
            fail("the X-ray window did not exit cleanly after Esc")
        return True
    finally:
        if win.poll() is None:
            win.kill()
            win.wait(timeout=10)


def browser_part(args, env, work, addr, pb, cstate):
    """--http: the page's requests (POST /input) for a click, a drag with the hand at the eye,
    joypad keys and X-ray; the outcome in /status and the control state."""
    port_file = fresh_port_file(work, "http")
    view = subprocess.Popen([args.window_bin, f"--server={addr}", "--http=127.0.0.1:0",
                             f"--port_file={port_file}", "--width=640", "--height=360",
                             "--max_seconds=200", "--operator_id=browser-test"], env=env,
                            stdout=subprocess.DEVNULL)
    try:
        try:
            base_url = "http://127.0.0.1:" + wait_port(view, port_file, 60, "the browser view")
        except RuntimeError as e:
            fail(str(e))

        def post(q):
            urllib.request.urlopen(urllib.request.Request(base_url + "/input?" + q, method="POST"),
                                   timeout=10)

        def status(pred, what, timeout=60):
            t1 = time.time()
            while time.time() - t1 < timeout:
                try:
                    s = json.loads(urllib.request.urlopen(base_url + "/status", timeout=10).read())
                    if pred(s):
                        return s
                except (OSError, ValueError, KeyError, TypeError):
                    pass
                time.sleep(0.2)
            fail(f"browser view: no /status with {what}")

        def last(s, action):
            return s.get("drone_controls", {}).get("operator", {}).get("last_" + action)

        post("key=g&down=1")
        ov = {}
        t0 = time.time()
        while time.time() - t0 < 60:
            ov = json.loads(urllib.request.urlopen(base_url + "/overlay.json", timeout=10).read())
            if ov.get("drone_px"):
                break
            time.sleep(0.3)
        if not ov.get("drone_px"):
            fail("browser view: the drone is not on the page after g")
        time.sleep(1.0)
        ov = json.loads(urllib.request.urlopen(base_url + "/overlay.json", timeout=10).read())
        # A click (gaze-to-see) at the page's centre pixel.
        post(f"gaze={ov['width'] / 2},{ov['height'] / 2}")
        s = status(lambda s: last(s, "gaze") is not None, "the gaze reply")
        g = last(s, "gaze")
        log(f"browser click: {g['summary']}")
        if g["ok"] and cstate().operator_id != "browser-test":
            fail("browser view: the click's gaze-to-see is not the drone's command")
        # A drag from the drone with the hand at the eye: the server's division guard.
        dx, dy = ov["drone_px"]
        post(f"pick={dx},{dy},{dx + 80},{dy}&hand0=0&hand1=0.05")
        s = status(lambda s: last(s, "pick") is not None, "the pick-and-place reply")
        p = last(s, "pick")
        gest = s["drone_controls"]["last_gesture"]
        log(f"browser drag, hand at the eye: {p['summary']}; the window's preview scale "
            f"{gest['preview_scale']:.1f} guarded {gest['preview_guarded']}")
        if not p["ok"] or "guarded" not in p["note"] or not gest["preview_guarded"]:
            fail("browser view: the hand at the eye is not guarded (note / preview)")
        if not all(math.isfinite(x) for x in p["target"]):
            fail("browser view: the guarded target is not finite")
        cs = cstate()
        if cs.interaction != pb.PICK_AND_PLACE or cs.operator_id != "browser-test":
            fail("browser view: the drag's pick-and-place is not the drone's command")
        # Joypad keys (held, refreshed like the page does) and X-ray.
        t0 = time.time()
        while time.time() - t0 < 1.0:
            post("key=l&down=1")
            time.sleep(0.2)
        post("key=l&down=0")
        s = status(lambda s: last(s, "joypad") is not None, "a joypad reply")
        cs = cstate()
        log(f"browser L held 1 s: {last(s, 'joypad')['summary']}; control state {cs.interaction}")
        if cs.interaction != pb.JOYPAD or cs.operator_id != "browser-test":
            fail("browser view: the joypad keys did not command the drone")
        # X with the pointer at (0.3, 0.5) of the picture (the page sends its last position):
        # the hole is around it; the pointer moves (xat, as the page sends it): the hole too.
        fw, fh = ov["width"], ov["height"]
        post(f"key=x&down=1&xat={0.3 * fw},{0.5 * fh}")
        s = status(lambda s: s.get("drone_controls", {}).get("xray"), "X-ray on")
        dc = s["drone_controls"]
        log(f"browser X: X-ray on, a hole at {dc['xray_centre']} of the picture, cut at "
            f"{dc['xray_clip_m']:.2f} m")
        if abs(dc["xray_centre"][0] - 0.3) > 1e-6 or abs(dc["xray_centre"][1] - 0.5) > 1e-6:
            fail("browser view: the X-ray hole is not around the page's pointer")
        post(f"xat={0.7 * fw},{0.25 * fh}")
        status(lambda s: abs(s["drone_controls"]["xray_centre"][0] - 0.7) < 1e-6 and
               abs(s["drone_controls"]["xray_centre"][1] - 0.25) < 1e-6,
               "the hole following the pointer")
        post("key=x&down=1")
        status(lambda s: not s.get("drone_controls", {}).get("xray"), "X-ray off")
        chromium_part(args, env, work, base_url, status, last, cstate)
    finally:
        if view.poll() is None:
            view.terminate()
            try:
                view.wait(timeout=20)
            except subprocess.TimeoutExpired:
                view.kill()


def chromium_part(args, env, work, base_url, status, last, cstate):
    """The page's own gestures in headless Chromium (DevTools Input events): ctrl + click on the
    picture sends a gaze at that pixel; ctrl + drag from the drone draws the preview line and
    sends a pick-and-place from the drone's pixel."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        log("chromium not installed: SKIPPED the page's gesture check")
        return
    import http_view_test as hv
    if not hv.have_websocket():
        return
    c = hv.Chromium(chromium, base_url + "/", work, env, "chromium-ops")
    try:
        page = None
        t0 = time.time()
        while time.time() - t0 < 90:
            v = c.dt.eval("JSON.stringify({seq: seq, ov: overlay, "
                          "r: document.getElementById('v').getBoundingClientRect()})")
            page = json.loads(v) if v else {}
            if page.get("seq", 0) > 0 and (page.get("ov") or {}).get("drone_px"):
                break
            time.sleep(0.3)
        else:
            fail("the page did not show the frames and the drone")
        ov, r = page["ov"], page["r"]
        k = min(r["width"] / ov["width"], r["height"] / ov["height"])
        ox = r["x"] + (r["width"] - k * ov["width"]) / 2
        oy = r["y"] + (r["height"] - k * ov["height"]) / 2

        def mouse(kind, fx, fy, buttons):
            c.dt.call("Input.dispatchMouseEvent", type=kind, x=ox + k * fx, y=oy + k * fy,
                      button="left", buttons=buttons, clickCount=1, modifiers=2)  # 2 = ctrl

        s0 = status(lambda s: True, "a status")
        n_gaze = (last(s0, "gaze") or {}).get("operator_sequence", 0)
        n_pick = (last(s0, "pick") or {}).get("operator_sequence", 0)
        cx, cy = ov["width"] / 2, ov["height"] / 4  # above the drone (below the centre)
        mouse("mousePressed", cx, cy, 1)
        mouse("mouseReleased", cx, cy, 0)
        s = status(lambda s: (last(s, "gaze") or {}).get("operator_sequence", 0) > n_gaze,
                   "the page's ctrl+click")
        g = s["drone_controls"]["last_gesture"]
        log(f"chromium ctrl+click at frame pixel ({cx:.0f}, {cy:.0f}): sent at {g['px']}; "
            f"{last(s, 'gaze')['summary']}")
        if g["gesture"] != "click" or math.hypot(g["px"][0] + 0.5 - cx, g["px"][1] + 0.5 - cy) > 2:
            fail("the page's click did not send a gaze at the clicked pixel")
        t1 = time.time()  # the drone flies to the gaze target: drag it once it rests there
        while time.time() - t1 < 40 and (time.time() - t1 < 1 or np.linalg.norm(
                v3(cstate().drone.velocity)) > 0.05):
            time.sleep(0.2)
        time.sleep(0.6)  # the page's overlay (5 Hz) has the drone where it rests
        ov = json.loads(c.dt.eval("JSON.stringify(overlay)"))
        dx, dy = ov["drone_px"]
        mouse("mousePressed", dx, dy, 1)
        for i in range(1, 5):
            mouse("mouseMoved", dx + 15 * i, dy - 5 * i, 1)
        drawn = c.dt.eval("press && onDrone && cursor ? 1 : 0")
        img = c.dt.screenshot()
        mouse("mouseReleased", dx + 60, dy - 20, 0)
        s = status(lambda s: (last(s, "pick") or {}).get("operator_sequence", 0) > n_pick,
                   "the page's ctrl+drag")
        g = s["drone_controls"]["last_gesture"]
        log(f"chromium ctrl+drag from the drone ({dx:.0f}, {dy:.0f}): sent from {g['px0']} to "
            f"{g['px1']}, preview line drawn {bool(drawn)}; {last(s, 'pick')['summary']}")
        if g["gesture"] != "drag" or math.hypot(g["px0"][0] + 0.5 - dx, g["px0"][1] + 0.5 - dy) > 2:
            fail("the page's drag did not send a pick-and-place from the drone")
        if not drawn:
            fail("the page did not draw the drag's preview")
        if args.docs_dir:
            Image.fromarray(img).save(os.path.join(args.docs_dir, "browser_drone_drag.png"))
    finally:
        c.close()


if __name__ == "__main__":
    sys.exit(main())
