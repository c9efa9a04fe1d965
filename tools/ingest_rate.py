#!/usr/bin/python3
"""Ingest rate of the product path on real frames: a real exoview_server (defaults unless --server_arg)
on loopback, exoview_uploader --format=7scenes at --rate_hz, then the server's GetStats counters
(per-stage process ms, planning apply / plan ms, accepted / dropped). Prints one JSON line.

  tools/ingest_rate.py [--build build] [--data ../shared/data/7scenes-redkitchen] [--rate_hz 30]
                       [--server_arg=--stage_queue=32 ...] [--repeats 1]
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "client", "python"))


def start_server(server_bin, args, workdir, log_name="server.log"):
    port_file = os.path.join(workdir, "port")
    if os.path.exists(port_file):
        os.remove(port_file)
    log = open(os.path.join(workdir, log_name), "w")
    proc = subprocess.Popen([server_bin,
                             "--listen=127.0.0.1:0", "--port_file=" + port_file] + list(args),
                            stdout=log, stderr=subprocess.STDOUT)
    for _ in range(300):
        if os.path.exists(port_file):
            return proc, "127.0.0.1:%s" % open(port_file).read().strip()
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    proc.kill()
    sys.exit("exoview_server did not start (log: %s)" % os.path.join(workdir, log_name))


def get_stats(target, stubs_dir, wait_processed=None, timeout_s=120):
    import exoview_stubs
    exoview_stubs.load(stubs_dir)
    import grpc
    import exoview_pb2 as pb
    import exoview_pb2_grpc as pb_grpc
    from google.protobuf import json_format
    with grpc.insecure_channel(target) as ch:
        stub = pb_grpc.ExoviewStub(ch)
        deadline = time.monotonic() + timeout_s
        while True:
            s = stub.GetStats(pb.StatsRequest(), timeout=10)
            if (wait_processed is None or s.frames_processed >= s.frames_accepted
                    or time.monotonic() > deadline):
                break
            time.sleep(0.1)
        return json_format.MessageToDict(s, preserving_proto_field_name=True)


def thread_cpu_s(pid):
    """CPU seconds (user + system) per thread name of a live process (Linux /proc)."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for tid in os.listdir("/proc/%d/task" % pid):
        try:
            comm = open("/proc/%d/task/%s/comm" % (pid, tid)).read().strip()
            f = open("/proc/%d/task/%s/stat" % (pid, tid)).read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        name = comm if comm.startswith("exo-") else "other"
        out[name] = out.get(name, 0.0) + (int(f[11]) + int(f[12])) / tick
    return out


def loadavg():
    return round(os.getloadavg()[0], 2)


def run_once(args, workdir):
    load_before = loadavg()
    server, target = start_server(args.server_bin or os.path.join(args.build, "server", "app",
                                                                  "exoview_server"),
                                  args.server_arg, workdir)
    try:
        up_json = os.path.join(workdir, "up.json")
        cmd = [os.path.join(args.build, "client", "uploader", "exoview_uploader"),
               "--server=" + target, "--dataset=" + args.data, "--format=7scenes",
               "--rate_hz=%g" % args.rate_hz, "--stats_json=" + up_json] + args.uploader_arg
        t0 = time.monotonic()
        ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        up_s = time.monotonic() - t0
        up_cpu_s = (ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime)
        stats = get_stats(target, os.path.join(args.build, "client", "python", "stubs"),
                          wait_processed=True)
        acks = json.load(open(up_json))
        cpu = thread_cpu_s(server.pid)
        # the process total (threads that ended are in the process's own counters)
        f = open("/proc/%d/stat" % server.pid).read().rsplit(")", 1)[1].split()
        cpu["process_total"] = (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
    finally:
        server.terminate()
        server.wait(60)
    c = stats.get("counters", {})
    pick = {k: round(v, 3) for k, v in sorted(c.items())
            if k.endswith("_ms_mean") or k.endswith("_ms_max") or k.endswith("_ms_total")
            or k.endswith("_per_accepted") or k in ("geometry.voxel_m", "planning.cell_m",
                                                    "planning.cell_areas_set", "planning.views")}
    return {"accepted": acks.get("accepted"), "dropped": acks.get("dropped"),
            "rejected": acks.get("rejected"), "sent": acks.get("sent"),
            "upload_s": round(up_s, 2), "frames_processed": int(stats.get("frames_processed", 0)),
            "server_cpu_ms_per_frame": {k: round(1000.0 * v / max(1, acks.get("accepted") or 1), 2)
                                        for k, v in sorted(cpu.items())},
            "uploader_cpu_ms_per_frame": round(1000.0 * up_cpu_s / 300.0, 2),
            "load_1min_before": load_before, "load_1min_after": loadavg(), "counters": pick}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--data", default=os.path.join(ROOT, "..", "shared", "data",
                                                   "7scenes-redkitchen"))
    ap.add_argument("--server_bin", default="", help="default: BUILD/server/app/exoview_server")
    ap.add_argument("--rate_hz", type=float, default=30.0)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--server_arg", action="append", default=[],
                    help="extra exoview_server flag (repeatable), e.g. --server_arg=--stage_queue=32")
    ap.add_argument("--uploader_arg", action="append", default=[],
                    help="extra exoview_uploader flag (repeatable)")
    ap.add_argument("--label", default="")
    args = ap.parse_args()
    if not os.path.exists(os.path.join(args.data, "camera-intrinsics.txt")):
        sys.exit("no 7-Scenes data at %s" % args.data)
    for rep in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="exo_ingest_rate_") as d:
            r = run_once(args, d)
        r.update({"bench": "ingest_rate", "label": args.label, "server_bin": args.server_bin, "repeat": rep,
                  "rate_hz": args.rate_hz, "server_args": args.server_arg,
                  "cpus": os.cpu_count()})
        print(json.dumps(r), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
