"""Crops of denoised renders beside the raw ones and the reference, for the report of where
Open Image Denoise loses detail (bench/denoise-crops.sh runs it; docs/benchmarks/ holds its
output).

Usage: denoise_crops.py OUT.png NAME:REF.exr:LOW.exr:HIGH.exr:X,Y,W,H [more crops ...]

LOW.exr is a render with `--denoise` (its beauty and its `denoised` layer), HIGH.exr a raw render
at more samples. Each crop becomes one row of the PNG: reference | raw LOW | denoised LOW | raw
HIGH, each tone-mapped as `tessera render --preview` maps it (ACES, then sRGB) and scaled up 3×
by pixel replication, so that the pixels stay visible. Each crop's relMSE against the
reference is printed as a Markdown table for the report.
"""
import sys

import numpy as np
import OpenEXR
from PIL import Image

ZOOM = 3
GAP = 4


def layer(path, name):
    """The RGB layer `name` ("RGB" for the beauty) of an EXR file, as float32 (H, W, 3)."""
    channels = OpenEXR.File(path).parts[0].channels
    if name not in channels:
        sys.exit(f"{path}: no {name} layer (was it rendered with --denoise?)")
    return np.asarray(channels[name].pixels, dtype=np.float32)


def shown(rgb):
    """8-bit sRGB as previews show it: Narkowicz's ACES fit, then the sRGB curve."""
    x = np.clip(np.nan_to_num(rgb, nan=0.0, posinf=0.0), 0.0, None)
    x = np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (s * 255.0 + 0.5).clip(0, 255).astype(np.uint8)


def rel_mse(img, ref):
    """The bench's relMSE: mean of (I − R)²/(R² + 0.01) over pixels and channels."""
    return float(np.mean((img - ref) ** 2 / (ref * ref + 0.01)))


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    out = sys.argv[1]
    rows = []
    print("| crop | pixels | relMSE raw low | relMSE denoised low | relMSE raw high |")
    print("|---|---|---:|---:|---:|")
    for spec in sys.argv[2:]:
        name, ref, low, high, box = spec.split(":")
        x, y, w, h = (int(v) for v in box.split(","))
        cut = lambda a: a[y:y + h, x:x + w]
        images = [cut(layer(ref, "RGB")), cut(layer(low, "RGB")), cut(layer(low, "denoised")),
                  cut(layer(high, "RGB"))]
        errors = [rel_mse(i, images[0]) for i in images[1:]]
        print(f"| {name} | {w}×{h} at ({x}, {y}) | " + " | ".join(f"{e:.3e}" for e in errors) + " |")
        rows.append([np.kron(shown(i), np.ones((ZOOM, ZOOM, 1), dtype=np.uint8)) for i in images])
    width = max(sum(i.shape[1] for i in r) + GAP * (len(r) - 1) for r in rows)
    height = sum(r[0].shape[0] for r in rows) + GAP * (len(rows) - 1)
    sheet = Image.new("RGB", (width, height), (255, 255, 255))
    top = 0
    for r in rows:
        left = 0
        for i in r:
            sheet.paste(Image.fromarray(i), (left, top))
            left += i.shape[1] + GAP
        top += r[0].shape[0] + GAP
    sheet.save(out, optimize=True)


if __name__ == "__main__":
    main()
