#!/usr/bin/env python3
"""Rate and distortion of stereolink's frames against stock image codecs, on
the Middlebury pairs, in one run: PSNR of the pair at equal bytes, and the
Bjontegaard delta rate (BD-rate) of ours against each anchor.

Each of the 20 shared scenes is scaled to 320x240 (Pillow, Lanczos; the
aspect ratio changes a little, as a 320x240 camera would frame the scene),
and coded at each budget (bytes per pair, default 4000 6000 8000 10000
12000 16000):
  * ours: `stereolink encode --json --bytes N` with `--view-coding
    segmented` (k-means, 2 up to --levels 16 classes), `jpeg` and `webp`,
    the lossy ones with `--stereo-prediction off` and `on` (`+stereo`);
    the bytes are the whole frame message (header, fields, both views);
  * anchors: JPEG (libjpeg, optimised Huffman tables, 4:2:0), WebP
    (libwebp, method 6) and AVIF (Pillow's AVIF plugin, speed 6) through
    Pillow, each view a file, both views at the same quality, the highest
    whose two files fit the budget together.
PSNR is over the pair: both views against the scaled originals, one MSE.
A budget below a coding's smallest frame gives no point for it.

BD-rate (Bjontegaard, VCEG-M33): log-rate as a cubic in PSNR for each
curve, the mean difference over the PSNR range both cover; negative means
ours needs fewer bytes for the same PSNR. It is computed per scene (where
the curves have 4 or more points and overlap) and averaged over scenes.

    cargo build --release -p stereolink && python3 bench/rd_vs_codecs.py [DATA_DIR] [--scenes a,b] [--budgets 4000,8000]

Needs `pip install pillow numpy` (Pillow 11.3 or later for AVIF).
"""
import io
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image, features

SCENES = ["tsukuba", "venus", "teddy", "cones", "art", "books", "dolls", "laundry", "moebius", "reindeer",
          "adirondack", "jadeplant", "motorcycle", "piano", "pipes", "playroom", "playtable", "recycle",
          "shelves", "vintage"]
BUDGETS = [4000, 6000, 8000, 10000, 12000, 16000]
SIZE = (320, 240)
BIN = os.environ.get("STEREOLINK_BIN", "target/release/stereolink")
OURS = {
    "segmented": ["--view-coding", "segmented", "--method", "kmeans", "--levels", "16"],
    "jpeg": ["--view-coding", "jpeg", "--stereo-prediction", "off"],
    "webp": ["--view-coding", "webp", "--stereo-prediction", "off"],
    "jpeg+stereo": ["--view-coding", "jpeg", "--stereo-prediction", "on"],
    "webp+stereo": ["--view-coding", "webp", "--stereo-prediction", "on"],
}
ANCHORS = {
    "JPEG": ("JPEG", dict(optimize=True, subsampling=2), range(1, 96)),
    "WebP": ("WEBP", dict(method=6), range(0, 101)),
    "AVIF": ("AVIF", dict(speed=6), range(0, 101)),
}


def pair_psnr(orig, coded):
    a = np.concatenate([np.asarray(o, dtype=np.float64) for o in orig])
    b = np.concatenate([np.asarray(c, dtype=np.float64) for c in coded])
    mse = np.mean((a - b) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def anchor_point(pair, fmt, kw, qualities, budget):
    """The highest quality whose two files fit `budget`: (bytes, PSNR) or None."""
    def code(q):
        files = []
        for im in pair:
            buf = io.BytesIO()
            im.save(buf, format=fmt, quality=q, **kw)
            files.append(buf.getvalue())
        return files
    qs = list(qualities)
    lo, hi, best = 0, len(qs) - 1, None
    while lo <= hi:
        mid = (lo + hi) // 2
        files = code(qs[mid])
        if sum(map(len, files)) <= budget:
            best, lo = files, mid + 1
        else:
            hi = mid - 1
    if best is None:
        return None
    decoded = [Image.open(io.BytesIO(f)).convert("RGB") for f in best]
    return sum(map(len, best)), pair_psnr(pair, decoded)


def ours_point(paths, flags, budget, tmp):
    out = os.path.join(tmp, "frame.slnk")
    r = subprocess.run([BIN, "--json", "encode", paths[0], paths[1], "-o", out, "--bytes", str(budget), *flags],
                       capture_output=True, text=True)
    if r.returncode != 0:
        if "below the smallest frame" in r.stderr:
            return None
        raise RuntimeError(r.stderr)
    e = json.loads(r.stdout)
    if e.get("left_view_bytes"):
        LEFT.setdefault((flags[1], paths[0]), set()).add((e["left_view_bytes"], e["psnr_db"][0]))
    return e["bytes"], e["psnr_pair_db"]


# (codec, left image) -> {(left view bytes, left view PSNR)}: the left view's
# own curve, from every lossy frame coded (the left view is coded alone, at
# the frame's quality, with and without stereo prediction).
LEFT = {}


def bd_rate(anchor, test):
    """Bjontegaard delta rate of `test` against `anchor` ([(bytes, psnr)]), in %."""
    if len(anchor) < 4 or len(test) < 4:
        return None
    (ra, pa), (rt, pt) = [np.array(sorted(c, key=lambda p: p[1])).T for c in (anchor, test)]
    lo, hi = max(pa.min(), pt.min()), min(pa.max(), pt.max())
    if hi <= lo:
        return None
    fa, ft = np.polyfit(pa, np.log(ra), 3), np.polyfit(pt, np.log(rt), 3)
    ia, it = np.polyint(fa), np.polyint(ft)
    mean_diff = ((np.polyval(it, hi) - np.polyval(it, lo)) - (np.polyval(ia, hi) - np.polyval(ia, lo))) / (hi - lo)
    return (np.exp(mean_diff) - 1) * 100


def main():
    args = sys.argv[1:]
    scenes, budgets = SCENES, BUDGETS
    if "--scenes" in args:
        i = args.index("--scenes")
        scenes = args[i + 1].split(",")
        del args[i:i + 2]
    if "--budgets" in args:
        i = args.index("--budgets")
        budgets = [int(b) for b in args[i + 1].split(",")]
        del args[i:i + 2]
    data = args[0] if args else os.environ.get("STEREOLINK_DATA", "../shared/data/middlebury")
    anchors = {k: v for k, v in ANCHORS.items() if k != "AVIF" or features.check("avif")}
    if "AVIF" not in anchors:
        print("warning: this Pillow has no AVIF support; AVIF is left out", file=sys.stderr)
    names = list(OURS) + list(anchors)
    curves = {n: {} for n in names}  # name -> scene -> budget -> (bytes, psnr)
    print(f"{'scene':<11} {'budget':>6}  " + "  ".join(f"{n:>16}" for n in names))
    for scene in scenes:
        pair = [Image.open(os.path.join(data, scene, f"{v}.png")).convert("RGB").resize(SIZE, Image.LANCZOS)
                for v in ("left", "right")]
        with tempfile.TemporaryDirectory() as tmp:
            paths = [os.path.join(tmp, f"{scene}_{v}.png") for v in ("left", "right")]
            for im, p in zip(pair, paths):
                im.save(p)
            for budget in budgets:
                row = {}
                for n, flags in OURS.items():
                    row[n] = ours_point(paths, flags, budget, tmp)
                for n, (fmt, kw, qs) in anchors.items():
                    row[n] = anchor_point(pair, fmt, kw, qs, budget)
                for n, p in row.items():
                    if p is not None:
                        curves[n].setdefault(scene, {})[budget] = p
                cells = [f"{p[0]:>6} B {p[1]:5.2f} dB" if p else f"{'-':>16}" for p in row.values()]
                print(f"{scene:<11} {budget:>6}  " + "  ".join(cells), flush=True)
    print()
    print("mean pair PSNR (dB) and bytes per budget (scenes with a point, of " f"{len(scenes)}):")
    print(f"{'budget':>8}  " + "  ".join(f"{n:>21}" for n in names))
    for budget in budgets:
        cells = []
        for n in names:
            pts = [curves[n][s][budget] for s in scenes if budget in curves[n].get(s, {})]
            cells.append(f"{np.mean([p[1] for p in pts]):5.2f} dB {np.mean([p[0] for p in pts]):6.0f} B ({len(pts):>2})"
                         if pts else f"{'-':>21}")
        print(f"{budget:>8}  " + "  ".join(cells))
    print()
    print("BD-rate of ours against each anchor (%, mean over scenes; negative: ours needs fewer bytes):")
    for ours in OURS:
        for anchor in anchors:
            rates = [r for s in scenes
                     if (r := bd_rate(list(curves[anchor].get(s, {}).values()),
                                      list(curves[ours].get(s, {}).values()))) is not None]
            if rates:
                print(f"  {ours:<9} vs {anchor:<4}: {np.mean(rates):+7.1f} %  (median {np.median(rates):+7.1f} %, "
                      f"{len(rates)} scenes)")
            else:
                print(f"  {ours:<9} vs {anchor:<4}: no overlapping curves")
    print()
    print("pair / left view bytes at equal PSNR (the pair's curve against its left view's alone, "
          "1 + BD-rate; mean over scenes):")
    for ours, flags in OURS.items():
        if flags[1] == "segmented":
            continue
        ratios = []
        for scene in scenes:
            left = [p for (codec, path), pts in LEFT.items() if codec == flags[1] and f"/{scene}_" in path
                    for p in pts]
            r = bd_rate(sorted(left), list(curves[ours].get(scene, {}).values()))
            if r is not None:
                ratios.append(1 + r / 100)
        if ratios:
            print(f"  {ours:<12}: {np.mean(ratios):.2f}x (median {np.median(ratios):.2f}x, {len(ratios)} scenes)")


if __name__ == "__main__":
    main()
