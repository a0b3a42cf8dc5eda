#!/usr/bin/env python3
"""Reads an EXR file written with render passes (`<render aovs=...>`) with
the reference OpenEXR library's Python bindings (`pip install openexr`,
3.x), an independent reader of what Trevi's writer produced, and prints
every part's channels: name, type, and the min / mean / max of the finite
values, how many are +inf, and the value at a pixel.

    python3 bench/aov_check.py out.exr [x y]

Not run by the cargo tests (they must not need Python): run it by hand;
its output for the example in docs/aisxml-extensions.md is recorded there.
"""

import sys

import numpy as np
import OpenEXR


def main():
    if len(sys.argv) not in (2, 4):
        sys.exit(__doc__)
    path = sys.argv[1]
    # One entry per channel as the file names it (not grouped into RGB).
    with OpenEXR.File(path, separate_channels=True) as f:
        for p, part in enumerate(f.parts):
            channels = part.channels
            names = sorted(channels)
            first = channels[names[0]].pixels
            h, w = first.shape[:2]
            x, y = (int(sys.argv[2]), int(sys.argv[3])) if len(sys.argv) == 4 else (w // 2, h // 2)
            print(f"{path}: part {p}, {w}x{h}, {len(names)} channels, "
                  f"compression {part.header.get('compression')}")
            for name in names:
                stored = channels[name].pixels.dtype
                px = np.asarray(channels[name].pixels, dtype=np.float64)
                finite = px[np.isfinite(px)]
                inf = int(np.isposinf(px).sum())
                stats = (f"min {finite.min():.6g} mean {finite.mean():.6g} max {finite.max():.6g}"
                         if finite.size else "no finite value")
                print(f"  {name:9} {stored} {stats} +inf {inf:6}  "
                      f"at ({x},{y}) {px[y, x]:.6g}")


if __name__ == "__main__":
    main()
