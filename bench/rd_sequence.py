#!/usr/bin/env python3
"""Rate and distortion of stereolink's streams against x264, on stereo
sequences at 10 pairs/s: PSNR and SSIM of the pairs at equal bit rates, and
the Bjontegaard delta rate (BD-rate) of ours against x264.

Two sequences are built from one Middlebury scene (default: adirondack),
scaled so that a 320x240 window covers most of it, each view with fresh
Gaussian sensor noise (sigma 2 grey levels) on every pair:
  * `fixed`: a fixed rig filming a still scene, the window still;
  * `pan`: the rig panning, the window sliding 2 px right and 1 px down a
    pair.
Each is coded:
  * ours: `stereolink encode SEQ -o OUT --view-coding webp --bytes N`, the
    stream coding of `send --temporal`: a key frame, then frames predicted
    from the one before (blocks within the noise skipped), every frame at
    most N bytes; the bytes are the frame messages';
  * x264 (Debian's ffmpeg): each view a stream at half the total rate,
    `-preset medium -tune zerolatency`, 4:2:0, its rate capped with a 1 s
    buffer (`-maxrate`, `-bufsize`: a radio link's constraint), the raw
    H.264 bitstreams' bytes; at the bit rates ours reached, and at a half
    and a quarter of them, so that the curves meet.
PSNR is over the pair, one MSE for both views, averaged over the pairs;
SSIM (scikit-image, on the RGB views) is averaged over the views and pairs.
Both are against the noisy views as coded. The bit rate is the bytes of
the whole sequence over its duration at 10 pairs/s. BD-rate: as
bench/rd_vs_codecs.py computes it, over the bit rates.

    cargo build --release -p stereolink && python3 bench/rd_sequence.py
        [--scene DIR] [--budgets 2500,3500,5000,7000,10000] [--sequences fixed,pan]

Needs ffmpeg with libx264 (Debian's `ffmpeg`) and `pip install pillow numpy
scikit-image`.
"""
import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image
from skimage.metrics import structural_similarity

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rd_vs_codecs import bd_rate  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("STEREOLINK_DATA", os.path.join(ROOT, "..", "shared", "data", "middlebury"))
SIZE = (320, 240)
RATE = 10.0


def make_sequence(scene, out, pairs, pan, sigma=2.0, seed=1):
    """Writes left_NNNN.png/right_NNNN.png into `out`: a 320x240 window on
    the scene scaled to 300 px high, still or sliding (2, 1) px a pair."""
    views = []
    for side in ("left", "right"):
        im = Image.open(os.path.join(scene, f"{side}.png")).convert("RGB")
        w, h = im.size
        views.append(np.asarray(im.resize((w * 300 // h, 300), Image.LANCZOS), dtype=np.float32))
    rng = np.random.default_rng(seed)
    for i in range(pairs):
        x, y = (2 * i, i) if pan else (0, 0)
        for side, v in zip(("left", "right"), views):
            crop = v[y:y + SIZE[1], x:x + SIZE[0]]
            assert crop.shape[:2] == (SIZE[1], SIZE[0]), "the scene is too small to pan over"
            noisy = np.clip(crop + rng.normal(0, sigma, crop.shape), 0, 255).astype(np.uint8)
            Image.fromarray(noisy).save(os.path.join(out, f"{side}_{i + 1:04d}.png"))


def load(folder, pattern):
    return [np.asarray(Image.open(p).convert("RGB")) for p in sorted(glob.glob(os.path.join(folder, pattern)))]


def quality(orig, coded):
    """Mean pair PSNR and mean SSIM of `coded` ([(left, right)]) against `orig`."""
    psnrs, ssims = [], []
    for (ol, orr), (cl, cr) in zip(orig, coded):
        a = np.concatenate([ol, orr]).astype(np.float64)
        b = np.concatenate([cl, cr]).astype(np.float64)
        mse = np.mean((a - b) ** 2)
        psnrs.append(99.0 if mse == 0 else 10 * np.log10(255.0 ** 2 / mse))
        for o, c in ((ol, cl), (orr, cr)):
            ssims.append(structural_similarity(o, c, channel_axis=2, data_range=255))
    return float(np.mean(psnrs)), float(np.mean(ssims))


def ours_point(binary, seq, budget, tmp):
    out, dec = os.path.join(tmp, f"ours-{budget}"), os.path.join(tmp, f"ours-{budget}-dec")
    r = subprocess.run([binary, "--json", "encode", seq, "-o", out, "--view-coding", "webp", "--bytes", str(budget)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        if "below the smallest frame" in r.stderr:
            return None
        raise RuntimeError(r.stderr)
    frames = json.loads(r.stdout)["frames"]
    subprocess.run([binary, "decode", out, "--out", dec], check=True, capture_output=True)
    total = sum(f["bytes"] for f in frames)
    return total, dec, sum(f["kind"] == "key" for f in frames)


def x264_point(seq, kbps, tmp):
    """Both views coded at kbps/2 each; returns (bytes, decoded folder)."""
    dec = os.path.join(tmp, f"x264-{kbps:.1f}")
    os.makedirs(dec, exist_ok=True)
    total = 0
    for side in ("left", "right"):
        stream = os.path.join(tmp, f"{side}-{kbps:.1f}.h264")
        rate = f"{kbps / 2:.2f}k"
        subprocess.run(["ffmpeg", "-loglevel", "error", "-y", "-framerate", str(RATE),
                        "-i", os.path.join(seq, f"{side}_%04d.png"), "-c:v", "libx264", "-preset", "medium",
                        "-tune", "zerolatency", "-b:v", rate, "-maxrate", rate, "-bufsize", rate,
                        "-pix_fmt", "yuv420p", "-f", "h264", stream], check=True)
        total += os.path.getsize(stream)
        subprocess.run(["ffmpeg", "-loglevel", "error", "-y", "-i", stream,
                        os.path.join(dec, f"{side}_%04d.png")], check=True)
    return total, dec


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=os.path.join(DATA, "adirondack"))
    ap.add_argument("--budgets", default="2500,3500,5000,7000,10000",
                    help="ours: the most bytes a frame may take, one stream each")
    ap.add_argument("--pairs", type=int, default=30)
    ap.add_argument("--sequences", default="fixed,pan", help="the sequences to code, of fixed and pan")
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "stereolink"))
    args = ap.parse_args()
    budgets = [int(b) for b in args.budgets.split(",")]
    results = {}
    for name, pan in (("fixed", False), ("pan", True)):
        if name not in args.sequences.split(","):
            continue
        with tempfile.TemporaryDirectory() as tmp:
            seq = os.path.join(tmp, "seq")
            os.makedirs(seq)
            make_sequence(args.scene, seq, args.pairs, pan)
            orig = list(zip(load(seq, "left_*.png"), load(seq, "right_*.png")))
            seconds = len(orig) / RATE
            ours, x264 = [], []
            for b in budgets:
                p = ours_point(args.bin, seq, b, tmp)
                if p is None:
                    continue
                total, dec, keys = p
                kbps = total * 8 / seconds / 1e3
                psnr, ssim = quality(orig, list(zip(load(dec, "left_*.png"), load(dec, "right_*.png"))))
                ours.append({"budget": b, "kbps": kbps, "psnr": psnr, "ssim": ssim, "key_frames": keys})
                print(f"{name:5s} ours budget {b:6d}: {kbps:7.1f} kb/s {psnr:6.2f} dB SSIM {ssim:.4f}", flush=True)
            # x264 at the rates ours reached, and at a half and a quarter of
            # them, so that its curve meets ours where x264 is far ahead.
            for kbps in sorted({round(p["kbps"] * f, 1) for p in ours for f in (0.25, 0.5, 1.0)}):
                xb, xdec = x264_point(seq, kbps, tmp)
                xpsnr, xssim = quality(orig, list(zip(load(xdec, "left_*.png"), load(xdec, "right_*.png"))))
                x264.append({"asked_kbps": kbps, "kbps": xb * 8 / seconds / 1e3, "psnr": xpsnr, "ssim": xssim})
                print(f"{name:5s} x264 at {kbps:7.1f}: {x264[-1]['kbps']:7.1f} kb/s {xpsnr:6.2f} dB"
                      f" SSIM {xssim:.4f}", flush=True)
            bd = bd_rate([(p["kbps"], p["psnr"]) for p in x264], [(p["kbps"], p["psnr"]) for p in ours])
            bd_ssim = bd_rate([(p["kbps"], p["ssim"]) for p in x264], [(p["kbps"], p["ssim"]) for p in ours])
            results[name] = {"ours": ours, "x264": x264, "bd_rate_psnr_pct": bd, "bd_rate_ssim_pct": bd_ssim}
            fmt = lambda v: "n/a" if v is None else f"{v:+.1f} %"
            print(f"{name}: BD-rate of ours against x264: {fmt(bd)} (PSNR), {fmt(bd_ssim)} (SSIM)", flush=True)
    print(json.dumps(results))


if __name__ == "__main__":
    main()
