#!/usr/bin/python3
"""Independent reader of exoview_export's output (numpy + struct, no Exoview code): parses the
binary PLY from its header, the TUM trajectory and the COLMAP text model, and checks them against
each other and against export.json. Prints a JSON summary; exits 1 naming the first failed check.

    tools/export/read_exports.py EXPORT_DIR [--views N] [--require_open3d]

Checks: PLY vertex/face counts match the header and export.json, every face is a triangle with
indices in range, normals are unit length; Open3D (Debian python3-open3d), when it imports,
reads the same PLY with the same counts, positions and normals; TUM has one line per stored view with unit
quaternions; COLMAP images.txt has the same views, each the inverse of its TUM pose
(R_cw = R_wc^T, t_cw = -R_wc^T t_wc), a 2D-points line each, PINHOLE cameras with 4 parameters,
and points3D.txt holds no points.
"""
import argparse
import json
import os
import struct
import sys

import numpy as np

PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4",
             "uint": "<u4", "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1",
             "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4",
             "float32": "<f4", "float64": "<f8"}


class CheckError(Exception):
    pass


def check(cond, what):
    if not cond:
        raise CheckError(what)


def read_ply(path):
    data = open(path, "rb").read()
    end = data.find(b"end_header\n")
    check(data.startswith(b"ply\n") and end > 0, f"{path}: not a PLY file")
    elements = []
    for line in data[:end].decode("ascii").splitlines():
        w = line.split()
        if not w:
            continue
        if w[0] == "format":
            check(w[1] == "binary_little_endian", f"PLY format {w[1]}")
        elif w[0] == "element":
            elements.append({"name": w[1], "count": int(w[2]), "props": []})
        elif w[0] == "property":
            elements[-1]["props"].append(w[1:])
    off = end + len(b"end_header\n")
    out = {}
    for e in elements:
        if e["name"] == "vertex":
            check(all(p[0] != "list" for p in e["props"]), "vertex lists are not expected")
            dt = np.dtype([(p[1], PLY_TYPES[p[0]]) for p in e["props"]])
            v = np.frombuffer(data, dtype=dt, count=e["count"], offset=off)
            off += dt.itemsize * e["count"]
            out["vertex"] = v
        elif e["name"] == "face":
            check(len(e["props"]) == 1 and e["props"][0][0] == "list", "face: one list property")
            _, ctype, itype, _ = e["props"][0]
            csize, isize = np.dtype(PLY_TYPES[ctype]).itemsize, np.dtype(PLY_TYPES[itype]).itemsize
            faces = []
            for _ in range(e["count"]):
                (n,) = struct.unpack_from("<" + {1: "B", 2: "H", 4: "I"}[csize], data, off)
                off += csize
                faces.append(np.frombuffer(data, dtype=PLY_TYPES[itype], count=n, offset=off))
                off += n * isize
            out["face"] = faces
        else:
            raise CheckError(f"unexpected PLY element {e['name']}")
    check(off == len(data), f"PLY: {len(data) - off} bytes after the last element")
    return out


def quat_to_matrix(w, x, y, z):
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def read_with_open3d(path, positions, normals, faces):
    """The same PLY through Open3D, when installed: returns its version, or None."""
    try:
        import open3d as o3d
    except ImportError:
        return None
    m = o3d.io.read_triangle_mesh(path)
    pv, tv = np.asarray(m.vertices), np.asarray(m.triangles)
    check(len(pv) == len(positions), f"Open3D reads {len(pv)} vertices, ours {len(positions)}")
    check(len(tv) == len(faces), f"Open3D reads {len(tv)} triangles, ours {len(faces)}")
    check(m.has_vertex_normals(), "Open3D finds no vertex normals")
    check(np.abs(pv - positions).max() < 1e-9, "Open3D positions differ")
    check(np.abs(np.asarray(m.vertex_normals) - normals).max() < 1e-6, "Open3D normals differ")
    check((tv == faces).all(), "Open3D triangles differ")
    return o3d.__version__


def data_lines(path, keep_empty=False):
    with open(path, encoding="ascii") as f:
        return [ln.rstrip("\n") for ln in f
                if not ln.startswith("#") and (keep_empty or ln.strip())]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dir")
    ap.add_argument("--views", type=int, default=None, help="expected number of stored views")
    ap.add_argument("--require_open3d", action="store_true",
                    help="fail when Open3D cannot be imported (deploy/bootstrap.sh installs it)")
    a = ap.parse_args()
    d = a.dir
    summary = json.load(open(os.path.join(d, "export.json"), encoding="utf-8"))

    ply = read_ply(os.path.join(d, "mesh.ply"))
    v = ply["vertex"]
    nv, nf = len(v), len(ply["face"])
    check(nv == summary["mesh_vertices"], f"PLY vertices {nv} != export.json {summary['mesh_vertices']}")
    check(nf == summary["mesh_triangles"], f"PLY faces {nf} != export.json {summary['mesh_triangles']}")
    check(nv > 0 and nf > 0, "empty mesh")
    faces = np.stack(ply["face"]) if nf else np.zeros((0, 3), int)
    check(faces.shape[1] == 3, "a face is not a triangle")
    check(faces.min() >= 0 and faces.max() < nv, "face index out of range")
    check(len(np.unique(faces)) == nv, "a vertex is used by no face")
    n = np.stack([v["nx"], v["ny"], v["nz"]], axis=1).astype(np.float64)
    norm_err = float(np.abs(np.linalg.norm(n, axis=1) - 1).max())
    check(norm_err < 1e-5, f"normals not unit length (max error {norm_err})")
    p = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    check(np.isfinite(p).all(), "non-finite vertex")
    open3d = read_with_open3d(os.path.join(d, "mesh.ply"), p, n, faces)
    check(open3d or not a.require_open3d, "Open3D is not installed (apt-get install python3-open3d)")

    tum = [ln.split() for ln in data_lines(os.path.join(d, "trajectory.tum"))]
    check(all(len(t) == 8 for t in tum), "TUM line without 8 columns")
    if a.views is not None:
        check(len(tum) == a.views, f"TUM lines {len(tum)} != stored views {a.views}")
    check(len(tum) == summary["views"], "TUM lines != export.json views")
    poses = {}
    for t in tum:
        vals = [float(x) for x in t]
        tx, ty, tz, qx, qy, qz, qw = vals[1:]
        check(abs(np.linalg.norm([qx, qy, qz, qw]) - 1) < 1e-9, "TUM quaternion not unit")
        poses[int(vals[0])] = (quat_to_matrix(qw, qx, qy, qz), np.array([tx, ty, tz]))

    cams = {}
    for ln in data_lines(os.path.join(d, "colmap", "cameras.txt")):
        w = ln.split()
        check(w[1] == "PINHOLE" and len(w) == 8, f"camera line {ln!r}")
        cams[int(w[0])] = [float(x) for x in w[4:]]
    img_lines = data_lines(os.path.join(d, "colmap", "images.txt"), keep_empty=True)
    check(len(img_lines) == 2 * len(tum), f"images.txt has {len(img_lines)} lines, expected 2 per view")
    max_r, max_t = 0.0, 0.0
    for i in range(0, len(img_lines), 2):
        w = img_lines[i].split()
        check(len(w) == 10, f"image line {img_lines[i]!r}")
        check(img_lines[i + 1].strip() == "", "2D points line not empty")
        iid, (qw, qx, qy, qz, tx, ty, tz), cid = int(w[0]), map(float, w[1:8]), int(w[8])
        check(iid in poses, f"image {iid} has no TUM pose")
        check(cid in cams, f"image {iid}: unknown camera {cid}")
        r_cw, t_cw = quat_to_matrix(qw, qx, qy, qz), np.array([tx, ty, tz])
        r_wc, t_wc = poses[iid]
        max_r = max(max_r, float(np.abs(r_cw - r_wc.T).max()))
        max_t = max(max_t, float(np.abs(t_cw + r_wc.T @ t_wc).max()))
    check(max_r < 1e-9, f"COLMAP rotation is not the inverse of TUM's (max error {max_r})")
    check(max_t < 1e-6, f"COLMAP translation is not the inverse of TUM's (max error {max_t})")
    check(not data_lines(os.path.join(d, "colmap", "points3D.txt")), "points3D.txt is not empty")

    print(json.dumps({"vertices": nv, "faces": nf, "normal_max_error": norm_err,
                      "open3d": open3d, "views": len(tum), "colmap_cameras": len(cams),
                      "colmap_inverse_max_rot_error": max_r, "colmap_inverse_max_t_error": max_t,
                      "bbox_min": p.min(axis=0).round(3).tolist(),
                      "bbox_max": p.max(axis=0).round(3).tolist()}))


if __name__ == "__main__":
    try:
        main()
    except CheckError as e:
        print(f"read_exports: FAILED: {e}", file=sys.stderr)
        sys.exit(1)
