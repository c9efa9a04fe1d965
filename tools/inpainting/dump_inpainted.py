#!/usr/bin/env python3
"""Writes the inpainted keyframes of an Exoview server (a snapshot over Subscribe) as JPEG files
(view_<id>.jpg, the colour the viewers receive) with their label masks (view_<id>_labels.pgm)
and prints the inpainting counters of GetStats as JSON: what docs/inpainting.md's contact sheet
is made from.

  dump_inpainted.py --target HOST:PORT --out DIR [--stubs DIR]
"""
import argparse
import json
import os
import sys
import zlib

import grpc

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "client",
                                "python"))
import exoview_stubs  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", default="127.0.0.1:50051")
    ap.add_argument("--out", required=True)
    ap.add_argument("--stubs")
    args = ap.parse_args()
    exoview_stubs.load(args.stubs)
    import exoview_pb2 as pb
    import exoview_pb2_grpc as pbg
    os.makedirs(args.out, exist_ok=True)
    stub = pbg.ExoviewStub(grpc.insecure_channel(args.target))
    views = []
    for d in stub.Subscribe(pb.SubscribeRequest(), timeout=60):
        if d.HasField("view_added") and d.view_added.inpainted:
            v = d.view_added
            path = os.path.join(args.out, "view_%d.jpg" % v.view_id)
            with open(path, "wb") as f:
                f.write(v.color_jpeg)
            views.append({"view_id": v.view_id, "jpeg": path,
                          "source_timestamp_s": d.source_timestamp_s,
                          "region_ids": list(v.region_ids)})
        if d.HasField("snapshot_end"):
            break
    stats = stub.GetStats(pb.StatsRequest(), timeout=30)
    counters = {k: v for k, v in stats.counters.items() if k.startswith("inpainting.")}
    print(json.dumps({"inpainted_views": views, "counters": counters}, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()
