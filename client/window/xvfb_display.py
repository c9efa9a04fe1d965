"""A virtual X display for the window tests (window_xvfb_test, window_drone_xvfb_test).

Xvfb picks a free display number itself and reports it on a pipe (-displayfd), so tests running
in parallel never collide; close() ends it. Imported from the tests beside this file (Python puts
a script's own folder first on sys.path).
"""
import os
import shutil
import subprocess

TOOLS = ("Xvfb", "xdotool", "import")  # the display, input injection, screenshots


def missing_tools():
    """The tools these tests need that are not installed (their skip message names them)."""
    return [t for t in TOOLS if shutil.which(t) is None]


class Display:
    def __init__(self, width, height):
        r, w = os.pipe()
        self.proc = subprocess.Popen(
            ["Xvfb", "-displayfd", str(w), "-screen", "0", f"{width}x{height}x24", "-nolisten",
             "tcp"],
            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(w)
        with os.fdopen(r) as f:
            num = f.readline().strip()
        if not num:
            self.proc.kill()
            self.proc.wait(timeout=10)
            raise RuntimeError("Xvfb did not report a display number")
        self.name = f":{num}"

    def close(self):
        self.proc.terminate()
        self.proc.wait(timeout=10)
