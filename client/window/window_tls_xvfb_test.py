#!/usr/bin/env python3
"""The viewer window against a server with TLS and role tokens (issues 17 and 20).

deploy/make_certs.sh makes a CA, the server's certificate and one bearer token per role; a real
exoview_server runs with --tls_cert/--tls_key/--auth_tokens_file on loopback, the uploader sends
20 synthetic apartment frames with the uploader's token, and exoview_window subscribes with
--tls_ca/--tls_server_name/--token_file (the viewer's token) under Xvfb: the status file must
show the live model (views > 0, "live: subscribed"). A token file that does not exist is a clear
error (exit != 0 naming the file), before anything is shown.
Skips (exit 0 with a clear message) where Xvfb, xdotool, ImageMagick or openssl is missing.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

from local_procs import start_server, wait_port
from xvfb_display import Display, missing_tools

W, H = 320, 240


def log(msg):
    print(f"[window_tls_xvfb_test] {msg}", flush=True)


def fail(msg):
    log(f"FAIL: {msg}")
    sys.exit(1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--window_bin", required=True)
    ap.add_argument("--server_bin", required=True)
    ap.add_argument("--uploader_bin", required=True)
    ap.add_argument("--make_certs", required=True)
    ap.add_argument("--work_dir", default="")
    ap.add_argument("--timeout_s", type=float, default=90)
    args = ap.parse_args()
    missing = missing_tools() + ([] if shutil.which("openssl") else ["openssl"])
    if missing:
        log(f"SKIPPED: {', '.join(missing)} not installed "
            "(apt-get install xvfb xdotool imagemagick openssl)")
        return 0
    work = args.work_dir or tempfile.mkdtemp(prefix="window_tls_")
    os.makedirs(work, exist_ok=True)
    certs = os.path.join(work, "certs")
    shutil.rmtree(certs, ignore_errors=True)
    subprocess.run(["bash", args.make_certs, certs], check=True, stdout=subprocess.DEVNULL)
    env = dict(os.environ, LP_NUM_THREADS="2", SDL_VIDEODRIVER="x11")
    server, port_file = start_server(args.server_bin, work, env,
                                     [f"--tls_cert={certs}/server.pem", f"--tls_key={certs}/server.key",
                                      f"--auth_tokens_file={certs}/tokens.txt"])
    win = disp = None
    try:
        try:
            addr = "127.0.0.1:" + wait_port(server, port_file, 30, "the server")
        except RuntimeError as e:
            fail(str(e))
        tls = [f"--tls_ca={certs}/ca.pem", "--tls_server_name=localhost"]
        subprocess.run([args.uploader_bin, f"--server={addr}", *tls,
                        f"--token_file={certs}/uploader.token", "--synthetic=apartment",
                        "--trajectory=walk", "--frames=20", f"--width={W}", f"--height={H}",
                        "--rate_hz=0"], check=True, env=env, stdout=subprocess.DEVNULL)
        disp = Display(W, H)
        env["DISPLAY"] = disp.name

        # A token file that is not there: a clear error, nothing shown.
        bad = subprocess.run([args.window_bin, f"--server={addr}", *tls,
                              f"--token_file={certs}/no_such.token", f"--width={W}",
                              f"--height={H}", "--max_seconds=20"], env=env, capture_output=True,
                             text=True, timeout=60)
        log(f"missing token file: exit {bad.returncode}: {bad.stderr.strip()[-160:]}")
        if bad.returncode == 0 or "no_such.token" not in bad.stderr:
            fail("a missing token file was not a clear error naming the file")

        status = os.path.join(work, "status.json")
        if os.path.exists(status):
            os.remove(status)
        win = subprocess.Popen([args.window_bin, f"--server={addr}", *tls,
                                f"--token_file={certs}/viewer.token", f"--width={W}",
                                f"--height={H}", "--no_overlays", f"--status_file={status}",
                                "--max_seconds=120"], env=env)
        t1 = time.time()
        st = None
        while time.time() - t1 < args.timeout_s:
            if win.poll() is not None:
                fail(f"the window exited ({win.returncode}) before showing the live model")
            try:
                with open(status) as f:
                    s = json.load(f)
                if s["views"] > 0 and s["sync"].startswith("live: subscribed") and s["stage"] == 1:
                    st = s
                    break
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(0.1)
        if st is None:
            fail(f"no live model through TLS + the viewer's token within {args.timeout_s} s")
        log(f"TLS + viewer token: {st['views']} views, model v{st['model_version']}, "
            f"'{st['sync']}'")
        subprocess.run(["xdotool", "key", "Escape"], check=True, env=env)
        if win.wait(timeout=30) != 0:
            fail("the window did not exit cleanly after Esc")
        win = None
        log("PASS")
        return 0
    finally:
        for p in (win, server):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(timeout=10)
        if disp is not None:
            disp.close()


if __name__ == "__main__":
    sys.exit(main())
