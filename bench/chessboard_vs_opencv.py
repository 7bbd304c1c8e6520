#!/usr/bin/env python3
"""Chessboard corners: stereolink's detector against OpenCV, in the same run.

Usage (from the workspace root):

    python3 bench/chessboard_vs_opencv.py [--data DIR] [--board 9x6] [--repeat 3]

DIR defaults to $STEREOLINK_CALIB_DATA/ximea-9x6 or ../shared/data/calibration/ximea-9x6.
Builds and runs `cargo run --release -p stereolink-calib --example corners` on
every left*/right* image and OpenCV's findChessboardCorners (adaptive threshold
+ normalise) + cornerSubPix (winSize (11,11), i.e. 23x23, zeroZone (-1,-1), EPS+MAX_ITER 30, 0.001),
one thread each (cv2.setNumThreads(1)), and prints: detections of each (of
all images), RMS and max corner difference left and right on the images both
detect (also without corners more than 1 px apart, which are listed: one
detector's outliers), whether corner k is the same board corner in both
(ordering), and the time per image (reading excluded; best of --repeat runs,
the two alternating so both see the same machine load).
Needs opencv-python-headless and numpy.
"""
import argparse
import glob
import json
import os
import subprocess
import sys
import time

import cv2
import numpy as np


def opencv_corners(files, board):
    cv2.setNumThreads(1)
    images = [cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in files]
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    out = {}
    start = time.perf_counter()
    for f, g in zip(files, images):
        ok, c = cv2.findChessboardCorners(g, board, flags)
        if ok:
            c = cv2.cornerSubPix(g, c, (11, 11), (-1, -1), criteria)
            out[f] = c.reshape(-1, 2)
        else:
            out[f] = None
    return out, 1000.0 * (time.perf_counter() - start) / len(files)


def our_corners(files, board, root, sigma=None):
    cmd = ["cargo", "run", "--quiet", "--release", "-p", "stereolink-calib", "--example", "corners",
           "--", "--board", f"{board[0]}x{board[1]}"]
    if sigma is not None:
        cmd += ["--subpix-sigma", str(sigma)]
    cmd += files
    res = subprocess.run(cmd, cwd=root, capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"corners example failed:\n{res.stderr}")
    report = json.loads(res.stdout)
    out = {f: (None if c is None else np.array(c)) for f, c in report["files"].items()}
    return out, report["ms_per_image"]


def main():
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    default = os.path.join(os.environ.get("STEREOLINK_CALIB_DATA",
                                          os.path.join(root, "..", "shared", "data", "calibration")),
                           "ximea-9x6")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=default)
    ap.add_argument("--board", default="9x6")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--subpix-sigma", type=float, default=None,
                    help="our refinement's gradient smoothing (default: the detector's; 0 is cornerSubPix's)")
    args = ap.parse_args()
    board = tuple(int(v) for v in args.board.lower().split("x"))
    files = sorted(glob.glob(os.path.join(args.data, "left*.jpg")) +
                   glob.glob(os.path.join(args.data, "right*.jpg")))
    if not files:
        sys.exit(f"no left*/right* .jpg images in {args.data}")

    ours_runs, cv_runs = [], []
    for _ in range(max(args.repeat, 1)):
        ours_runs.append(our_corners(files, board, root, args.subpix_sigma))
        cv_runs.append(opencv_corners(files, board))
    ours, ours_ms = ours_runs[0][0], min(r[1] for r in ours_runs)
    cv, cv_ms = cv_runs[0][0], min(r[1] for r in cv_runs)

    n = len(files)
    print(f"detections: ours {sum(v is not None for v in ours.values())}/{n}, "
          f"OpenCV {sum(v is not None for v in cv.values())}/{n}")
    for side in ("left", "right"):
        diffs, same_order, both, outliers = [], 0, 0, []
        for f in files:
            if not os.path.basename(f).startswith(side) or ours[f] is None or cv[f] is None:
                continue
            both += 1
            d = np.linalg.norm(ours[f] - cv[f], axis=1)
            # Same order: corner k is OpenCV's corner k (median well under a
            # square; a single corner far off is one detector's outlier).
            if np.median(d) < 3.0:
                same_order += 1
                diffs.append(d)
                outliers += [f"{os.path.basename(f)}#{k} ({d[k]:.2f} px)" for k in np.where(d > 1.0)[0]]
        d = np.concatenate(diffs) if diffs else np.array([np.nan])
        inl = d[d <= 1.0]
        print(f"{side:5}: {both} images detected by both, same order in {same_order}; "
              f"corner difference RMS {np.sqrt(np.mean(d ** 2)):.4f} px, max {d.max():.4f} px "
              f"over {d.size} corners; without the {d.size - inl.size} corner(s) > 1 px apart: "
              f"RMS {np.sqrt(np.mean(inl ** 2)):.4f} px, max {inl.max():.4f} px")
        if outliers:
            print(f"       corners > 1 px apart: {', '.join(outliers)}")
    print(f"time per image: ours {ours_ms:.2f} ms, OpenCV {cv_ms:.2f} ms "
          f"(OpenCV / ours = {cv_ms / ours_ms:.1f}x)")


if __name__ == "__main__":
    main()
