"""Writes tunnel_section.png: the cross-section of workflows/tunnel.yaml, 40 x 40 pixels of
0.1 m (a 4 x 4 m section): sandstone (tan, #c8a064) over mudstone (grey, #6e6e78), their
contact dipping 10 degrees and passing 0.6 m below the section's centre (the tunnel's axis).

    python workflows/data/tunnel_section.py
"""
import math
from pathlib import Path

import numpy as np
from PIL import Image

SANDSTONE, MUDSTONE = (200, 160, 100), (110, 110, 120)


def section(n=40, pixel=0.1, depth_below_centre=0.6, dip_deg=10.0):
    px = np.empty((n, n, 3), np.uint8)
    u = (np.arange(n) + 0.5) * pixel                  # pixel centres, left to right [m]
    v = (n - 0.5 - np.arange(n)) * pixel              # row 0 is the top
    c = 0.5 * n * pixel
    contact = c - depth_below_centre + math.tan(math.radians(dip_deg)) * (u - c)
    lower = v[:, None] < contact[None, :]
    px[:] = SANDSTONE
    px[lower] = MUDSTONE
    return px


if __name__ == "__main__":
    out = Path(__file__).with_name("tunnel_section.png")
    Image.fromarray(section()).save(out, optimize=True)
    print(f"wrote {out}")
