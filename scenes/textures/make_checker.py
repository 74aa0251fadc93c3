"""Writes checker.png, the texture of scenes/textured.toml: 64 × 64 8-bit sRGB texels in
8 × 8 checks of two colours, with a 16-texel stripe along the top edge so that a render shows
which way up the texture is. Standard library only.

    python3 make_checker.py [OUT]
"""
import struct
import sys
import zlib

SIZE = 64
LIGHT, DARK, STRIPE = (230, 214, 170), (60, 90, 140), (190, 40, 30)


def texel(x, y):
    if y < 8:
        return STRIPE
    return LIGHT if (x // 8 + y // 8) % 2 == 0 else DARK


def chunk(kind, data):
    body = kind + data
    return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))


def main(out):
    rows = b"".join(b"\0" + bytes(c for x in range(SIZE) for c in texel(x, y)) for y in range(SIZE))
    png = (b"\x89PNG\r\n\x1a\n"
           + chunk(b"IHDR", struct.pack(">IIBBBBB", SIZE, SIZE, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(rows, 9))
           + chunk(b"IEND", b""))
    with open(out, "wb") as f:
        f.write(png)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "checker.png")
