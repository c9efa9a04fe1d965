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
"""
import argparse
import io
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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--window_bin", required=True)
    ap.add_argument("--server_bin", required=True)
    ap.add_argument("--bench_bin", required=True)
    ap.add_argument("--work_dir", default="")
    args = ap.parse_args()
    work = args.work_dir or tempfile.mkdtemp(prefix="window_dr_")
    os.makedirs(work, exist_ok=True)
    env = dict(os.environ, LP_NUM_THREADS="2")
    for f in ("server.port", "http.port"):
        if os.path.exists(os.path.join(work, f)):
            os.remove(os.path.join(work, f))
    dump = os.path.join(work, "frames")
    procs = []
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
        log("PASS")
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()


if __name__ == "__main__":
    main()
