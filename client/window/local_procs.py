"""Processes the window tests start on loopback (window_*_xvfb_test, window_tls_xvfb_test): a
binary told to listen on a free port writes it to a --port_file, which the test waits for.
Imported from the tests beside this file (Python puts a script's own folder first on sys.path).
"""
import os
import subprocess
import time


def fresh_port_file(work, name):
    """The path of a port file in `work`, with a stale one from an earlier run removed."""
    path = os.path.join(work, f"{name}.port")
    if os.path.exists(path):
        os.remove(path)
    return path


def wait_port(proc, port_file, timeout_s, what):
    """The port `proc` wrote to `port_file`; RuntimeError naming `what` if it exits first or
    nothing arrives within timeout_s."""
    t0 = time.time()
    while not (os.path.exists(port_file) and open(port_file).read().strip()):
        if proc.poll() is not None or time.time() - t0 > timeout_s:
            raise RuntimeError(f"{what} did not start")
        time.sleep(0.1)
    return open(port_file).read().strip()


def start_server(server_bin, work, env, extra_args=()):
    """exoview_server on 127.0.0.1 at a free port (log level warning): (process, port file)."""
    port_file = fresh_port_file(work, "server")
    proc = subprocess.Popen([server_bin, "--listen=127.0.0.1:0", f"--port_file={port_file}",
                             "--log_level=warning", *extra_args], env=env)
    return proc, port_file


def scene_control_zones(uploader_bin, env, scene="apartment"):
    """The synthetic scene's flight zone as the simulated-drone uploader prints it (before it
    connects anywhere: the server address is a closed port); None if it printed none."""
    probe = subprocess.run(["timeout", "20", uploader_bin, "--drone=sim", f"--synthetic={scene}",
                            "--server=127.0.0.1:9", "--flight_s=1"], env=env, capture_output=True,
                           text=True)
    zones = [w.split("control_zones=", 1)[1].rstrip(")") for w in probe.stderr.split()
             if w.startswith("control_zones=")]
    return (zones[0] if zones else None), probe.stderr
