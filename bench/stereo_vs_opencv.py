#!/usr/bin/env python3
"""Speed and accuracy of stereolink's matchers against OpenCV, in one run.

For each Middlebury v2 scene (Tsukuba, Venus, Teddy, Cones) it times OpenCV
StereoBM (numDisparities 64, blockSize 9) and StereoSGBM 3-way (blockSize 5),
and `stereolink bench match` for WTA and SGM at the same disparity range
(64), and prints the time ratios and the bad-pixel rates (> 1 px,
non-occluded, invalid counts as bad). The timings are taken in rounds that
alternate the anchor and ours (each a median over --iters runs); a ratio is
the median of the rounds' ratios, so load that comes and goes on a shared
machine falls on both sides alike.

    cargo build --release && python3 bench/stereo_vs_opencv.py [DATA_DIR] [--iters N] [--rounds R]

Needs `pip install opencv-python-headless numpy`.
"""
import argparse
import json
import os
import subprocess
import time

import cv2
import numpy as np

SCENES = ["tsukuba", "venus", "teddy", "cones"]
SCALES = {"tsukuba": 16, "venus": 8, "teddy": 4, "cones": 4}
NDISP = 64


def median_ms(fn, iters):
    fn()
    times = []
    for _ in range(iters):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return float(np.median(times))


def bad1(disp, folder, scale):
    gt = cv2.imread(os.path.join(folder, "gt_left.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    mask = cv2.imread(os.path.join(folder, "mask_nonocc.png"), cv2.IMREAD_GRAYSCALE) == 255
    known = (gt > 0) & mask
    gt = gt / scale
    invalid = ~np.isfinite(disp) | (disp < 0)
    bad = invalid | (np.abs(disp - gt) > 1.0)
    return 100.0 * bad[known].mean()


def ours(binary, folder, algo, iters, extra=()):
    out = subprocess.run(
        [binary, "--json", "bench", "match", "--scene", folder, "--algo", algo,
         "--max-disp", str(NDISP - 1), "--iters", str(iters), *extra],
        check=True, capture_output=True, text=True).stdout
    r = json.loads(out)
    return r["median_ms"], r["bad_1_nonocc"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("data", nargs="?", default=os.environ.get("STEREOLINK_DATA", "../shared/data/middlebury"))
    ap.add_argument("--iters", type=int, default=15)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--binary", default="target/release/stereolink")
    a = ap.parse_args()
    cv2.setNumThreads(os.cpu_count())
    bm = cv2.StereoBM_create(numDisparities=NDISP, blockSize=9)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=NDISP, blockSize=5,
                                 P1=8 * 5 * 5, P2=32 * 5 * 5, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    # WTA is timed twice: with its default refinement (LR check, colour-
    # weighted median, fill), which the accuracy column scores, and raw (the
    # matcher alone, as StereoBM is mostly its matcher).
    print(f"{'scene':<8} {'BM ms':>7} {'WTA ms':>7} {'ratio':>6} {'raw ms':>7} {'ratio':>6} |"
          f" {'SGBM ms':>7} {'SGM ms':>7} {'ratio':>6} | bad1: {'BM':>6} {'WTA':>6} {'SGBM':>6} {'SGM':>6}")
    for name in SCENES:
        folder = os.path.join(a.data, name)
        l = cv2.imread(os.path.join(folder, "left.png"), cv2.IMREAD_GRAYSCALE)
        r = cv2.imread(os.path.join(folder, "right.png"), cv2.IMREAD_GRAYSCALE)
        lc = cv2.imread(os.path.join(folder, "left.png"))
        rc = cv2.imread(os.path.join(folder, "right.png"))
        d_bm = bm.compute(l, r).astype(np.float32) / 16.0
        d_sgbm = sgbm.compute(lc, rc).astype(np.float32) / 16.0
        rounds = []
        for _ in range(a.rounds):
            t_bm = median_ms(lambda: bm.compute(l, r), a.iters)
            t_wta, b_wta = ours(a.binary, folder, "wta", a.iters)
            t_raw, _ = ours(a.binary, folder, "wta", a.iters, ["--raw"])
            t_sgbm = median_ms(lambda: sgbm.compute(lc, rc), a.iters)
            t_sgm, b_sgm = ours(a.binary, folder, "sgm", a.iters)
            rounds.append((t_bm, t_wta, t_raw, t_sgbm, t_sgm))
        t_bm, t_wta, t_raw, t_sgbm, t_sgm = np.median(np.array(rounds), axis=0)
        r_wta, r_raw, r_sgm = np.median([(w / b, raw / b, sg / sb) for b, w, raw, sb, sg in rounds], axis=0)
        s = SCALES[name]
        print(f"{name:<8} {t_bm:7.2f} {t_wta:7.2f} {r_wta:6.2f} {t_raw:7.2f} {r_raw:6.2f} |"
              f" {t_sgbm:7.2f} {t_sgm:7.2f} {r_sgm:6.2f} |"
              f"       {bad1(d_bm, folder, s):6.2f} {b_wta:6.2f} {bad1(d_sgbm, folder, s):6.2f} {b_sgm:6.2f}")


if __name__ == "__main__":
    main()
