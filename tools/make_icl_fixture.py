#!/usr/bin/env python3
"""Make the ICL-NUIM point cloud fixtures in fixtures/icl_nuim/ from the Augmented ICL-NUIM
livingroom1 depth PNGs (Python 3 standard library only).

Each depth PNG (640x480, 16-bit grayscale, millimetres) is back-projected with the pinhole
intrinsics below into the camera frame (x right, y down, z forward, metres), keeping every
`--stride`-th pixel in u and v and skipping zero (invalid) depth, and written as a binary
little-endian float32 PLY (x, y, z). The ground-truth trajectory.log (camera-to-world per
frame) is copied next to the clouds.

Usage (from the repository root):
    python3 tools/make_icl_fixture.py --data ../shared/data/icl_nuim_livingroom1/rgbd5 \
        --out fixtures/icl_nuim --frames 0 4 --stride 2
"""

import argparse
import os
import shutil
import struct
import sys
import zlib

FX = 525.0  # focal length [px]
FY = 525.0  # focal length [px]
CX = 319.5  # principal point [px]
CY = 239.5  # principal point [px]
DEPTH_SCALE = 1000.0  # PNG units per metre (millimetres)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    if pa <= pb and pa <= pc:
        return a
    return b if pb <= pc else c


def read_png_gray16(path):
    """Decode a non-interlaced 16-bit grayscale PNG; return (width, height, rows of ints)."""
    with open(path, "rb") as f:
        data = f.read()
    if not data.startswith(PNG_SIGNATURE):
        raise ValueError(f"{path}: not a PNG file")
    pos = len(PNG_SIGNATURE)
    ihdr = None
    idat = []
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        ctype = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        if len(body) != length:
            raise ValueError(f"{path}: truncated {ctype!r} chunk")
        (crc,) = struct.unpack(">I", data[pos + 8 + length : pos + 12 + length])
        if zlib.crc32(ctype + body) & 0xFFFFFFFF != crc:
            raise ValueError(f"{path}: CRC mismatch in {ctype!r} chunk")
        pos += 12 + length
        if ctype == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif ctype == b"IDAT":
            idat.append(body)
        elif ctype == b"IEND":
            break
    if ihdr is None:
        raise ValueError(f"{path}: no IHDR chunk")
    width, height, bit_depth, color_type, _comp, _filter, interlace = ihdr
    if (bit_depth, color_type, interlace) != (16, 0, 0):
        raise ValueError(
            f"{path}: need 16-bit grayscale non-interlaced, got depth {bit_depth} "
            f"colour type {color_type} interlace {interlace}"
        )
    raw = zlib.decompress(b"".join(idat))
    bpp = 2  # bytes per pixel
    stride = width * bpp
    if len(raw) != height * (stride + 1):
        raise ValueError(f"{path}: decompressed {len(raw)} bytes, expected {height * (stride + 1)}")
    prev = bytearray(stride)
    rows = []
    filters_seen = set()
    for y in range(height):
        start = y * (stride + 1)
        ftype = raw[start]
        filters_seen.add(ftype)
        line = bytearray(raw[start + 1 : start + 1 + stride])
        if ftype == 0:
            pass
        elif ftype == 1:  # Sub
            for i in range(bpp, stride):
                line[i] = (line[i] + line[i - bpp]) & 0xFF
        elif ftype == 2:  # Up
            for i in range(stride):
                line[i] = (line[i] + prev[i]) & 0xFF
        elif ftype == 3:  # Average
            for i in range(stride):
                left = line[i - bpp] if i >= bpp else 0
                line[i] = (line[i] + ((left + prev[i]) >> 1)) & 0xFF
        elif ftype == 4:  # Paeth
            for i in range(stride):
                left = line[i - bpp] if i >= bpp else 0
                upleft = prev[i - bpp] if i >= bpp else 0
                line[i] = (line[i] + _paeth(left, prev[i], upleft)) & 0xFF
        else:
            raise ValueError(f"{path}: row {y} has unknown filter type {ftype}")
        rows.append(list(struct.unpack(f">{width}H", bytes(line))))
        prev = line
    return width, height, rows, sorted(filters_seen)


def depth_to_points(rows, stride):
    """Back-project every `stride`-th pixel with nonzero depth; camera frame, metres."""
    points = []
    for v in range(0, len(rows), stride):
        row = rows[v]
        for u in range(0, len(row), stride):
            d = row[u]
            if d == 0:
                continue
            z = d / DEPTH_SCALE
            points.append(((u - CX) * z / FX, (v - CY) * z / FY, z))
    return points


def write_ply(path, points, comment):
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment {comment}\n"
        f"element vertex {len(points)}\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(b"".join(struct.pack("<3f", *p) for p in points))


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="rgbd5 folder with depth/NNNNN.png and trajectory.log")
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--frames", type=int, nargs="+", default=[0, 4], help="frame numbers (default: 0 4)")
    ap.add_argument("--stride", type=int, default=2, help="keep every stride-th pixel in u and v (default: 2)")
    args = ap.parse_args(argv)
    if args.stride < 1:
        ap.error("--stride must be >= 1")
    os.makedirs(args.out, exist_ok=True)
    for k in args.frames:
        png = os.path.join(args.data, "depth", f"{k:05d}.png")
        width, height, rows, filters = read_png_gray16(png)
        valid = [d for row in rows for d in row if d]
        points = depth_to_points(rows, args.stride)
        out = os.path.join(args.out, f"rgbd5_{k:05d}.ply")
        write_ply(
            out,
            points,
            f"ICL-NUIM livingroom1 (Augmented, noisy) depth frame {k}, camera frame (x right, y down, "
            f"z forward), metres, stride {args.stride}",
        )
        print(
            f"{png}: {width}x{height}, PNG filters {filters}, {len(valid)} valid pixels, "
            f"depth {min(valid) / DEPTH_SCALE:.3f}..{max(valid) / DEPTH_SCALE:.3f} m, "
            f"centre pixel {rows[height // 2][width // 2]} mm -> {out}: {len(points)} points, "
            f"{os.path.getsize(out)} bytes"
        )
    shutil.copyfile(os.path.join(args.data, "trajectory.log"), os.path.join(args.out, "trajectory.log"))


if __name__ == "__main__":
    main(sys.argv[1:])
