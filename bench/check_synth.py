#!/usr/bin/env python3
"""Independent check of `stereolink synth` output, written without any stereolink code.

Reads left.png, right.png, gt_left.pfm and mask_nonocc.png with Pillow/NumPy,
warps the right view into the left with the ground truth (linear interpolation)
and prints the mean absolute difference on non-occluded pixels, next to the
difference with zero disparity and with the ground truth scaled by 0.9 and 1.1.
A correct ground truth gives a far smaller error than any of the alternatives.

    target/release/stereolink synth /tmp/syn && python3 bench/check_synth.py /tmp/syn
"""
import sys

import numpy as np
from PIL import Image


def read_pfm(path):
    with open(path, "rb") as f:
        magic = f.readline().strip()
        assert magic == b"Pf", magic
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4", count=w * h)
    return data.reshape(h, w)[::-1]


def warp_error(left, right, disp, mask):
    h, w = disp.shape
    xs = np.arange(w)[None, :] - disp
    valid = mask & (xs >= 0) & (xs <= w - 1)
    x0 = np.clip(np.floor(xs).astype(int), 0, w - 1)
    x1 = np.clip(x0 + 1, 0, w - 1)
    t = (xs - x0)[..., None]
    rows = np.arange(h)[:, None]
    warped = right[rows, x0] * (1 - t) + right[rows, x1] * t
    return np.abs(warped - left)[valid].mean()


def main(folder):
    left = np.asarray(Image.open(f"{folder}/left.png").convert("RGB"), dtype=np.float64)
    right = np.asarray(Image.open(f"{folder}/right.png").convert("RGB"), dtype=np.float64)
    gt = read_pfm(f"{folder}/gt_left.pfm")
    mask = np.asarray(Image.open(f"{folder}/mask_nonocc.png")) == 255
    errors = {name: warp_error(left, right, d, mask)
              for name, d in [("ground truth", gt), ("zero disparity", gt * 0),
                              ("0.9 x ground truth", gt * 0.9), ("1.1 x ground truth", gt * 1.1)]}
    for name, e in errors.items():
        print(f"{name:>20}: mean |left - warped right| = {e:.2f}")
    ok = all(errors["ground truth"] * 3 < e for n, e in errors.items() if n != "ground truth")
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "demo-scene"))
