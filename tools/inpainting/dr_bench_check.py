#!/usr/bin/python3
"""dr_bench smoke test (issue 18): runs dr_bench on a short, small apartment walk around the
removable chair and checks that ours (keyframes + 3D look-up in the views that observed the
background) beats every per-frame baseline and the session-9 keyframe warp in ROI PSNR / SSIM,
depth MAE and flicker. Usage: dr_bench_check.py DR_BENCH [extra dr_bench args]."""
import json
import subprocess
import sys


def main():
    if len(sys.argv) < 2:
        print(__doc__)
        return 2
    cmd = [sys.argv[1], "--scene", "apartment", "--frames", "40", "--width", "160",
           "--height", "120"] + sys.argv[2:]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=240).stdout
    d = json.loads(out)
    m = d["methods"]
    ours = m["ours"]
    failures = []
    for base in ("telea", "ns", "pm", "kf_warp"):
        b = m[base]
        for key, higher in (("psnr_roi", True), ("ssim_roi", True), ("depth_mae_mm", False),
                            ("flicker_ratio", False)):
            better = ours[key] > b[key] if higher else ours[key] < b[key]
            print(f"{key:14s} ours {ours[key]:8.3f} {base:8s} {b[key]:8.3f} {'ok' if better else 'WORSE'}")
            if not better:
                failures.append(f"{key}: ours {ours[key]} vs {base} {b[key]}")
    if d["ours"]["keyframes"] < 2 or d["ours"]["observed_fraction_between_keyframes"] <= 0.2:
        failures.append(f"ours: too few keyframes or observations: {d['ours']}")
    if failures:
        print("FAILED:\n  " + "\n  ".join(failures))
        return 1
    print("dr_bench_check: ours beats every baseline on the short apartment walk")
    return 0


if __name__ == "__main__":
    sys.exit(main())
