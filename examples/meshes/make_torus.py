#!/usr/bin/env python3
"""Writes torus.obj, the mesh the instancing example loads.

A torus of major radius R and minor radius r, with U x V quads (written as
quads, so the loader's fan triangulation is exercised). No normals: Trevi
computes smooth ones. Run: python3 examples/meshes/make_torus.py
"""
import math
import os

R, r, U, V = 1.0, 0.35, 48, 24
out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "torus.obj")
with open(out, "w") as f:
    f.write(f"# torus R={R} r={r}, {U}x{V} quads, made by make_torus.py\n")
    for i in range(U):
        a = 2 * math.pi * i / U
        for j in range(V):
            b = 2 * math.pi * j / V
            x = (R + r * math.cos(b)) * math.cos(a)
            z = (R + r * math.cos(b)) * math.sin(a)
            y = r * math.sin(b)
            f.write(f"v {x:.6f} {y:.6f} {z:.6f}\n")
    for i in range(U):
        for j in range(V):
            a = i * V + j + 1
            b = ((i + 1) % U) * V + j + 1
            c = ((i + 1) % U) * V + (j + 1) % V + 1
            d = i * V + (j + 1) % V + 1
            # Counter-clockwise seen from outside.
            f.write(f"f {a} {d} {c} {b}\n")
