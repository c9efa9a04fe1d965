#!/usr/bin/python3
"""Exoview uploader example in Python: streams a 7-Scenes or TUM RGB-D folder to an
exoview_server over gRPC (exoview.v1.Exoview/Upload), then reads the scene statistics
(GetStats). Prints one JSON line: the acks (counts per status and per code, every rejection with
its code and reason) and the server's stats.

Stubs are generated from the unchanged proto/exoview.proto with Debian's python3-grpc-tools
(exoview_stubs.py); only Debian packages are used (python3-grpcio, python3-protobuf,
python3-numpy, python3-pil).

  exoview_upload.py --target=127.0.0.1:50051 --sevenscenes=DIR [--frames=N] [--every=K]
  exoview_upload.py --target=... --tum=DIR [--fx=525 --fy=525 --cx=319.5 --cy=239.5]

7-Scenes (flat folder or one seq-XX folder): camera-intrinsics.txt, frame-NNNNNN.color.{jpg,png},
frame-NNNNNN.depth.png (uint16 mm, 65535 = invalid), frame-NNNNNN.pose.txt (4x4 camera-to-world).
Poses are sent as written (3x3 rotation matrix): the server projects rotations within 1e-2 of
orthonormal to SO(3). Depth is sent as registered to colour with the folder's K; the C++
exoview_uploader registers 7-Scenes depth to colour properly and is what the evaluation measures.
TUM: rgb.txt, depth.txt, groundtruth.txt (tx ty tz qx qy qz qw); depth uint16 / 5000 m.
"""
import argparse
import glob
import io
import json
import os
import re
import sys
import threading
import time

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import exoview_stubs  # noqa: E402


# ---- datasets -> (colour JPEG bytes, width, height, depth uint16 array, depth scale, K, pose) ----

def read_numbers(path):
    with open(path) as f:
        return [float(v) for v in f.read().split()]


def color_jpeg(path, quality):
    """JPEG files are sent as they are; other formats are re-encoded."""
    with Image.open(path) as im:
        size = im.size
        if im.format == "JPEG":
            with open(path, "rb") as f:
                return f.read(), size
        buf = io.BytesIO()
        im.convert("RGB").save(buf, format="JPEG", quality=quality)
        return buf.getvalue(), size


def depth_u16(path, invalid=None):
    with Image.open(path) as im:
        d = np.array(im).astype(np.uint16)
    if invalid is not None:
        d[d == invalid] = 0
    return d


def seven_scenes_frames(folder, args):
    k = read_numbers(os.path.join(folder, "camera-intrinsics.txt"))
    if len(k) != 9:
        raise ValueError("%s/camera-intrinsics.txt: expected a 3x3 matrix" % folder)
    intr = (k[0], k[4], k[2], k[5])
    ids = sorted(int(m.group(1)) for m in
                 (re.search(r"frame-(\d+)\.pose\.txt$", p)
                  for p in glob.glob(os.path.join(folder, "frame-*.pose.txt"))) if m)
    if not ids:
        raise ValueError("%s: no frame-NNNNNN.pose.txt files (not a 7-Scenes folder)" % folder)
    for n, i in enumerate(ids[args.first::args.every][:args.frames]):
        stem = os.path.join(folder, "frame-%06d" % i)
        color = stem + ".color.jpg" if os.path.exists(stem + ".color.jpg") else stem + ".color.png"
        jpeg, size = color_jpeg(color, args.jpeg_quality)
        m = read_numbers(stem + ".pose.txt")
        if len(m) != 16:
            raise ValueError("%s.pose.txt: expected 16 numbers, got %d" % (stem, len(m)))
        yield dict(jpeg=jpeg, size=size, depth=depth_u16(stem + ".depth.png", invalid=65535),
                   depth_scale=0.001, intrinsics=intr, timestamp=i / 30.0,
                   rotation=("matrix", [m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]]),
                   translation=(m[3], m[7], m[11]), name=stem)


def tum_list(path):
    out = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line and not line.startswith("#"):
                parts = line.split()
                out.append((float(parts[0]), parts[1:]))
    return out


def nearest(entries, t, max_dt):
    best = min(entries, key=lambda e: abs(e[0] - t))
    return best if abs(best[0] - t) <= max_dt else None


def tum_frames(folder, args):
    defaults = (525.0, 525.0, 319.5, 239.5)
    intr = (args.fx or defaults[0], args.fy or defaults[1], args.cx or defaults[2],
            args.cy or defaults[3])
    if not (args.fx and args.fy and args.cx and args.cy):
        print("exoview_upload: warning: TUM intrinsics not all given, using %s (the Kinect "
              "defaults; pass --fx --fy --cx --cy for your sensor)" % (intr,), file=sys.stderr)
    rgb = tum_list(os.path.join(folder, "rgb.txt"))
    depth = tum_list(os.path.join(folder, "depth.txt"))
    gt = tum_list(os.path.join(folder, "groundtruth.txt"))
    pairs = []
    for t, (name,) in rgb:
        d, p = nearest(depth, t, 0.02), nearest(gt, t, 0.02)
        if d and p:
            pairs.append((t, name, d[1][0], [float(v) for v in p[1]]))
    for t, color, dname, p in pairs[args.first::args.every][:args.frames]:
        jpeg, size = color_jpeg(os.path.join(folder, color), args.jpeg_quality)
        tx, ty, tz, qx, qy, qz, qw = p
        yield dict(jpeg=jpeg, size=size, depth=depth_u16(os.path.join(folder, dname)),
                   depth_scale=1.0 / 5000.0, intrinsics=intr, timestamp=t,
                   rotation=("quaternion", (qw, qx, qy, qz)), translation=(tx, ty, tz),
                   name=color)


# ---- wire ----

def to_proto(pb, seq, f):
    msg = pb.Frame(sequence=seq, timestamp_s=f["timestamp"], color_jpeg=f["jpeg"])
    w, h = f["size"]
    fx, fy, cx, cy = f["intrinsics"]
    msg.color_intrinsics.CopyFrom(pb.Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=w, height=h))
    d = f["depth"]
    if d.shape != (h, w):
        raise ValueError("%s: depth is %dx%d, colour %dx%d" % (f["name"], d.shape[1], d.shape[0], w, h))
    msg.depth.CopyFrom(pb.DepthImage(codec=pb.DEPTH_CODEC_RAW_U16, data=d.astype("<u2").tobytes(),
                                     width=w, height=h, depth_scale_m=f["depth_scale"]))
    kind, r = f["rotation"]
    if kind == "matrix":
        msg.world_from_cam.matrix.row_major.extend(r)
    else:
        msg.world_from_cam.quaternion.CopyFrom(pb.Quaternion(w=r[0], x=r[1], y=r[2], z=r[3]))
    tx, ty, tz = f["translation"]
    msg.world_from_cam.translation.CopyFrom(pb.Vec3(x=tx, y=ty, z=tz))
    return msg


def upload(stub, pb, frames, max_in_flight):
    """Streams the frames with at most max_in_flight unacknowledged; returns the acks."""
    window = threading.Semaphore(max_in_flight)
    errors = []

    def requests():
        try:
            for seq, f in enumerate(frames, start=1):
                msg = to_proto(pb, seq, f)
                window.acquire()
                yield msg
        except Exception as e:  # a reader error ends the stream; reported after the acks
            errors.append(e)

    acks = []
    for ack in stub.Upload(requests()):
        acks.append(ack)
        window.release()
    if errors:
        raise errors[0]
    return acks


def summarize(pb, acks):
    out = {"sent": len(acks), "accepted": 0, "rejected": 0, "dropped": 0, "codes": {},
           "rejections": []}
    for a in acks:
        status = pb.Ack.Status.Name(a.status)
        code = pb.Ack.Code.Name(a.code)
        out[status.lower()] = out.get(status.lower(), 0) + 1
        out["codes"][code] = out["codes"].get(code, 0) + 1
        if a.status != pb.Ack.ACCEPTED:
            out["rejections"].append({"sequence": a.sequence, "status": status, "code": code,
                                      "reason": a.reason})
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", default="127.0.0.1:50051", help="server address host:port")
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--sevenscenes", help="7-Scenes folder")
    src.add_argument("--tum", help="TUM RGB-D folder")
    ap.add_argument("--first", type=int, default=0, help="first frame (index in the folder)")
    ap.add_argument("--frames", type=int, default=1 << 30, help="frames to send")
    ap.add_argument("--every", type=int, default=1, help="send every k-th frame")
    ap.add_argument("--max_in_flight", type=int, default=8, help="unacknowledged frames")
    ap.add_argument("--jpeg_quality", type=int, default=90, help="re-encoding of PNG colour")
    ap.add_argument("--fx", type=float), ap.add_argument("--fy", type=float)
    ap.add_argument("--cx", type=float), ap.add_argument("--cy", type=float)
    ap.add_argument("--wait_s", type=float, default=60.0,
                    help="wait this long for the server to process every accepted frame")
    ap.add_argument("--stubs", help="directory of the generated stubs (default: generate them)")
    args = ap.parse_args()
    if args.first < 0 or args.frames < 1 or args.every < 1 or args.max_in_flight < 1:
        ap.error("--first >= 0, --frames, --every and --max_in_flight >= 1")

    exoview_stubs.load(args.stubs)
    import grpc
    import exoview_pb2 as pb
    import exoview_pb2_grpc as pb_grpc
    from google.protobuf import json_format

    frames = (seven_scenes_frames(args.sevenscenes, args) if args.sevenscenes
              else tum_frames(args.tum, args))
    channel = grpc.insecure_channel(args.target, options=[
        ("grpc.max_send_message_length", 64 << 20), ("grpc.max_receive_message_length", 64 << 20)])
    stub = pb_grpc.ExoviewStub(channel)
    t0 = time.monotonic()
    try:
        acks = upload(stub, pb, frames, args.max_in_flight)
    except (OSError, ValueError) as e:
        print("exoview_upload: %s" % e, file=sys.stderr)
        return 1
    except grpc.RpcError as e:
        print("exoview_upload: %s: %s" % (e.code().name, e.details()), file=sys.stderr)
        return 1
    elapsed = time.monotonic() - t0
    result = summarize(pb, acks)
    result["elapsed_s"] = round(elapsed, 3)
    deadline = time.monotonic() + args.wait_s
    while True:
        stats = stub.GetStats(pb.StatsRequest(), timeout=10)
        if stats.frames_processed >= stats.frames_accepted or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    result["stats"] = json_format.MessageToDict(stats, preserving_proto_field_name=True,
                                                including_default_value_fields=True)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
