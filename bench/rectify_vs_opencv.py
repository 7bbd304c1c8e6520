#!/usr/bin/env python3
"""Rectification speed and agreement of stereolink against OpenCV, in one run.

It builds a synthetic C-310-like rig (distortion, turned cameras, 6 cm
baseline), rectifies it with cv2.stereoRectify and writes it with
cv2.FileStorage (theirs.yml). `stereolink rectify --export` reads theirs and
writes ours (stereo.yml, left.yaml, right.yaml); cv2 must read ours back with
the same matrices, and our rectified views must agree with cv2.remap's.

Then, for gray and RGB 640x480 pairs, it times cv2.initUndistortRectifyMap
(CV_16SC2) maps applied with cv2.remap(INTER_LINEAR) to both views, with
cv2.setNumThreads(1), and `stereolink bench rectify --threads 1`, in rounds
that alternate the two (each a median over --iters pairs); a ratio is the
median of the rounds' ratios, so load that comes and goes on a shared
machine falls on both sides alike.

    cargo build --release -p stereolink && python3 bench/rectify_vs_opencv.py [--iters N] [--rounds R]

Needs `pip install opencv-python-headless numpy`.
"""
import argparse
import json
import os
import subprocess
import tempfile
import time

import cv2
import numpy as np

SIZE = (640, 480)
KEYS = ["M1", "D1", "M2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q"]


def rig():
    m1 = np.array([[670.5, 0, 322.0], [0, 668.0, 238.25], [0, 0, 1]])
    m2 = np.array([[668.0, 0, 318.5], [0, 667.5, 241.0], [0, 0, 1]])
    d1 = np.array([[-0.3, 0.12, 0.001, -0.0015, -0.02]])
    d2 = np.array([[-0.28, 0.1, 0.0005, -0.001, -0.01]])
    r = cv2.Rodrigues(np.array([0.004, -0.012, 0.002]))[0]
    t = np.array([[-0.06], [0.0005], [0.001]])
    r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(m1, d1, m2, d2, SIZE, r, t, alpha=0)
    return dict(M1=m1, D1=d1, M2=m2, D2=d2, R=r, T=t, R1=r1, R2=r2, P1=p1, P2=p2, Q=q)


def write_theirs(path, c):
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", SIZE[0])
    fs.write("image_height", SIZE[1])
    for k in KEYS:
        fs.write(k, c[k])
    fs.release()


def read(path, keys):
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
    assert fs.isOpened(), f"cv2 cannot open {path}"
    out = {k: fs.getNode(k).mat() for k in keys}
    fs.release()
    return out


def scene_image(seed):
    """A textured 640x480 colour view: smoothed noise at a few scales."""
    rng = np.random.default_rng(seed)
    img = np.zeros((SIZE[1], SIZE[0], 3), np.float32)
    for scale in (4, 16, 64):
        small = rng.random((SIZE[1] // scale + 2, SIZE[0] // scale + 2, 3)).astype(np.float32)
        img += cv2.resize(small, (SIZE[0] + 2 * scale, SIZE[1] + 2 * scale),
                          interpolation=cv2.INTER_CUBIC)[scale:-scale, scale:-scale]
    img -= img.min()
    return (255 * img / img.max()).astype(np.uint8)


def median_min_ms(fn, iters):
    fn()
    times = []
    for _ in range(iters):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return float(np.median(times)), float(np.min(times))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--binary", default=os.path.join(
        os.environ.get("CARGO_TARGET_DIR", "target"), "release", "stereolink"))
    ap.add_argument("--iters", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    tmp = tempfile.mkdtemp(prefix="rectify-bench-")
    c = rig()
    theirs = os.path.join(tmp, "theirs.yml")
    write_theirs(theirs, c)
    left, right = scene_image(1), scene_image(2)
    lp, rp = os.path.join(tmp, "left.png"), os.path.join(tmp, "right.png")
    cv2.imwrite(lp, left)
    cv2.imwrite(rp, right)

    # Files: we read theirs, cv2 reads ours.
    out = os.path.join(tmp, "out")
    subprocess.run([args.binary, "rectify", lp, rp, "--calib", theirs, "-o", out, "--export"],
                   check=True, capture_output=True)
    ours = read(os.path.join(out, "stereo.yml"), KEYS + ["E", "F"])
    worst = max(float(np.abs(ours[k].reshape(-1) - c[k].reshape(-1)).max()) for k in KEYS)
    x_l = np.array([0.2, -0.1, 1.8])
    x_r = c["R"] @ x_l + c["T"].reshape(-1)
    epi = float((x_r / x_r[2]) @ ours["E"] @ (x_l / x_l[2]))
    print(f"cv2 reads our stereo.yml: {len(KEYS)} matrices, largest difference from theirs "
          f"{worst:.3g}; epipolar residual of our E {epi:.2e}")
    try:
        import yaml  # ROS's own loader is PyYAML
        for side, p in (("left", "P1"), ("right", "P2")):
            with open(os.path.join(out, side + ".yaml")) as f:
                info = yaml.safe_load(f)
            got = np.array(info["projection_matrix"]["data"]).reshape(3, 4)
            print(f"PyYAML reads our {side}.yaml (ROS camera_info, {info['distortion_model']}): "
                  f"projection_matrix differs from {p} by {np.abs(got - c[p]).max():.3g}")
    except ImportError:
        print("PyYAML not installed: the ROS camera_info check is skipped")

    # The rectified views: ours against cv2.remap with the same maps.
    maps = []
    for m, d, r, p in (("M1", "D1", "R1", "P1"), ("M2", "D2", "R2", "P2")):
        maps.append(cv2.initUndistortRectifyMap(c[m], c[d], c[r], c[p], SIZE, cv2.CV_16SC2))
    for name, raw, (m1, m2) in (("left", left, maps[0]), ("right", right, maps[1])):
        cv = cv2.remap(raw, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        us = cv2.imread(os.path.join(out, name + ".png"))
        diff = np.abs(cv.astype(int) - us.astype(int))
        print(f"{name}: our rectified view vs cv2.remap: max difference {diff.max()}, "
              f"{100 * (diff > 1).mean():.3f} % of samples differ by more than 1")

    gray = [cv2.cvtColor(v, cv2.COLOR_BGR2GRAY) for v in (left, right)]
    glp, grp = os.path.join(tmp, "gl.png"), os.path.join(tmp, "gr.png")
    cv2.imwrite(glp, gray[0])
    cv2.imwrite(grp, gray[1])

    def cv_pair(views):
        return lambda: [cv2.remap(v, m1, m2, cv2.INTER_LINEAR) for v, (m1, m2) in zip(views, maps)]

    rows = {"gray": [], "rgb": []}
    for _ in range(args.rounds):
        cv_gray = median_min_ms(cv_pair(gray), args.iters)
        cv_rgb = median_min_ms(cv_pair((left, right)), args.iters)
        r = json.loads(subprocess.run(
            [args.binary, "--json", "bench", "rectify", "--calib", theirs, "--left", lp,
             "--right", rp, "--iters", str(args.iters), "--threads", "1"],
            check=True, capture_output=True, text=True).stdout)
        rows["gray"].append(((r["gray_median_ms"], r["gray_min_ms"]), cv_gray))
        rows["rgb"].append(((r["rgb_median_ms"], r["rgb_min_ms"]), cv_rgb))
    print(f"\nrectify a {SIZE[0]}x{SIZE[1]} pair, one thread, {args.rounds} rounds x "
          f"{args.iters} pairs: median of the rounds' medians, and the fastest pair "
          f"(what a quiet core does; the medians carry the machine's load)")
    print(f"{'':6} {'stereolink ms':>14} {'cv2.remap ms':>13} {'ratio':>6} "
          f"{'fastest: ours':>14} {'cv2':>7} {'ratio':>6}")
    for kind, rs in rows.items():
        ours_ms = float(np.median([a[0] for a, _ in rs]))
        cv_ms = float(np.median([b[0] for _, b in rs]))
        ratio = float(np.median([a[0] / b[0] for a, b in rs]))
        ours_min = min(a[1] for a, _ in rs)
        cv_min = min(b[1] for _, b in rs)
        print(f"{kind:6} {ours_ms:14.3f} {cv_ms:13.3f} {ratio:6.2f} "
              f"{ours_min:14.3f} {cv_min:7.3f} {ours_min / cv_min:6.2f}")


if __name__ == "__main__":
    main()
