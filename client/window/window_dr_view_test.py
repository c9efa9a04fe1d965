#!/usr/bin/env python3
"""The live DR view in the viewer's browser page (issue 18), against a real server.

A real exoview_server on loopback; the browser view of the viewer (exoview_window --server
--http) subscribes to it. dr_live_bench --target uploads the synthetic apartment's arc around its
removable chair to that server (320x240, paced), marks the chair through MarkRegion, and writes
every frame's input colour and the chair's pixels (--dump_dir). While it uploads, this test asks
the page's endpoint GET /dr.jpg (what the page's "DR view" toggle shows) like the page does and
checks that
  - the page carries the toggle (button, key V, /dr.jpg);
  - DR frames arrive, with X-Dr-Meta naming the uploaded frame's sequence;
  - in composited frames the chair's pixels differ from the raw uploaded frame (the chair is
    removed: mean |DR - input| there > 12 grey levels), while outside the chair (and a 6 px band
    around it) the DR frame is the raw frame up to JPEG noise (< 6 grey levels);
  - after the page stops asking, the viewer closes its subscription (the server's live_watchers
    counter goes back to 0), so the server composites only while someone looks.

The SDL/Vulkan window (exoview_window --server, under Xvfb; skipped with a message where Xvfb,
xdotool or ImageMagick is missing) runs beside the page on the same server: once its first
render is up the test presses V, takes screenshots while the upload runs and checks them the
same way against the raw uploaded frame whose sequence the window's status file names (the
chair removed: > 12 grey levels inside it; elsewhere the camera's frame, < 6); then Tab shows
the HUD line (saved as window_dr_view.png, and to --docs_dir), and V again returns to the
free-viewpoint render (the screenshot is the render again, not the DR picture, and the window's
subscription is closed: live_watchers 0 at the end covers it too).
"""
import argparse
import io
import threading
import json
import os
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

try:
    import numpy as np
    from PIL import Image
except ImportError:
    print("SKIPPED: python3-numpy / python3-pil not installed (apt-get install python3-numpy python3-pil)")
    sys.exit(0)


def log(msg):
    print(msg, flush=True)


def fail(msg):
    log("FAIL: " + msg)
    sys.exit(1)


def get(url, timeout=10):
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as e:
        return e.code, dict(e.headers), e.read()


def wait_port(path, proc, what, limit=60):
    t0 = time.time()
    while not (os.path.exists(path) and open(path).read().strip()):
        if proc.poll() is not None or time.time() - t0 > limit:
            fail(f"{what} did not start")
        time.sleep(0.1)
    return int(open(path).read())


def live_watchers(addr, stubs_dir):
    """The server's inpainting.live_watchers (GetStats over gRPC), or None without python3-grpc."""
    try:
        import grpc
        sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
        import exoview_stubs
        exoview_stubs.load(stubs_dir)
        import exoview_pb2 as pb
        import exoview_pb2_grpc as pbg
    except Exception as e:  # noqa: BLE001 (python3-grpc / grpc-tools missing)
        log(f"no python gRPC ({e}): SKIPPED the live_watchers check")
        return None
    with grpc.insecure_channel(addr) as ch:
        stats = pbg.ExoviewStub(ch).GetStats(pb.StatsRequest(), timeout=10)
    return stats.counters.get("inpainting.live_watchers")


def dr_scores(img, dump, s, hud=None):
    """(inside the chair, outside the chair and its band) mean |img - input_s|, or None."""
    from PIL import ImageFilter
    inp = os.path.join(dump, f"input_{s}.png")
    chair = os.path.join(dump, f"chair_{s}.png")
    if not (os.path.exists(inp) and os.path.exists(chair)):
        return None
    raw = np.asarray(Image.open(inp).convert("RGB")).astype(float)
    m = np.asarray(Image.open(chair).convert("L")) > 0
    if m.sum() < 200 or img.shape != raw.shape:
        return None
    band = np.asarray(Image.open(chair).convert("L").filter(ImageFilter.MaxFilter(13))) > 0
    keep = np.ones(m.shape, bool)
    if hud:  # the HUD panel covers the picture there
        x, y, w, h = (int(round(v)) for v in hud)
        keep[max(0, y):y + h + 1, max(0, x):x + w + 1] = False
    diff = np.abs(img.astype(float) - raw).mean(axis=2)
    return float(diff[m & keep].mean()), float(diff[~band & keep].mean())


class WindowDr:
    """The SDL window's live DR view (key V) under Xvfb, run on a thread beside the page."""

    def __init__(self, args, addr, work, env, dump, bench):
        from xvfb_display import Display
        self.work, self.dump, self.bench = work, dump, bench
        self.disp = Display(320, 240)
        self.env = dict(env, DISPLAY=self.disp.name, SDL_VIDEODRIVER="x11")
        self.status = os.path.join(work, "window_status.json")
        if os.path.exists(self.status):
            os.remove(self.status)
        self.proc = subprocess.Popen(
            [args.window_bin, f"--server={addr}", "--width=320", "--height=240", "--no_overlays",
             f"--status_file={self.status}", "--max_seconds=240"], env=self.env,
            stdout=subprocess.DEVNULL, stderr=open(f"{work}/sdl_window.log", "w"))
        self.docs_dir = args.docs_dir
        self.error, self.scored, self.log = None, [], []
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def xdo(self, *a):
        subprocess.run(["xdotool", *a], check=True, env=self.env)

    def shot(self, name):
        path = os.path.join(self.work, f"sdl_{name}.png")
        subprocess.run(["import", "-window", "root", path], check=True, env=self.env)
        return path, np.asarray(Image.open(path).convert("RGB"))

    def read(self):
        try:
            with open(self.status) as f:
                return json.load(f)
        except (OSError, ValueError):
            return None

    def wait(self, pred, what, limit=90):
        t0 = time.time()
        while time.time() - t0 < limit:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the window exited ({self.proc.returncode}) waiting for {what}")
            st = self.read()
            if st is not None and pred(st):
                return st
            time.sleep(0.1)
        raise RuntimeError(f"the window: no {what} within {limit} s")

    def run(self):
        try:
            self.steps()
        except Exception as e:  # noqa: BLE001 (reported by the main thread)
            self.error = f"{type(e).__name__}: {e}"

    def steps(self):
        st = self.wait(lambda s: s["stage"] == 1 and s["views"] > 0, "first render")
        time.sleep(0.3)
        self.xdo("mousemove", "160", "120")  # focus follows the pointer (no WM)
        _, render0 = self.shot("render_before")
        self.xdo("key", "v")
        self.wait(lambda s: s["dr_view"]["on"], "DR mode after V", 20)
        # Screenshots while the upload runs (and a few after it: the last frame stays on screen).
        t_end = None
        while len(self.scored) < 6:
            if self.bench.poll() is not None:
                t_end = t_end or time.time()
                if time.time() - t_end > 4:
                    break
            a = self.read()
            _, img = self.shot("dr")
            b = self.read()
            if not a or not b or not a["dr_view"]["composited"]:
                time.sleep(0.2)
                continue
            lo, hi = a["dr_view"]["shown_sequence"], b["dr_view"]["shown_sequence"]
            if lo == 0 or hi - lo > 4:
                continue
            # The frame on screen is one of lo..hi (it changed during the shot): the one that
            # matches the screenshot best outside the chair.
            cands = [(s, dr_scores(img, self.dump, s)) for s in range(lo, hi + 1)]
            cands = [(s, c) for s, c in cands if c is not None]
            if not cands:
                time.sleep(0.2)
                continue
            s, (inside, outside) = min(cands, key=lambda x: x[1][1])
            self.scored.append((s, inside, outside))
            self.last_dr, self.last_seq = img, s
            time.sleep(0.3)
        # The HUD line (Tab): the picture for the docs.
        self.xdo("key", "Tab")
        st = self.wait(lambda s: "dr_hud" in s["overlay"], "the DR HUD after Tab", 10)
        time.sleep(0.4)
        path, _ = self.shot("dr_hud")
        self.hud_line = st["dr_view"]["hud"]
        self.hud_seq = st["dr_view"]["shown_sequence"]
        raw = os.path.join(self.dump, f"input_{self.hud_seq}.png")
        sheet = Image.new("RGB", (650, 240), (255, 255, 255))
        if os.path.exists(raw):
            sheet.paste(Image.open(raw).convert("RGB"), (0, 0))
        sheet.paste(Image.open(path).convert("RGB"), (330, 0))
        sheet.save(os.path.join(self.work, "window_dr_view.png"))
        if self.docs_dir:
            os.makedirs(self.docs_dir, exist_ok=True)
            sheet.save(os.path.join(self.docs_dir, "window_dr_view.png"))
        self.xdo("key", "Tab")
        # V again: back to the free-viewpoint render, the subscription closed.
        f0 = self.read()["frame"]
        self.xdo("key", "v")
        st = self.wait(lambda s: not s["dr_view"]["on"] and s["dr_view"]["watch"] == "off",
                       "the render after V again", 20)
        try:
            self.wait(lambda s: s["frame"] > f0 and s["stage"] == 1, "a new render", 15)
        except RuntimeError:
            pass  # the model did not change: the last render is shown again
        time.sleep(0.5)
        _, self.render1 = self.shot("render_after")
        self.render0 = render0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--window_bin", required=True)
    ap.add_argument("--server_bin", required=True)
    ap.add_argument("--bench_bin", required=True)
    ap.add_argument("--work_dir", default="")
    ap.add_argument("--docs_dir", default="", help="also write window_dr_view.png here")
    args = ap.parse_args()
    work = args.work_dir or tempfile.mkdtemp(prefix="window_dr_")
    os.makedirs(work, exist_ok=True)
    env = dict(os.environ, LP_NUM_THREADS="2")
    for f in ("server.port", "http.port"):
        if os.path.exists(os.path.join(work, f)):
            os.remove(os.path.join(work, f))
    dump = os.path.join(work, "frames")
    procs = []
    win = None
    try:
        server = subprocess.Popen([args.server_bin, "--listen=127.0.0.1:0",
                                   f"--port_file={work}/server.port"], env=env,
                                  stdout=subprocess.DEVNULL, stderr=open(f"{work}/server.log", "w"))
        procs.append(server)
        addr = f"127.0.0.1:{wait_port(f'{work}/server.port', server, 'the server')}"
        view = subprocess.Popen([args.window_bin, f"--server={addr}", "--http=127.0.0.1:0",
                                 f"--port_file={work}/http.port", "--width=320", "--height=240",
                                 "--max_seconds=240"], env=env, stdout=subprocess.DEVNULL,
                                stderr=open(f"{work}/window.log", "w"))
        procs.append(view)
        bench = subprocess.Popen([args.bench_bin, f"--target={addr}", "--width=320", "--height=240",
                                  "--frames=150", "--before=8", "--rate_hz=15", "--watch=false",
                                  f"--dump_dir={dump}"], env=env, stdout=open(f"{work}/bench.json", "w"),
                                 stderr=open(f"{work}/bench.log", "w"))
        procs.append(bench)
        from xvfb_display import missing_tools
        missing = missing_tools()
        if missing:
            log(f"SKIPPED the SDL window's DR view: {', '.join(missing)} not installed "
                "(apt-get install xvfb xdotool imagemagick)")
        else:
            win = WindowDr(args, addr, work, env, dump, bench)
            procs.append(win.proc)
        base = f"http://127.0.0.1:{wait_port(f'{work}/http.port', view, 'the viewer', 90)}"
        st, _, page = get(base + "/")
        for needle in (b"/dr.jpg", b"DR view", b"KeyV"):
            if needle not in page:
                fail(f"the page has no live DR view toggle ({needle!r} missing)")
        # Ask for DR frames as the page does while its toggle is on, until the upload ends.
        seq, got, composited, scored = 0, 0, 0, []
        t0 = time.time()
        while time.time() - t0 < 150:
            st, hdr, body = get(f"{base}/dr.jpg?after={seq}", timeout=10)
            if st == 503:
                if bench.poll() is not None:
                    break
                time.sleep(0.2)
                continue
            if st != 200:
                fail(f"/dr.jpg answered {st}: {body[:200]!r}")
            seq = int(hdr["X-Frame-Seq"])
            meta = json.loads(hdr["X-Dr-Meta"])
            got += 1
            if meta["composited"]:
                composited += 1
                s = meta["sequence"]
                inp = os.path.join(dump, f"input_{s}.png")
                chair = os.path.join(dump, f"chair_{s}.png")
                if os.path.exists(inp) and os.path.exists(chair):
                    dr = np.asarray(Image.open(io.BytesIO(body)).convert("RGB")).astype(float)
                    raw = np.asarray(Image.open(inp).convert("RGB")).astype(float)
                    m = np.asarray(Image.open(chair).convert("L")) > 0
                    if m.sum() >= 200 and dr.shape == raw.shape:
                        # The band: the ROI is the chair dilated by the server's margins.
                        from PIL import ImageFilter
                        band = np.asarray(Image.open(chair).convert("L").filter(ImageFilter.MaxFilter(13))) > 0
                        diff = np.abs(dr - raw).mean(axis=2)
                        scored.append((s, float(diff[m].mean()), float(diff[~band].mean())))
            if bench.poll() is not None and composited >= 3:
                break
        bench.wait(timeout=120)
        if bench.returncode != 0:
            fail(f"dr_live_bench failed: {open(f'{work}/bench.log').read()[-800:]}")
        log(f"DR frames from the page: {got}, composited {composited}, scored {len(scored)}")
        for s, inside, outside in scored[:10]:
            log(f"  frame {s}: mean |DR - input| in the chair {inside:.1f}, outside {outside:.1f}")
        if got < 5:
            fail(f"only {got} DR frames reached the page")
        if len(scored) < 3:
            fail(f"only {len(scored)} composited DR frames with the chair in view")
        inside = float(np.median([x[1] for x in scored]))
        outside = float(np.median([x[2] for x in scored]))
        if not inside > 12.0:
            fail(f"the chair was not removed in the DR view: median |DR - input| there {inside:.1f}")
        if not outside < 6.0:
            fail(f"outside the chair the DR view is not the camera's frame: {outside:.1f}")
        if win is not None:
            win.thread.join(timeout=150)
            if win.thread.is_alive():
                fail("the SDL window's DR test did not finish")
            if win.error:
                fail(f"the SDL window's DR view: {win.error}")
            log(f"SDL window (key V): {len(win.scored)} DR screenshots scored")
            for s, i, o in win.scored:
                log(f"  frame {s}: mean |screen - input| in the chair {i:.1f}, outside {o:.1f}")
            if len(win.scored) < 2:
                fail(f"only {len(win.scored)} composited DR pictures seen in the window")
            w_in = float(np.median([x[1] for x in win.scored]))
            w_out = float(np.median([x[2] for x in win.scored]))
            if not w_in > 12.0:
                fail(f"the window's DR view did not remove the chair: {w_in:.1f}")
            if not w_out < 6.0:
                fail(f"outside the chair the window's DR view is not the camera's frame: {w_out:.1f}")
            log(f"window HUD: '{win.hud_line}'")
            if "frame seq" not in win.hud_line or "fps" not in win.hud_line:
                fail(f"the window's DR HUD line lacks seq/fps: {win.hud_line!r}")
            # V again: the render, not the DR picture.
            to_dr = float(np.abs(win.render1.astype(float) - win.last_dr).mean())
            to_render = float(np.abs(win.render1.astype(float) - win.render0).mean())
            log(f"after V again: mean |screen - render before V| {to_render:.1f}, "
                f"|screen - last DR picture| {to_dr:.1f}")
            if not (to_render < to_dr and to_dr > 8.0) or win.render1.std() < 5:
                fail("V again did not return the window to the free-viewpoint render")
            log(f"window median |DR - input|: chair {w_in:.1f}, elsewhere {w_out:.1f}")
        # Nobody asks any more: the viewer drops the subscription within its idle time (5 s).
        watchers = None
        t1 = time.time()
        while time.time() - t1 < 20:
            watchers = live_watchers(addr, os.path.join(work, "stubs"))
            if watchers is None or watchers == 0:
                break
            time.sleep(1)
        if watchers is not None and watchers != 0:
            fail(f"the viewer still watches the DR view 20 s after the page stopped ({watchers})")
        log(f"median |DR - input|: chair {inside:.1f}, elsewhere {outside:.1f}; live_watchers "
            f"after the page stopped: {watchers}")
        if win is not None:
            # The window's messages: V with the camera stopped (no frame comes), then the server
            # gone (unreachable); V again leaves the mode.
            win.xdo("key", "v")
            # (the server may still send the newest frame; then nothing for > 2 s)
            st = win.wait(lambda s: s["dr_view"]["on"] and "dr_hud" in s["overlay"] and any(
                m in s["dr_view"]["hud"] for m in ("no frame yet", "no new frame")),
                "the DR HUD's message with the camera stopped", 20)
            log(f"window, camera stopped: '{st['dr_view']['hud']}'")
            if "dr_hud" not in st["overlay"]:
                fail("the window shows no message panel with the camera stopped")
            server.terminate()
            server.wait(timeout=20)
            st = win.wait(lambda s: "unreachable" in s["dr_view"]["hud"] and "dr_hud" in s["overlay"],
                          "the 'unreachable' HUD", 30)
            log(f"window, server gone: '{st['dr_view']['hud'][:90]}...'")
            _, gone = win.shot("dr_server_gone")
            if "dr_hud" not in st["overlay"] or gone.std() < 1:
                fail("the window shows no message panel with the server gone")
            win.xdo("key", "v")
            win.wait(lambda s: not s["dr_view"]["on"], "DR off", 20)
        log("PASS")
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()
        if win is not None:
            win.disp.close()


if __name__ == "__main__":
    main()
