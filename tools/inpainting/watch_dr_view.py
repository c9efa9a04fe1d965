#!/usr/bin/env python3
"""Watches the live DR view of an Exoview server (WatchDrView: the camera's stream with the marked
regions removed) and writes each frame as JPEG (dr_<sequence>.jpg) into --out; prints one JSON
line at the end: frames received, their rate, composited frames, mean compose and latency ms.

  watch_dr_view.py --target HOST:PORT --out DIR [--seconds 10] [--quality 90] [--stubs DIR]
"""
import argparse
import json
import os
import sys
import time

import grpc

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "client",
                                "python"))
import exoview_stubs  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", default="127.0.0.1:50051")
    ap.add_argument("--out", required=True)
    ap.add_argument("--seconds", type=float, default=10.0, help="stop after this long")
    ap.add_argument("--quality", type=int, default=90, help="JPEG quality (1..100)")
    ap.add_argument("--stubs")
    args = ap.parse_args()
    exoview_stubs.load(args.stubs)
    import exoview_pb2 as pb
    import exoview_pb2_grpc as pbg
    os.makedirs(args.out, exist_ok=True)
    stub = pbg.ExoviewStub(grpc.insecure_channel(args.target))
    n = composited = 0
    compose = latency = 0.0
    t0 = t_first = t_last = None
    t0 = time.monotonic()
    try:
        for m in stub.WatchDrView(pb.WatchDrViewRequest(jpeg_quality=args.quality),
                                  timeout=args.seconds):
            now = time.monotonic()
            t_first = t_first or now
            t_last = now
            n += 1
            composited += m.composited
            compose += m.compose_ms
            latency += m.latency_ms
            with open(os.path.join(args.out, "dr_%06d.jpg" % m.sequence), "wb") as f:
                f.write(m.color_jpeg)
    except grpc.RpcError as e:
        if e.code() != grpc.StatusCode.DEADLINE_EXCEEDED:
            print("WatchDrView: %s: %s" % (e.code().name, e.details()), file=sys.stderr)
            sys.exit(1)
    span = (t_last - t_first) if n > 1 else 0.0
    print(json.dumps({"frames": n, "composited": composited,
                      "fps": round((n - 1) / span, 2) if span > 0 else 0.0,
                      "compose_ms_mean": round(compose / n, 2) if n else 0.0,
                      "latency_ms_mean": round(latency / n, 1) if n else 0.0,
                      "out": args.out}))


if __name__ == "__main__":
    main()
