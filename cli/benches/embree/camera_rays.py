#!/usr/bin/env python3
"""Writes a vkrt .rays file of N x N pinhole camera rays looking down -z at a mesh's box,
with tmax = +inf (unbounded, Embree's tfar convention): the rays of README's Embree check.

    python3 benches/embree/camera_rays.py MIN_X MIN_Y MIN_Z MAX_X MAX_Y MAX_Z OUT.rays [N]

(the box from `vkrt scene MESH --json`, "bounds")."""
import struct
import sys

lo = [float(x) for x in sys.argv[1:4]]
hi = [float(x) for x in sys.argv[4:7]]
out = sys.argv[7]
n = int(sys.argv[8]) if len(sys.argv) > 8 else 1024
c = [(a + b) / 2 for a, b in zip(lo, hi)]
ext = max(b - a for a, b in zip(lo, hi))
eye = (c[0], c[1], c[2] + 2 * ext)
half = 0.6 * ext
with open(out, "wb") as f:
    for j in range(n):
        row = bytearray()
        for i in range(n):
            px = c[0] - half + (i + 0.5) / n * 2 * half
            py = c[1] + half - (j + 0.5) / n * 2 * half
            d = (px - eye[0], py - eye[1], c[2] - eye[2])
            row += struct.pack("<8f", *eye, 0.0, *d, float("inf"))
        f.write(row)
