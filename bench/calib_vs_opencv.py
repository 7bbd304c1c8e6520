#!/usr/bin/env python3
"""Stereo calibration against OpenCV, on the same images in one run.

    cargo build --release
    pip install opencv-python-headless numpy
    python3 bench/calib_vs_opencv.py [--data ../shared/data/calibration/ximea-9x6] [--threads 1]

OpenCV runs the tool chain of the data's MANIFEST.md (findChessboardCorners
with adaptive threshold and normalisation, cornerSubPix 11x11, calibrateCamera
per camera, stereoCalibrate with CALIB_USE_INTRINSIC_GUESS, stereoRectify
alpha 0); stereolink runs `stereolink calibrate --json`. Both read the JPEGs
from disk, both are timed end to end (best of --rounds), with --threads
threads each. The script prints both sides' figures, their differences and
the time ratio, and checks that OpenCV loads our YAML file.
"""
import argparse, glob, json, os, subprocess, sys, tempfile, time

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def opencv(left, right, board):
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE
    corners = {"left": [], "right": []}
    ok_pairs = []
    for i, (l, r) in enumerate(zip(left, right)):
        found = []
        for side, path in (("left", l), ("right", r)):
            g = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
            ok, c = cv2.findChessboardCorners(g, board, flags)
            if ok:
                c = cv2.cornerSubPix(g, c, (11, 11), (-1, -1), crit)
            found.append(c if ok else None)
        if all(f is not None for f in found):
            ok_pairs.append(i)
            corners["left"].append(found[0])
            corners["right"].append(found[1])
    size = g.shape[::-1]
    obj = np.zeros((board[0] * board[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0:board[0], 0:board[1]].T.reshape(-1, 2)
    objs = [obj] * len(ok_pairs)
    rl, m1, d1, _, _ = cv2.calibrateCamera(objs, corners["left"], size, None, None)
    rr, m2, d2, _, _ = cv2.calibrateCamera(objs, corners["right"], size, None, None)
    rs, m1, d1, m2, d2, R, T, _, _ = cv2.stereoCalibrate(
        objs, corners["left"], corners["right"], m1, d1, m2, d2, size, flags=cv2.CALIB_USE_INTRINSIC_GUESS)
    r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(m1, d1, m2, d2, size, R, T, alpha=0)
    dy = []
    for cl, cr in zip(corners["left"], corners["right"]):
        ul = cv2.undistortPoints(cl, m1, d1, R=r1, P=p1).reshape(-1, 2)
        ur = cv2.undistortPoints(cr, m2, d2, R=r2, P=p2).reshape(-1, 2)
        dy.extend(np.abs(ul[:, 1] - ur[:, 1]))
    return {
        "pairs": len(ok_pairs),
        "rms": (rl, rr, rs),
        "f": (m1[0, 0], m1[1, 1], m2[0, 0], m2[1, 1]),
        "baseline": float(np.linalg.norm(T)),
        "rect_f": p1[0, 0],
        "row_offset": (float(np.mean(dy)), float(np.max(dy))),
    }


def ours(exe, left, right, board, out):
    cmd = [exe, "--json", "calibrate", "--board", f"{board[0]}x{board[1]}", "--square", "1",
           "--left", *left, "--right", *right, "-o", out]
    res = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
    return {
        "pairs": res["pairs_used"],
        "rms": (res["left"]["rms_px"], res["right"]["rms_px"], res["stereo_rms_px"]),
        "f": (res["left"]["fx"], res["left"]["fy"], res["right"]["fx"], res["right"]["fy"]),
        "baseline": res["baseline"],
        "rect_f": res["rectified_focal_px"],
        "row_offset": (res["mean_row_offset_px"], res["max_row_offset_px"]),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=os.path.join(ROOT, "..", "shared", "data", "calibration", "ximea-9x6"))
    ap.add_argument("--board", default="9x6")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--exe", default=os.path.join(ROOT, "target", "release", "stereolink"))
    a = ap.parse_args()
    board = tuple(int(v) for v in a.board.split("x"))
    left = sorted(glob.glob(os.path.join(a.data, "left*.jpg")))
    right = sorted(glob.glob(os.path.join(a.data, "right*.jpg")))
    cv2.setNumThreads(a.threads)
    os.environ["RAYON_NUM_THREADS"] = str(a.threads)
    out = os.path.join(tempfile.mkdtemp(), "stereo.yml")
    t_cv, t_us = [], []
    for _ in range(a.rounds):  # alternate, so both see the same machine load
        t = time.perf_counter(); cv = opencv(left, right, board); t_cv.append(time.perf_counter() - t)
        t = time.perf_counter(); us = ours(a.exe, left, right, board, out); t_us.append(time.perf_counter() - t)

    rows = [
        ("pairs with both boards", cv["pairs"], us["pairs"], None),
        ("left RMS (px)", cv["rms"][0], us["rms"][0], "le"),
        ("right RMS (px)", cv["rms"][1], us["rms"][1], "le"),
        ("stereo RMS (px)", cv["rms"][2], us["rms"][2], "le"),
        ("left fx", cv["f"][0], us["f"][0], "pct"),
        ("left fy", cv["f"][1], us["f"][1], "pct"),
        ("right fx", cv["f"][2], us["f"][2], "pct"),
        ("right fy", cv["f"][3], us["f"][3], "pct"),
        ("baseline (squares)", cv["baseline"], us["baseline"], "pct"),
        ("rectified focal (px)", cv["rect_f"], us["rect_f"], "pct"),
        ("mean |dy| rectified (px)", cv["row_offset"][0], us["row_offset"][0], "le"),
        ("max |dy| rectified (px)", cv["row_offset"][1], us["row_offset"][1], "le"),
        ("time, best of rounds (s)", min(t_cv), min(t_us), "le"),
    ]
    print(f"{len(left)} pairs from {a.data}, {a.threads} thread(s)")
    print(f"{'quantity':<28}{'OpenCV':>12}{'stereolink':>12}  comparison")
    for name, c, s, kind in rows:
        if kind == "pct":
            cmp = f"{100 * (s / c - 1):+.3f} %"
        elif kind == "le":
            cmp = f"ratio {s / c:.3f} ({'met' if s <= c else 'NOT met'}: at most OpenCV's)"
        else:
            cmp = "" if c == s else "differs"
        print(f"{name:<28}{c:>12.4f}{s:>12.4f}  {cmp}")
    fs = cv2.FileStorage(out, cv2.FILE_STORAGE_READ)
    names = ["M1", "D1", "M2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q"]
    missing = [n for n in names if fs.getNode(n).empty()]
    print("OpenCV reads our stereo.yml:", "yes, all of " + ", ".join(names) if not missing else f"NO, missing {missing}")
    return 0 if not missing else 1


if __name__ == "__main__":
    sys.exit(main())
