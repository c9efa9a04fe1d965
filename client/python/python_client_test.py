#!/usr/bin/python3
"""Test of the Python client against a real exoview_server on loopback (ctest python_client_test).

  python_client_test.py --server=BIN --stubs=DIR [--shared=DIR]

Each test starts its own server process on a free port. The stubs come from the unchanged
proto/exoview.proto, compiled with Debian's python3-grpc-tools.
"""
import argparse
import io
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import unittest

import numpy as np
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
ARGS = None


class Server:
    def __init__(self, binary, workdir):
        self.workdir = workdir
        self.port_file = os.path.join(workdir, "port")
        self.log = open(os.path.join(workdir, "server.log"), "w")
        self.proc = subprocess.Popen(
            [binary, "--listen=127.0.0.1:0", "--port_file=" + self.port_file],
            stdout=self.log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 20
        while not os.path.exists(self.port_file):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("server did not start:\n" + self.read_log())
            time.sleep(0.05)
        with open(self.port_file) as f:
            self.target = "127.0.0.1:%d" % int(f.read())

    def read_log(self):
        self.log.flush()
        with open(os.path.join(self.workdir, "server.log")) as f:
            return f.read()

    def stop(self):
        self.proc.terminate()
        self.proc.wait(timeout=20)
        self.log.close()


def run_tool(script, *args):
    cmd = [sys.executable, os.path.join(HERE, script), "--stubs=" + ARGS.stubs] + list(args)
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    return r.returncode, r.stdout, r.stderr


def rot_y(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def write_seven_scenes(folder, n, bad=None):
    """n frames of a 7-Scenes folder: a textured plane 2 m ahead (160x120), poses printed with 4
    decimals (max|R^T R - I| ~ 1e-4, as real tracker files); frame `bad` off by 0.05."""
    os.makedirs(folder)
    w, h, f = 160, 120, 140.0
    with open(os.path.join(folder, "camera-intrinsics.txt"), "w") as out:
        out.write("%f 0 %f\n0 %f %f\n0 0 1\n" % (f, w / 2, f, h / 2))
    errors = []
    for i in range(n):
        stem = os.path.join(folder, "frame-%06d" % i)
        yy, xx = np.mgrid[0:h, 0:w]
        rgb = np.stack([((xx // 8 + yy // 8) % 2) * 180 + 30,
                        (xx * 255 // w), (yy * 255 // h)], axis=-1).astype(np.uint8)
        Image.fromarray(rgb).save(stem + ".color.jpg", quality=90)
        depth = np.full((h, w), 2000, dtype=np.uint16)
        depth[:4, :4] = 65535  # 7-Scenes' invalid marker
        Image.fromarray(depth).save(stem + ".depth.png")
        pose = np.eye(4)
        pose[:3, :3] = np.round(rot_y(0.15 * i), 4)
        pose[:3, 3] = [0.1 * i, 0.0, 0.0]
        if i == bad:
            pose[0, 1] += 0.05
        r = pose[:3, :3]
        errors.append(float(np.abs(r.T @ r - np.eye(3)).max()))
        np.savetxt(stem + ".pose.txt", pose, fmt="%.4f")
    return errors


def write_tum(folder, n):
    """n frames of a TUM RGB-D folder: PNG colour (re-encoded to JPEG by the uploader), depth
    uint16 / 5000 m, ground truth 'tx ty tz qx qy qz qw' at slightly different times."""
    os.makedirs(os.path.join(folder, "rgb"))
    os.makedirs(os.path.join(folder, "depth"))
    w, h = 128, 96
    with open(os.path.join(folder, "rgb.txt"), "w") as rgb_txt, \
            open(os.path.join(folder, "depth.txt"), "w") as depth_txt, \
            open(os.path.join(folder, "groundtruth.txt"), "w") as gt_txt:
        rgb_txt.write("# timestamp filename\n")
        for i in range(n):
            t = 100.0 + 0.1 * i
            yy, xx = np.mgrid[0:h, 0:w]
            rgb = np.stack([((xx // 6 + yy // 6) % 2) * 200 + 20, xx * 2, yy * 2],
                           axis=-1).astype(np.uint8)
            Image.fromarray(rgb).save(os.path.join(folder, "rgb", "%.6f.png" % t))
            Image.fromarray(np.full((h, w), 2.5 * 5000, dtype=np.uint16)).save(
                os.path.join(folder, "depth", "%.6f.png" % (t + 0.005)))
            rgb_txt.write("%.6f rgb/%.6f.png\n" % (t, t))
            depth_txt.write("%.6f depth/%.6f.png\n" % (t + 0.005, t + 0.005))
            half = 0.05 * i
            gt_txt.write("%.4f %.4f 0 0 0 %.4f 0 %.4f\n" % (t - 0.003, 0.1 * i, math.sin(half),
                                                           math.cos(half)))


class PythonClientTest(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="exoview_py_")
        self.server = Server(ARGS.server, self.dir)

    def tearDown(self):
        self.server.stop()
        if sys.exc_info() == (None, None, None):
            shutil.rmtree(self.dir, ignore_errors=True)

    def upload(self, *args):
        rc, out, err = run_tool("exoview_upload.py", "--target=" + self.server.target, *args)
        self.assertEqual(rc, 0, "uploader failed:\n" + err + "\nserver log:\n" +
                         self.server.read_log())
        return json.loads(out.strip().splitlines()[-1])

    def test_reflection_lists_the_exoview_service(self):
        rc, out, err = run_tool("list_services.py", "--target=" + self.server.target)
        self.assertEqual(rc, 0, err)
        services = json.loads(out)["services"]
        self.assertEqual(services.get("exoview.v1.Exoview"),
                         ["ClearRegion", "CompleteView", "GetStats", "ListRegions", "MarkRegion",
                          "Subscribe", "Upload", "WatchDrView"])
        self.assertIn("grpc.health.v1.Health", services)

    def test_uploads_frames_it_wrote_and_reads_stats(self):
        folder = os.path.join(self.dir, "scene")
        errors = write_seven_scenes(folder, 6, bad=4)
        # Written with 4 decimals, the good rotations are off orthonormal by more than the old
        # strict tolerance (1e-4) and far less than the projection limit (1e-2).
        self.assertGreater(max(e for i, e in enumerate(errors) if i != 4), 1e-5)
        self.assertGreater(errors[4], 0.04)
        result = self.upload("--sevenscenes=" + folder)
        self.assertEqual(result["sent"], 6)
        self.assertEqual(result["accepted"], 5, result["rejections"])
        self.assertEqual(result["rejected"], 1)
        self.assertEqual(result["codes"], {"OK": 5, "INVALID_ARGUMENT": 1})
        (rej,) = result["rejections"]
        self.assertEqual(rej["sequence"], 5)  # frame 4 is the 5th sent
        self.assertEqual(rej["code"], "INVALID_ARGUMENT")
        self.assertIn("rotation is not orthonormal: max|R^T R - I| = ", rej["reason"])
        measured = float(rej["reason"].split("max|R^T R - I| = ")[1].split()[0])
        self.assertAlmostEqual(measured, errors[4], delta=1e-6)
        stats = result["stats"]
        self.assertEqual(int(stats["frames_received"]), 6)
        self.assertEqual(int(stats["frames_accepted"]), 5)
        self.assertEqual(int(stats["frames_rejected"]), 1)
        self.assertEqual(int(stats["frames_processed"]), 5)
        self.assertGreater(int(stats["num_views"]), 0)
        self.assertGreater(int(stats["num_chunks"]), 0)  # the plane became proxy geometry
        self.assertNotEqual(int(stats["model_digest"]), 0)

    def test_uploads_a_tum_folder_with_quaternion_poses(self):
        folder = os.path.join(self.dir, "tum")
        write_tum(folder, 4)
        rc, out, err = run_tool("exoview_upload.py", "--target=" + self.server.target,
                                "--tum=" + folder, "--fx=110", "--fy=110", "--cx=63.5",
                                "--cy=47.5")
        self.assertEqual(rc, 0, err)
        self.assertNotIn("warning", err)  # intrinsics given: no default used
        result = json.loads(out)
        self.assertEqual(result["codes"], {"OK": 4}, result["rejections"])
        self.assertEqual(int(result["stats"]["frames_processed"]), 4)
        self.assertGreater(int(result["stats"]["num_views"]), 0)

    def test_missing_folder_is_a_clear_error(self):
        rc, out, err = run_tool("exoview_upload.py", "--target=" + self.server.target,
                                "--sevenscenes=" + os.path.join(self.dir, "nowhere"))
        self.assertEqual(rc, 1)
        self.assertIn("camera-intrinsics.txt", err)

    def test_uploads_real_seven_scenes_frames_as_written(self):
        folder = os.path.join(ARGS.shared, "data", "7scenes-redkitchen")
        if not os.path.isdir(folder):
            self.skipTest("%s not found (real data missing)" % folder)
        result = self.upload("--sevenscenes=" + folder, "--frames=5", "--every=20")
        self.assertEqual(result["sent"], 5)
        self.assertEqual(result["accepted"], 5, result["rejections"])
        self.assertEqual(result["codes"], {"OK": 5})
        stats = result["stats"]
        self.assertEqual(int(stats["frames_processed"]), 5)
        self.assertGreater(int(stats["num_views"]), 0)
        self.assertGreater(int(stats["num_cells"]), 0)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--server", required=True)
    ap.add_argument("--stubs", required=True)
    ap.add_argument("--shared", default=os.environ.get("EXOVIEW_SHARED_DIR",
                                                       os.path.join(HERE, "..", "..", "..", "shared")))
    ARGS, rest = ap.parse_known_args()
    unittest.main(argv=[sys.argv[0], "-v"] + rest)
