"""A bird's-eye picture of a map exported by `cosem export ply` (PNG).

    python3 docs/render_ply.py MAP.ply OUT.png [--cell 0.1]

Each voxel is drawn as a square of its class colour, seen from above (x
forward to the right, y left upwards), higher voxels over lower ones; grey
for voxels of an unknown class. Needs numpy only (the PNG is written with
zlib).
"""
import argparse
import struct
import sys
import zlib

import numpy as np

FIELDS = {"float": "<f4", "uchar": "u1", "ushort": "<u2"}


def read_ply(path):
    data = open(path, "rb").read()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        sys.exit(f"{path}: not a PLY file")
    header = data[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in header:
        sys.exit(f"{path}: not binary little-endian PLY")
    count, props = None, []
    for line in header:
        words = line.split()
        if words[:2] == ["element", "vertex"]:
            count = int(words[2])
        elif words[:1] == ["property"] and count is not None:
            if words[1] not in FIELDS:
                sys.exit(f"{path}: property type {words[1]} not read here")
            props.append((words[2], FIELDS[words[1]]))
    dtype = np.dtype(props)
    body = data[end + len(b"end_header\n"):]
    if count is None or len(body) < count * dtype.itemsize:
        sys.exit(f"{path}: {len(body)} bytes of vertices, the header says {count} x {dtype.itemsize}")
    return np.frombuffer(body, dtype=dtype, count=count)


def write_png(path, rgb):
    h, w, _ = rgb.shape
    rows = b"".join(b"\x00" + rgb[y].tobytes() for y in range(h))

    def chunk(kind, payload):
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(rows, 9)) + chunk(b"IEND", b"")
    open(path, "wb").write(png)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ply")
    ap.add_argument("png")
    ap.add_argument("--cell", type=float, default=0.1, help="metres per pixel")
    a = ap.parse_args()
    v = read_ply(a.ply)
    if len(v) == 0:
        sys.exit(f"{a.ply}: no points")
    x, y, z = v["x"].astype(float), v["y"].astype(float), v["z"].astype(float)
    colour = np.stack([v["red"], v["green"], v["blue"]], axis=1)
    # Image columns along x (forward), rows along -y (left is up).
    col = np.floor((x - x.min()) / a.cell).astype(int)
    row = np.floor((y.max() - y) / a.cell).astype(int)
    w, h = col.max() + 3, row.max() + 3
    img = np.full((h, w, 3), 255, np.uint8)
    order = np.argsort(z, kind="stable")
    size = 2
    for dy in range(size):
        for dx in range(size):
            img[row[order] + dy, col[order] + dx] = colour[order]
    write_png(a.png, img)
    print(f"{a.png}: {w}x{h} pixels, {len(v)} voxels, {a.cell} m a pixel")


if __name__ == "__main__":
    main()
