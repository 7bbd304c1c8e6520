#!/usr/bin/env python3
"""Sizes of segmented Middlebury views: stereolink's label coder against the
best indexed PNG and zstd -19 of the raw label map, in one run.

For each 2001-2005 scene of the shared data and each method (k-means k=3,
FO-DPSO 3 levels per channel) it segments the left view with
`stereolink segment`, then measures:
  * best PNG: the segmented image as an indexed (palette) PNG, Pillow with
    optimize=True at compress_level 9, and OpenCV PNG with every strategy;
    the smallest wins;
  * zstd -19 of the raw label map (one byte per pixel);
  * ours: `stereolink bench codec` (left view alone, right view alone and
    conditioned on the left), label maps in the strong mode unless
    `--mode fast` is given; the right view stereo-consistent (labels carried
    over from the left, the default) unless `--independent-right` is given;
and prints bits per pixel, the ratios, the conditioned gain with the right
view's PSNR against the original right image, and the pair's reduction
against the original PNG files beside the paper's 79-86 % (PSO family) /
51-62 % (k-means).

    cargo build --release && python3 bench/codec_vs_png.py [DATA_DIR] [--mode fast|strong] [--independent-right]

Needs `pip install pillow numpy opencv-python-headless zstandard`.
"""
import io
import json
import os
import subprocess
import sys
import tempfile

import cv2
import numpy as np
import zstandard
from PIL import Image

SCENES = ["tsukuba", "venus", "teddy", "cones", "art", "books", "dolls", "laundry", "moebius", "reindeer"]
BIN = "target/release/stereolink"


def best_png(rgb):
    colours, labels = np.unique(rgb.reshape(-1, 3), axis=0, return_inverse=True)
    labels = labels.reshape(rgb.shape[:2]).astype(np.uint8)
    im = Image.fromarray(labels, mode="P")
    im.putpalette(colours.astype(np.uint8).flatten().tolist())
    sizes = []
    buf = io.BytesIO()
    im.save(buf, format="PNG", optimize=True, compress_level=9)
    sizes.append(len(buf.getvalue()))
    for strategy in range(5):
        ok, enc = cv2.imencode(".png", labels, [cv2.IMWRITE_PNG_COMPRESSION, 9, cv2.IMWRITE_PNG_STRATEGY, strategy])
        if ok:
            sizes.append(len(enc) + 3 * len(colours) + 12)  # plus a PLTE chunk
    return min(sizes), labels


def main():
    args = sys.argv[1:]
    mode = "strong"
    right = []
    if "--independent-right" in args:
        args.remove("--independent-right")
        right = ["--independent-right"]
    if "--mode" in args:
        i = args.index("--mode")
        mode = args[i + 1]
        del args[i:i + 2]
    data = args[0] if args else os.environ.get("STEREOLINK_DATA", "../shared/data/middlebury")
    print(f"label coding mode: {mode}; right view {'independent' if right else 'stereo-consistent'}")
    print(f"{'scene':<9} {'method':<7} {'ours bpp':>8} {'PNG bpp':>8} {'zstd bpp':>8} {'PNG/ours':>8} {'zstd/ours':>9} "
          f"{'cond gain':>9} {'right PSNR':>10} {'pair reduction':>14}")
    totals = {}
    for name in SCENES:
        folder = os.path.join(data, name)
        originals = os.path.getsize(os.path.join(folder, "left.png")) + os.path.getsize(os.path.join(folder, "right.png"))
        for method in ["kmeans", "fodpso"]:
            with tempfile.TemporaryDirectory() as tmp:
                out = os.path.join(tmp, "seg.png")
                subprocess.run([BIN, "segment", os.path.join(folder, "left.png"), "-o", out, "--method", method,
                                "--levels", "3"], check=True, capture_output=True)
                rgb = np.asarray(Image.open(out).convert("RGB"))
            png, labels = best_png(rgb)
            zstd = len(zstandard.ZstdCompressor(level=19).compress(labels.tobytes()))
            r = json.loads(subprocess.run([BIN, "--json", "bench", "codec", "--scene", folder, "--method", method,
                                           "--levels", "3", "--iters", "3", "--mode", mode] + right, check=True, capture_output=True,
                                          text=True).stdout)
            px = labels.size
            ours = r["bytes_left"]
            reduction = 100.0 * (1 - r["frame_bytes"] / originals)
            totals.setdefault(method, []).append((png / ours, zstd / ours, r["conditioned_gain_percent"], reduction,
                                                  r["psnr_right_db"]))
            print(f"{name:<9} {method:<7} {8 * ours / px:8.3f} {8 * png / px:8.3f} {8 * zstd / px:8.3f} {png / ours:8.2f} "
                  f"{zstd / ours:9.2f} {r['conditioned_gain_percent']:8.1f}% {r['psnr_right_db']:7.3f} dB {reduction:13.2f}%")
    for method, rows in totals.items():
        a = np.array(rows)
        print(f"mean {method:<7}: PNG/ours {a[:, 0].mean():.3f}, zstd/ours {a[:, 1].mean():.3f}, "
              f"conditioned gain {a[:, 2].mean():.1f} % (right PSNR {a[:, 4].mean():.3f} dB), pair reduction {a[:, 3].mean():.2f} % "
              f"(paper: {'51.48-61.54' if method == 'kmeans' else '79.49-86.00'} %)")


if __name__ == "__main__":
    main()
