#!/usr/bin/env python3
"""Segmentation speed and quality against the anchors, in one run, on Cones:

* exact multilevel Otsu (ours, DP) vs scikit-image `threshold_multiotsu`
  (brute force) at 5 classes on each of R, G, B; and ours up to 16 levels;
* FO-DPSO / DPSO / PSO: fitness over 20 seeds as a share of the exact optimum
  at 4 and 5 levels, and their times; and the time each needs to reach the
  same fitness (the paper's claim that FO-DPSO is faster);
* k-means k=3 (ours) vs scikit-learn `KMeans(n_clusters=3, n_init=1)` on the
  same pixels: time and objective J;
* mean shift (ours, h_s=20, h_r=40) vs OpenCV `pyrMeanShiftFiltering(20, 40)`,
  at its pyramid default (1 level) and without a pyramid.

    cargo build --release && python3 bench/segment_vs_anchors.py [DATA_DIR]
"""
import json
import os
import subprocess
import sys
import time

import cv2
import numpy as np
from skimage.filters import threshold_multiotsu
from sklearn.cluster import KMeans

BIN = "target/release/stereolink"


def ours(scene, method, levels, iters=5, seed=1, extra=()):
    out = subprocess.run([BIN, "--json", "bench", "segment", "--scene", scene, "--method", method, "--levels", str(levels),
                          "--iters", str(iters), "--seed", str(seed), *extra], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def timed(fn, iters=3):
    fn()
    ts = []
    for _ in range(iters):
        t = time.perf_counter()
        r = fn()
        ts.append((time.perf_counter() - t) * 1e3)
    return float(np.median(ts)), r


def main():
    data = sys.argv[1] if len(sys.argv) > 1 else os.environ.get("STEREOLINK_DATA", "../shared/data/middlebury")
    scene = os.path.join(data, "cones")
    rgb = cv2.cvtColor(cv2.imread(os.path.join(scene, "left.png")), cv2.COLOR_BGR2RGB)

    t_sk, _ = timed(lambda: [threshold_multiotsu(rgb[..., c], classes=5) for c in range(3)], iters=1)
    r = ours(scene, "otsu", 5)
    print(f"exact Otsu, 5 classes x 3 channels: scikit-image {t_sk:.0f} ms, ours {r['median_ms']:.2f} ms "
          f"-> {t_sk / r['median_ms']:.0f}x faster")
    for levels in (8, 16):
        print(f"exact Otsu, {levels} levels x 3 channels: ours {ours(scene, 'otsu', levels)['median_ms']:.2f} ms")

    for levels in (4, 5):
        for method in ("pso", "dpso", "fodpso"):
            fr, ms = [], []
            for seed in range(20):
                r = ours(scene, method, levels, iters=1, seed=seed)
                fr.append(r["fitness_fraction"])
                ms.append(r["median_ms"])
            print(f"{method:>6} {levels} levels, 20 seeds: median fitness {100 * np.median(fr):.3f} % of optimum "
                  f"(min {100 * min(fr):.3f} %), median time {np.median(ms):.2f} ms")

    # The paper's claim, FO-DPSO takes less time than PSO for the same
    # fitness: the fewest iterations (of a ladder) at which each method's
    # median fitness over 20 seeds reaches a share of the optimum, and the
    # median time of a run at that count.
    ladder = (5, 10, 20, 30, 50, 75, 100, 150, 200, 300)
    for levels in (4, 5):
        for share in (0.999, 0.9999):
            cells = []
            for method in ("pso", "dpso", "fodpso"):
                found = "not reached"
                for n in ladder:
                    runs = [ours(scene, method, levels, iters=1, seed=seed, extra=("--iterations", str(n)))
                            for seed in range(20)]
                    if np.median([r["fitness_fraction"] for r in runs]) >= share:
                        found = f"{n} it, {np.median([r['median_ms'] for r in runs]):.2f} ms"
                        break
                cells.append(f"{method} {found}")
            print(f"{levels} levels, median fitness >= {100 * share:g} % of optimum: " + "; ".join(cells))

    pixels = rgb.reshape(-1, 3).astype(np.float64)
    # Rounds alternate the two (each a median over 9 runs); the ratio is the
    # median of the rounds' ratios, the range their spread.
    rounds = []
    for _ in range(5):
        t_km, km = timed(lambda: KMeans(n_clusters=3, n_init=1, random_state=0).fit(pixels), iters=9)
        r = ours(scene, "kmeans", 3, iters=9)
        rounds.append((t_km, r["median_ms"]))
    ratios = [a / b for a, b in rounds]
    t_km, t_ours = np.median(rounds, axis=0)
    print(f"k-means k=3: scikit-learn {t_km:.1f} ms (J {km.inertia_:.4g}), ours {t_ours:.1f} ms "
          f"(J {r['objective']:.4g}) -> {np.median(ratios):.1f}x faster ({min(ratios):.1f}-{max(ratios):.1f}x "
          f"over 5 rounds), J ratio {r['objective'] / km.inertia_:.6f}")

    bgr = cv2.imread(os.path.join(scene, "left.png"))
    # Like for like: OpenCV's stopping rule (5 iterations, eps 1) on 8-bit
    # colour, and the same number of pyramid levels (OpenCV's maxLevel,
    # our --pyramid; 1 is the default of both, 0 filters every pixel).
    crit = (cv2.TERM_CRITERIA_MAX_ITER + cv2.TERM_CRITERIA_EPS, 5, 1)
    as_opencv = ("--colour-space", "rgb", "--threshold", "1", "--iterations", "5")
    for levels in (1, 0):
        t_cv, _ = timed(lambda: cv2.pyrMeanShiftFiltering(bgr, 20, 40, maxLevel=levels, termcrit=crit), iters=2)
        rows = [("as OpenCV (RGB, threshold 1, 5 iterations)", as_opencv)]
        if levels == 1:
            rows.insert(0, ("our defaults (L*u*v*, threshold 0.5, 8 iterations)", ()))
        for label, extra in rows:
            r = ours(scene, "meanshift", 3, iters=2,
                     extra=("--spatial", "20", "--range", "40", "--pyramid", str(levels), *extra))
            print(f"mean shift h_s=20 h_r=40, pyramid {levels}, {label}: OpenCV pyrMeanShiftFiltering "
                  f"{t_cv:.0f} ms, ours (filtering + clustering) {r['median_ms']:.0f} ms -> {t_cv / r['median_ms']:.2f}x")

if __name__ == "__main__":
    main()
