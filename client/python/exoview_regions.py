#!/usr/bin/env python3
"""Marks, lists and clears InpaintFusion regions of interest on an Exoview server (operator).

A region is a 2D stroke (pixels) on an image and the camera it was drawn in: the live camera's
frame (--world_from_cam, the uploads' world frame) or a viewer's window (--local_from_cam, the
scene-local frame). The server renders its proxy from that camera, takes the pixels within r_ROI
of the stroke whose surface lies within d_ROI along the normal (SPEC §7, 4.1) and labels them in
3D; every later frame re-projects the labels, and inpainted keyframes without the object reach
the viewers (docs/inpainting.md "Marking a region").

  exoview_regions.py --target HOST:PORT mark --camera FX,FY,CX,CY,W,H \\
      --world_from_cam TX,TY,TZ,QW,QX,QY,QZ --stroke X,Y[;X,Y...] [--radius_px R] \\
      [--depth_tol_m D] [--label TEXT]
  exoview_regions.py --target HOST:PORT list
  exoview_regions.py --target HOST:PORT clear [--id N]      (no id: every region)
  exoview_regions.py --target HOST:PORT complete --camera FX,FY,CX,CY,W,H \
      --local_from_cam TX,TY,TZ,QW,QX,QY,QZ [--max_side_px N]
      (scene completion at a viewer's camera, viewer role: docs/inpainting.md "Session 15")

With TLS and roles (docs/security.md): --tls_ca ca.pem --token_file operator.token.
Prints JSON; exits 1 with the server's status and message on an error.
"""
import argparse
import json
import os
import sys

import grpc

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import exoview_stubs  # noqa: E402


def floats(text, n, what):
    v = [float(x) for x in text.split(",")]
    if len(v) != n:
        raise SystemExit("%s needs %d comma-separated numbers" % (what, n))
    return v


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", default="127.0.0.1:50051", help="server address host:port")
    ap.add_argument("--tls_ca", help="CA of the server certificate (PEM): TLS")
    ap.add_argument("--token_file", help="bearer token (first line), needs --tls_ca")
    ap.add_argument("--stubs", help="directory of the generated stubs (default: generate them)")
    sub = ap.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("mark")
    m.add_argument("--camera", required=True, help="FX,FY,CX,CY,W,H (pixels)")
    pose = m.add_mutually_exclusive_group(required=True)
    pose.add_argument("--world_from_cam", help="TX,TY,TZ,QW,QX,QY,QZ (live camera, world)")
    pose.add_argument("--local_from_cam", help="TX,TY,TZ,QW,QX,QY,QZ (viewer window, scene-local)")
    m.add_argument("--stroke", required=True, help="X,Y;X,Y;... pixels")
    m.add_argument("--radius_px", type=float, default=0.0, help="r_ROI (0: server default)")
    m.add_argument("--depth_tol_m", type=float, default=0.0, help="d_ROI (0: server default)")
    m.add_argument("--label", default="")
    sub.add_parser("list")
    c = sub.add_parser("clear")
    c.add_argument("--id", type=int, default=0, help="region id (0: every region)")
    k = sub.add_parser("complete")
    k.add_argument("--camera", required=True, help="FX,FY,CX,CY,W,H (pixels)")
    k.add_argument("--local_from_cam", required=True,
                   help="TX,TY,TZ,QW,QX,QY,QZ (the viewer's camera, scene-local)")
    k.add_argument("--max_side_px", type=int, default=0, help="0: the server's default (640)")
    args = ap.parse_args()

    exoview_stubs.load(args.stubs)
    import exoview_pb2 as pb
    import exoview_pb2_grpc as pbg
    from google.protobuf import json_format

    if args.tls_ca:
        creds = grpc.ssl_channel_credentials(open(args.tls_ca, "rb").read())
        if args.token_file:
            token = open(args.token_file).readline().strip()
            creds = grpc.composite_channel_credentials(
                creds, grpc.access_token_call_credentials(token))
        channel = grpc.secure_channel(args.target, creds)
    else:
        if args.token_file:
            raise SystemExit("--token_file needs --tls_ca")
        channel = grpc.insecure_channel(args.target)
    stub = pbg.ExoviewStub(channel)
    try:
        if args.cmd == "mark":
            req = pb.MarkRegionRequest()
            fx, fy, cx, cy, w, h = floats(args.camera, 6, "--camera")
            req.camera.fx, req.camera.fy, req.camera.cx, req.camera.cy = fx, fy, cx, cy
            req.camera.width, req.camera.height = int(w), int(h)
            text = args.world_from_cam or args.local_from_cam
            t = floats(text, 7, "the pose")
            p = req.world_from_cam if args.world_from_cam else req.local_from_cam
            p.translation.x, p.translation.y, p.translation.z = t[0:3]
            p.quaternion.w, p.quaternion.x, p.quaternion.y, p.quaternion.z = t[3:7]
            for pt in args.stroke.split(";"):
                if pt.strip():
                    x, y = floats(pt, 2, "a stroke point")
                    req.stroke.add(x=x, y=y)
            req.radius_px, req.depth_tolerance_m, req.label = (args.radius_px, args.depth_tol_m,
                                                               args.label)
            out = stub.MarkRegion(req, timeout=30)
        elif args.cmd == "complete":
            req = pb.CompleteViewRequest(max_side_px=args.max_side_px)
            fx, fy, cx, cy, w, h = floats(args.camera, 6, "--camera")
            req.camera.fx, req.camera.fy, req.camera.cx, req.camera.cy = fx, fy, cx, cy
            req.camera.width, req.camera.height = int(w), int(h)
            t = floats(args.local_from_cam, 7, "the pose")
            p = req.local_from_cam
            p.translation.x, p.translation.y, p.translation.z = t[0:3]
            p.quaternion.w, p.quaternion.x, p.quaternion.y, p.quaternion.z = t[3:7]
            out = stub.CompleteView(req, timeout=120)
        elif args.cmd == "list":
            out = stub.ListRegions(pb.ListRegionsRequest(), timeout=30)
        else:
            out = stub.ClearRegion(pb.ClearRegionRequest(region_id=args.id), timeout=30)
    except grpc.RpcError as e:
        print(json.dumps({"error": e.code().name, "message": e.details()}))
        return 1
    print(json_format.MessageToJson(out, preserving_proto_field_name=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
