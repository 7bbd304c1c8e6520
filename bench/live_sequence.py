#!/usr/bin/env python3
"""Live over the calibrated radio: a fixed rig filmed at 10 pairs/s, played
through `stereolink bench live` (sender, simulated radio in real time, board
and axis in one process).

The sequence is one Middlebury scene (default: adirondack), cropped to 4:3
and scaled to 320x240 (its calib.txt scaled with it), each pair with fresh
Gaussian sensor noise (default sigma 2 grey levels), as a fixed camera rig
sees a still scene. Prints the sender's and the receiver's figures: reports
a second and their capture-to-axis latency (p50, p99), frames a second and
bytes.

    python3 bench/live_sequence.py [--scene DIR] [--pairs 60] [--rate 10]
        [--link 'sim:?radio=zigbee'] [--method kmeans --levels 3] [-- extra args]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("STEREOLINK_DATA", os.path.join(ROOT, "..", "shared", "data", "middlebury"))
SIZE = (320, 240)


def read_calib(path):
    calib = {}
    for line in open(path):
        if "=" in line:
            k, v = line.strip().split("=", 1)
            calib[k] = v
    return calib


def cam(text):
    rows = [r.split() for r in text.strip("[]").split(";")]
    return [[float(v) for v in r] for r in rows]


def make_sequence(scene, out, pairs, sigma, seed):
    """Writes left_NNNN.png/right_NNNN.png and calib.txt into `out`."""
    left, right = (Image.open(os.path.join(scene, f"{s}.png")).convert("RGB") for s in ("left", "right"))
    w, h = left.size
    cw = min(w, h * 4 // 3)
    ch = cw * 3 // 4
    scale = SIZE[0] / cw
    views = [np.asarray(v.crop((0, 0, cw, ch)).resize(SIZE, Image.LANCZOS), dtype=np.float32) for v in (left, right)]
    rng = np.random.default_rng(seed)
    for i in range(1, pairs + 1):
        for side, v in zip(("left", "right"), views):
            noisy = np.clip(v + rng.normal(0, sigma, v.shape), 0, 255).astype(np.uint8)
            Image.fromarray(noisy).save(os.path.join(out, f"{side}_{i:04d}.png"))
    c = read_calib(os.path.join(scene, "calib.txt"))
    m0, m1 = cam(c["cam0"]), cam(c["cam1"])
    f, cx0, cx1, cy = m0[0][0] * scale, m0[0][2] * scale, m1[0][2] * scale, m0[1][2] * scale
    ndisp = int(round(int(c["ndisp"]) * scale))
    with open(os.path.join(out, "calib.txt"), "w") as fh:
        fh.write(f"cam0=[{f:.3f} 0 {cx0:.3f}; 0 {f:.3f} {cy:.3f}; 0 0 1]\n")
        fh.write(f"cam1=[{f:.3f} 0 {cx1:.3f}; 0 {f:.3f} {cy:.3f}; 0 0 1]\n")
        fh.write(f"doffs={cx1 - cx0:.3f}\nbaseline={c['baseline']}\n")
        fh.write(f"width={SIZE[0]}\nheight={SIZE[1]}\nndisp={ndisp}\n")
    return ndisp


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=os.path.join(DATA, "adirondack"))
    ap.add_argument("--pairs", type=int, default=60)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--sigma", type=float, default=2.0)
    ap.add_argument("--link", default="sim:?radio=zigbee")
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "stereolink"))
    ap.add_argument("extra", nargs="*", help="more `bench live` arguments (after --)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ndisp = make_sequence(a.scene, tmp, a.pairs, a.sigma, 1)
        cmd = [a.bin, "--json", "bench", "live", "--sequence", tmp, "--rate", str(a.rate),
               "--link", a.link, "--calib", os.path.join(tmp, "calib.txt"),
               "--max-disp", str(ndisp - 1)] + a.extra
        print("$", " ".join(cmd), file=sys.stderr)
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    r = json.loads(out)
    for end in ("sender", "receiver"):
        f = r[end]
        lat = f.get("report_latency_ms") or {}
        print(f"{end:8}: {f['reports']} reports, {f['report_rate_hz']:.1f}/s, latency p50 "
              f"{lat.get('p50', float('nan')):.0f} ms, p99 {lat.get('p99', float('nan')):.0f} ms; "
              f"{f['frames']} frames, {f['frame_rate_hz']:.2f}/s; {f['bytes']} B in {f['seconds']:.1f} s")
    s = r["sender"]
    print(f"pairs {s['pairs']} in, {s['skipped']} skipped, {s['superseded']} reports superseded, "
          f"{s['retransmissions']} retransmissions; receiver refused {r['refused']}, "
          f"watchdog tripped {r['watchdog_trips']} times")


if __name__ == "__main__":
    main()
