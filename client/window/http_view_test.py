#!/usr/bin/env python3
"""The browser view (exoview_window --http) against real clients (issue 17).

A small synthetic model is served on a free loopback port; the test then
  - loads the page, /status (JSON) and /metrics (Prometheus text) and checks their content;
  - takes a frame, sends the page's key messages (W held 0.5 s) and checks that the next frame
    differs and that the stats moved (frames, pose);
  - opens 20 MJPEG streams at once while the camera moves: every one gets several frames; one
    of them disconnects mid-stream and the others keep receiving;
  - with Debian's chromium installed: loads the page headless and checks, through its DevTools
    protocol, that the browser shows the stream (screenshot not blank) and the stats line (DOM),
    then presses W in the browser; skipped with a message otherwise;
  - with Debian's firefox-esr installed: the same in headless Firefox, driven over WebDriver
    BiDi (picture, stats, W held in the browser moves the camera, the page shows the newest
    frame); skipped with a message otherwise.
With --docs_dir the browser screenshot is also written there.
"""
import argparse
import base64
import io
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

import numpy as np
from PIL import Image


def log(msg):
    print(f"[http_view_test] {msg}", flush=True)


def fail(msg):
    log(f"FAIL: {msg}")
    sys.exit(1)


def get(url, method="GET", timeout=10):
    req = urllib.request.Request(url, method=method)
    with urllib.request.urlopen(req, timeout=timeout) as r:
        return r.status, dict(r.headers), r.read()


def psnr(a, b):
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10 * math.log10(255.0 ** 2 / mse)


def stream_reader(port, seconds, out, idx, drop_after=None):
    """Reads an MJPEG stream for `seconds`; out[idx] = frames received (drop_after: close early)."""
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    s.sendall(b"GET /stream HTTP/1.1\r\nHost: x\r\n\r\n")
    data = b""
    t0 = time.time()
    frames = 0
    try:
        while time.time() - t0 < seconds:
            try:
                chunk = s.recv(65536)
            except socket.timeout:
                continue
            if not chunk:
                break
            data += chunk
            frames = data.count(b"--exoviewframe\r\n")
            if drop_after is not None and frames >= drop_after:
                break
    finally:
        s.close()
    out[idx] = frames


class DevTools:
    """A minimal Chrome DevTools Protocol client over one page target's websocket (Debian's
    python3-websocket): send a method, wait for the reply with the same id (events skipped)."""

    def __init__(self, ws_url):
        import websocket  # python3-websocket
        self.ws = websocket.create_connection(ws_url, timeout=60, suppress_origin=True)
        self.next_id = 0

    def call(self, method, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == self.next_id:
                if "error" in msg:
                    fail(f"DevTools {method}: {msg['error']}")
                return msg.get("result", {})

    def eval(self, expr):
        r = self.call("Runtime.evaluate", expression=expr, returnByValue=True)
        return r.get("result", {}).get("value")

    def screenshot(self):
        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))

    def key(self, kind, code, key, vk):
        self.call("Input.dispatchKeyEvent", type=kind, code=code, key=key,
                  windowsVirtualKeyCode=vk, nativeVirtualKeyCode=vk)

    def close(self):
        self.ws.close()


class Chromium:
    """Headless Chromium on `url` with a DevTools port; `dt` drives its page (DevTools). The
    screenshot is taken through the protocol (Page.captureScreenshot): chromium's own
    --screenshot mode could come back blank under load (it shoots when a virtual time budget
    ends, whether or not a frame arrived), the protocol capture is taken when the page shows
    what the test waited for."""

    def __init__(self, chromium, url, work, env, name):
        self.profile = os.path.join(work, name)
        shutil.rmtree(self.profile, ignore_errors=True)
        os.makedirs(self.profile)
        self.browser = subprocess.Popen(
            [chromium, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
             "--window-size=800,660", "--remote-debugging-port=0",
             "--remote-debugging-address=127.0.0.1", f"--user-data-dir={self.profile}", url],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.dt = None
        port_file = os.path.join(self.profile, "DevToolsActivePort")
        t0 = time.time()
        while not (os.path.exists(port_file) and len(open(port_file).read().split()) >= 2):
            if self.browser.poll() is not None or time.time() - t0 > 60:
                self.close()
                fail("chromium did not open its DevTools port")
            time.sleep(0.2)
        dport = int(open(port_file).read().split()[0])
        base = url.split("/?")[0].rstrip("/")
        pages = []
        while time.time() - t0 < 60:
            targets = json.loads(get(f"http://127.0.0.1:{dport}/json/list")[2])
            pages = [t for t in targets if t.get("type") == "page" and t["url"].startswith(base)]
            if pages:
                break
            time.sleep(0.2)
        if not pages:
            self.close()
            fail("no DevTools page target for the viewer's page")
        self.dt = DevTools(pages[0]["webSocketDebuggerUrl"])
        self.dt.call("Page.enable")
        self.dt.call("Emulation.setFocusEmulationEnabled", enabled=True)

    def close(self):
        if self.dt is not None:
            self.dt.close()
        self.browser.terminate()
        try:
            self.browser.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.browser.kill()


def reset_camera(base):
    """R from the page's protocol: the camera back at its start pose. Waits (up to 10 s) for the
    viewer to render the reset pose, so that a settle after it cannot see the frame before."""
    frames = json.loads(get(base + "/status")[2])["frames"]
    get(base + "/input?key=r&down=1", method="POST")
    t0 = time.time()
    while time.time() - t0 < 10 and json.loads(get(base + "/status")[2])["frames"] == frames:
        time.sleep(0.1)


def have_websocket():
    try:
        import websocket  # noqa: F401  (python3-websocket)
        return True
    except ImportError:
        log("python3-websocket not installed: SKIPPED the browser parts "
            "(apt-get install python3-websocket)")
        return False


def first_look_part(chromium, base, work, env, docs_dir):
    """What a person opening the page sees: /?frames=3 (the page stops polling after 3 frames)
    shows a picture (not blank) and the stats line (in the DOM) once the frames arrived."""
    if not have_websocket():
        return
    c = Chromium(chromium, base + "/?frames=3", work, env, "chromium-first-look")
    try:
        t0 = time.time()
        st = {}
        while time.time() - t0 < 90:
            v = c.dt.eval("JSON.stringify({seq: seq, shown: document.getElementById('v')"
                          ".naturalWidth, dom: document.documentElement.outerHTML})")
            st = json.loads(v) if v else {}
            if st.get("seq", 0) >= 1 and st.get("shown", 0) > 0 and "views 10" in st["dom"]:
                break
            time.sleep(0.3)
        im = c.dt.screenshot()
        view = im[50:550, 100:700]
        dom = st.get("dom", "")
        log(f"chromium (DevTools): page seq {st.get('seq')}, screenshot {im.shape[1]}x{im.shape[0]}, "
            f"view area std {view.std():.1f}; stats in DOM: {'views 10' in dom}")
        if view.std() < 10:
            fail("the browser shows no picture")
        if "views 10" not in dom:
            fail("the browser's stats line did not update")
        if docs_dir:
            os.makedirs(docs_dir, exist_ok=True)
            Image.fromarray(im).save(os.path.join(docs_dir, "browser_first_look.png"))
    finally:
        c.close()


def devtools_part(chromium, base, work, env, docs_dir):
    """The page in headless Chromium driven through its DevTools protocol like a person: the key
    goes through the browser (Input.dispatchKeyEvent -> the page's onkeydown -> its HTTP input
    call), and what the browser shows is read back from it (screenshot, DOM)."""
    if not have_websocket():
        return
    c = Chromium(chromium, base + "/", work, env, "chromium-devtools-profile")
    dt = c.dt
    try:
        def page_state():
            """The page's frame sequence, picture width and stats line (zeros while loading)."""
            v = dt.eval("JSON.stringify({seq: seq, shown: document.getElementById('v')"
                        ".naturalWidth, stats: document.getElementById('s').textContent})")
            return v if v is not None else '{"seq": 0, "shown": 0, "stats": ""}'

        def wait_page(pred, what, timeout=90):
            t1 = time.time()
            while time.time() - t1 < timeout:
                st = json.loads(page_state())
                if pred(st):
                    return st
                time.sleep(0.3)
            fail(f"the browser page: no {what} within {timeout} s")

        def settled_page(what):
            """The page shows the viewer's newest full-resolution frame and nothing is coming."""
            t1 = time.time()
            while time.time() - t1 < 120:
                s = json.loads(get(base + "/status")[2])
                st = json.loads(page_state())
                if s.get("stage") == 1 and st["seq"] >= s["frames"] and st["shown"] > 0:
                    time.sleep(0.8)
                    s2 = json.loads(get(base + "/status")[2])
                    if s2["frames"] == s["frames"]:
                        return s, json.loads(page_state())
                time.sleep(0.3)
            fail(f"the browser page did not settle ({what})")

        wait_page(lambda s: s["seq"] > 0 and s["shown"] > 0 and "views 10" in s["stats"],
                  "frame and stats")
        def page_picture():
            """The pixels the page's <img> shows (drawn into a canvas in the page)."""
            for _ in range(50):  # between two frames the <img> may be decoding its new source
                url = dt.eval("(() => { const i = document.getElementById('v'); "
                              "if (!i.complete || !i.naturalWidth) return ''; "
                              "const c = document.createElement('canvas'); c.width = i.naturalWidth; "
                              "c.height = i.naturalHeight; c.getContext('2d').drawImage(i, 0, 0); "
                              "return c.toDataURL('image/png'); })()")
                if url and url.startswith("data:image/png;base64,"):
                    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1])))
                                      .convert("RGB"))
                time.sleep(0.1)
            fail("could not read the picture the page shows")

        def viewer_picture():
            body = get(base + "/frame.jpg?after=0", timeout=30)[2]
            return np.asarray(Image.open(io.BytesIO(body)).convert("RGB"))

        # From the start pose (R): the earlier parts moved and turned the camera, and a camera
        # walked out of the model shows the same empty picture before and after the key.
        reset_camera(base)
        s0, p0 = settled_page("before the key")
        img0 = dt.screenshot()
        shown0, sent0 = page_picture(), viewer_picture()
        # W held for 0.6 s in the browser (the page re-sends held keys every 200 ms).
        dt.key("keyDown", "KeyW", "w", 87)
        time.sleep(0.6)
        # A one-shot key (3: the cells overlay) is sent once per press, never re-sent as held
        # (the page re-sends held keys every 200 ms; a one-shot key in that set toggled again).
        dt.key("keyDown", "Digit3", "3", 51)
        held_now = dt.eval("JSON.stringify([held.has('w'), held.has('3')])")
        dt.key("keyUp", "Digit3", "3", 51)
        dt.key("keyDown", "Digit3", "3", 51)
        dt.key("keyUp", "Digit3", "3", 51)
        dt.key("keyUp", "KeyW", "w", 87)
        if json.loads(held_now) != [True, False]:
            fail(f"the page's held keys while W and 3 are down: {held_now} (3 is one-shot)")
        s1, p1 = settled_page("after W")
        img1 = dt.screenshot()
        shown1, sent1 = page_picture(), viewer_picture()
        moved = float(np.linalg.norm(np.array(s1["pose_local"]["t"]) -
                                     np.array(s0["pose_local"]["t"])))
        view0, view1 = img0[50:550, 100:700], img1[50:550, 100:700]
        log(f"DevTools: W pressed in the browser: viewer moved {moved:.3f} m, page frame seq "
            f"{p0['seq']} -> {p1['seq']}; the page's picture vs the viewer's frame: before "
            f"{psnr(shown0, sent0):.1f} dB, after {psnr(shown1, sent1):.1f} dB; page after vs "
            f"before {psnr(shown0, shown1):.1f} dB (screenshots {psnr(view0, view1):.1f} dB); "
            f"stats '{p0['stats'][:40]}...' -> '{p1['stats'][:40]}...'")
        if not moved > 0.05:
            fail("the key pressed in the browser did not move the viewer's camera")
        if p1["seq"] <= p0["seq"]:
            fail("the browser received no new frame after the key")
        if shown1.shape != sent1.shape or psnr(shown1, sent1) < 40 or psnr(shown0, sent0) < 40:
            fail("the page does not show the viewer's newest frame")
        if psnr(shown0, shown1) > 40 or view1.std() < 10:
            fail("the browser does not show a changed picture after the key")
        if p1["stats"] == p0["stats"] or f"frames {s1['frames']}" not in p1["stats"]:
            fail("the browser's stats line did not update after the key")
        if docs_dir:
            Image.fromarray(img1).save(os.path.join(docs_dir, "browser_view_after_w.png"))
    finally:
        c.close()


class Firefox:
    """Headless Firefox (Debian firefox-esr) on `url`, driven over WebDriver BiDi (its
    --remote-debugging-port websocket; python3-websocket): evaluate in the page, capture a
    screenshot, send input actions."""

    def __init__(self, firefox, url, work, env, name):
        import re
        import websocket  # python3-websocket
        self.profile = os.path.join(work, name)
        shutil.rmtree(self.profile, ignore_errors=True)
        os.makedirs(self.profile)
        self.proc = subprocess.Popen(
            [firefox, "--headless", "--remote-debugging-port=0", "--profile", self.profile,
             "--no-remote", "--width=800", "--height=660", "about:blank"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.ws = None
        ws_url = None
        t0 = time.time()
        while time.time() - t0 < 90 and self.proc.poll() is None:
            line = self.proc.stderr.readline()
            m = re.search(r"WebDriver BiDi listening on (ws://\S+)", line)
            if m:
                ws_url = m.group(1)
                break
        if ws_url is None:
            self.close()
            fail("firefox did not open its WebDriver BiDi port")
        threading.Thread(target=lambda: self.proc.stderr.read(), daemon=True).start()
        self.ws = websocket.create_connection(ws_url + "/session", timeout=90,
                                              suppress_origin=True)
        self.next_id = 0
        self.call("session.new", capabilities={})
        self.ctx = self.call("browsingContext.getTree")["contexts"][0]["context"]
        self.call("browsingContext.navigate", context=self.ctx, url=url, wait="complete")

    def call(self, method, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == self.next_id:
                if msg.get("type") == "error":
                    fail(f"BiDi {method}: {msg.get('error')}: {msg.get('message')}")
                return msg.get("result", {})

    def eval(self, expr):
        r = self.call("script.evaluate", expression=expr, target={"context": self.ctx},
                      awaitPromise=False)
        return r.get("result", {}).get("value")

    def screenshot(self):
        png = base64.b64decode(self.call("browsingContext.captureScreenshot",
                                         context=self.ctx)["data"])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))

    def hold_key(self, key, seconds):
        self.call("input.performActions", context=self.ctx, actions=[
            {"type": "key", "id": "keyboard", "actions": [
                {"type": "keyDown", "value": key},
                {"type": "pause", "duration": int(seconds * 1000)},
                {"type": "keyUp", "value": key}]}])

    def close(self):
        if self.ws is not None:
            try:
                self.call("session.end")
            except Exception:  # noqa: BLE001 (the browser may be gone already)
                pass
            self.ws.close()
        self.proc.terminate()
        try:
            self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def firefox_part(firefox, base, work, env, docs_dir):
    """The page in headless Firefox over WebDriver BiDi: it shows the stream and the stats, W
    held in the browser (its own key handler) moves the viewer's camera, and the page then shows
    the viewer's newest frame."""
    if not have_websocket():
        return
    ff = Firefox(firefox, base + "/", work, env, "firefox-profile")
    try:
        def page_state():
            v = ff.eval("JSON.stringify({seq: seq, shown: document.getElementById('v')"
                        ".naturalWidth, stats: document.getElementById('s').textContent})")
            return json.loads(v) if v else {"seq": 0, "shown": 0, "stats": ""}

        def page_picture():
            for _ in range(50):
                url = ff.eval("(() => { const i = document.getElementById('v'); "
                              "if (!i.complete || !i.naturalWidth) return ''; "
                              "const c = document.createElement('canvas'); c.width = i.naturalWidth; "
                              "c.height = i.naturalHeight; c.getContext('2d').drawImage(i, 0, 0); "
                              "return c.toDataURL('image/png'); })()")
                if url and url.startswith("data:image/png;base64,"):
                    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1])))
                                      .convert("RGB"))
                time.sleep(0.1)
            fail("firefox: could not read the picture the page shows")

        def settled(what):
            t1 = time.time()
            while time.time() - t1 < 120:
                s = json.loads(get(base + "/status")[2])
                st = page_state()
                if s.get("stage") == 1 and st["seq"] >= s["frames"] and st["shown"] > 0:
                    time.sleep(0.8)
                    s2 = json.loads(get(base + "/status")[2])
                    if s2["frames"] == s["frames"]:
                        return s, page_state()
                time.sleep(0.3)
            fail(f"firefox: the page did not settle ({what})")

        def viewer_picture():
            body = get(base + "/frame.jpg?after=0", timeout=30)[2]
            return np.asarray(Image.open(io.BytesIO(body)).convert("RGB"))

        # From the start pose (R), as in the DevTools part: two more metres forward from where
        # that part left the camera can leave the model (the same empty picture before and after).
        reset_camera(base)
        s0, p0 = settled("before the key")
        img0 = ff.screenshot()
        shown0, sent0 = page_picture(), viewer_picture()
        ff.hold_key("w", 0.6)
        s1, p1 = settled("after W")
        img1 = ff.screenshot()
        shown1, sent1 = page_picture(), viewer_picture()
        moved = float(np.linalg.norm(np.array(s1["pose_local"]["t"]) -
                                     np.array(s0["pose_local"]["t"])))
        view1 = img1[50:550, 100:700]
        log(f"Firefox (WebDriver BiDi): screenshot {img1.shape[1]}x{img1.shape[0]}, view area std "
            f"{view1.std():.1f}; W held in the browser: viewer moved {moved:.3f} m, page frame seq "
            f"{p0['seq']} -> {p1['seq']}; page picture vs the viewer's frame "
            f"{psnr(shown1, sent1):.1f} dB, after vs before {psnr(shown0, shown1):.1f} dB; stats "
            f"'{p1['stats'][:40]}...'")
        if "views 10" not in p0["stats"] or view1.std() < 10:
            fail("firefox does not show the picture and the stats line")
        if not moved > 0.05 or p1["seq"] <= p0["seq"]:
            fail("W held in firefox did not move the viewer's camera / bring new frames")
        if shown1.shape != sent1.shape or psnr(shown1, sent1) < 40 or psnr(shown0, sent0) < 40:
            fail("firefox does not show the viewer's newest frame")
        if psnr(shown0, shown1) > 40:
            fail("firefox does not show a changed picture after the key")
        if p1["stats"] == p0["stats"] or f"frames {s1['frames']}" not in p1["stats"]:
            fail("firefox's stats line did not update after the key")
        if docs_dir:
            Image.fromarray(img1).save(os.path.join(docs_dir, "browser_firefox.png"))
    finally:
        ff.close()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--window_bin", required=True)
    ap.add_argument("--render_bin", required=True)
    ap.add_argument("--work_dir", default="")
    ap.add_argument("--docs_dir", default="")
    args = ap.parse_args()
    work = args.work_dir or tempfile.mkdtemp(prefix="http_view_")
    os.makedirs(work, exist_ok=True)
    env = dict(os.environ, LP_NUM_THREADS="2")
    model = os.path.join(work, "apt.exomodel")
    subprocess.run([args.render_bin, "--synthetic=apartment", "--synth_frames=24", "--store=10",
                    "--orbit=1", "--width=160", "--height=120", f"--save_model={model}"],
                   check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    port_file = os.path.join(work, "port")
    if os.path.exists(port_file):
        os.remove(port_file)
    viewer = subprocess.Popen([args.window_bin, f"--model={model}", "--http=127.0.0.1:0",
                               f"--port_file={port_file}", "--width=320", "--height=240",
                               "--max_seconds=240"], env=env, stdout=subprocess.DEVNULL)
    try:
        t0 = time.time()
        while not (os.path.exists(port_file) and open(port_file).read().strip()):
            if viewer.poll() is not None or time.time() - t0 > 60:
                fail("the viewer did not start serving")
            time.sleep(0.1)
        port = int(open(port_file).read())
        base = f"http://127.0.0.1:{port}"
        st, hdr, page = get(base + "/")
        if st != 200 or b"<img" not in page or b"/frame.jpg" not in page:
            fail("the page is not the viewer's page")
        if b"http://" in page or b"https://" in page:
            fail("the page refers to external assets")
        def settled(what):
            """Waits until the view is at full resolution and no new frame came for 0.6 s."""
            t1 = time.time()
            last = None
            while time.time() - t1 < 120:
                s = json.loads(get(base + "/status")[2])
                if s.get("stage") == 1 and last is not None and s["frames"] == last["frames"]:
                    return s
                last = s if s.get("stage") == 1 else None
                time.sleep(0.6)
            fail(f"the view did not settle at full resolution ({what})")

        settled("first frame")
        st, hdr, body = get(base + "/frame.jpg?after=0", timeout=30)
        seq0 = int(hdr["X-Frame-Seq"])
        img0 = np.asarray(Image.open(io.BytesIO(body)).convert("RGB"))
        if img0.std() < 5:
            fail("the first frame is flat")
        status0 = json.loads(get(base + "/status")[2])
        for key in ("frame_ms", "model_version", "views", "cells", "sync", "frames", "pose_local"):
            if key not in status0:
                fail(f"/status lacks {key}")
        if status0["views"] != 10:
            fail(f"/status says {status0['views']} views, the model has 10")
        metrics = get(base + "/metrics")[2].decode()
        values = {l.split()[0]: float(l.split()[1]) for l in metrics.splitlines()
                  if l and not l.startswith("#")}
        for name in ("exoview_viewer_frame_ms", "exoview_viewer_model_version",
                     "exoview_viewer_bytes_received_total", "exoview_viewer_frames_sent_total"):
            if name not in values:
                fail(f"/metrics lacks {name}")
        if not values["exoview_viewer_frames_sent_total"] >= 1:
            fail("/metrics does not count the frame sent")
        log(f"page, status ({status0['views']} views, {status0['frames']} frames), metrics ok; "
            f"first frame {img0.shape[1]}x{img0.shape[0]} seq {seq0}")

        # ---- a key from the page's protocol: W held 0.5 s ----
        get(base + "/input?key=w&down=1", method="POST")
        time.sleep(0.5)
        get(base + "/input?key=w&down=0", method="POST")
        settled("after W")  # the camera stopped; the frame refined to full resolution
        st, hdr, body = get(base + f"/frame.jpg?after=0", timeout=30)
        img1 = np.asarray(Image.open(io.BytesIO(body)).convert("RGB"))
        status1 = json.loads(get(base + "/status")[2])
        moved = np.linalg.norm(np.array(status1["pose_local"]["t"]) - np.array(status0["pose_local"]["t"]))
        log(f"W: seq {seq0} -> {hdr['X-Frame-Seq']}, moved {moved:.3f} m, frames "
            f"{status0['frames']} -> {status1['frames']}, PSNR to the first frame {psnr(img0, img1):.1f} dB")
        if int(hdr["X-Frame-Seq"]) <= seq0 or status1["frames"] <= status0["frames"]:
            fail("no new frame after the key")
        if not moved > 0.05 or psnr(img0, img1) > 30:
            fail("the view did not change after W")

        # ---- 20 browsers at once, one drops mid-stream ----
        n = 20
        got = [0] * n
        threads = [threading.Thread(target=stream_reader,
                                    args=(port, 6.0, got, i, 2 if i == 0 else None))
                   for i in range(n)]
        for t in threads:
            t.start()
        time.sleep(0.5)
        for _ in range(8):  # keep the camera turning: new frames for everyone
            get(base + "/input?key=right&down=1", method="POST")
            time.sleep(0.4)
        get(base + "/input?key=right&down=0", method="POST")
        for t in threads:
            t.join(timeout=20)
        log(f"20 streams: frames per stream {got}")
        if min(got[1:]) < 3:
            fail("a stream got fewer than 3 frames with 20 browsers connected")
        if viewer.poll() is not None:
            fail("the viewer died with 20 browsers")
        st, _, _ = get(base + "/status")
        if st != 200:
            fail("the viewer stopped answering after a browser dropped")

        # ---- a real browser (Debian chromium, headless, driven over its DevTools protocol) ----
        chromium = shutil.which("chromium") or shutil.which("chromium-browser")
        if chromium is None:
            log("chromium not installed: SKIPPED the headless-browser part (apt-get install chromium)")
        else:
            first_look_part(chromium, base, work, env, args.docs_dir)
            devtools_part(chromium, base, work, env, args.docs_dir)
        # ---- Firefox (Debian firefox-esr, headless, driven over WebDriver BiDi) ----
        firefox = shutil.which("firefox-esr") or shutil.which("firefox")
        if firefox is None:
            log("firefox-esr not installed: SKIPPED the Firefox part (apt-get install firefox-esr)")
        else:
            firefox_part(firefox, base, work, env, args.docs_dir)
        log("PASS")
        return 0
    finally:
        if viewer.poll() is None:
            viewer.terminate()
            try:
                viewer.wait(timeout=20)
            except subprocess.TimeoutExpired:
                viewer.kill()


if __name__ == "__main__":
    sys.exit(main())
