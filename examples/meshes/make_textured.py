#!/usr/bin/env python3
"""Writes the textured example's assets (examples/textured.xml), all made here:

- brick.png: 256 x 128 bricks (8-bit sRGB), the map_Kd of bricks.mtl;
- ring.obj + bricks.mtl: a torus of 48 x 24 quads with texture coordinates
  (`vt`, the seam vertices repeated so that u runs 0..1 once round the ring
  and v once round the tube) and `mtllib`/`usemtl`, so the OBJ brings its
  own colour;
- die.png: a 3 x 2 atlas of die faces (one to six pips), 384 x 256;
- die.ply: a cube with a per-face `texcoord` list (u v for each corner of
  each quad), so each face shows one cell of the atlas;
- tiles.png: 64 x 64 two-tone floor tiles, used by `diffuse-texture` on the
  floor's inline mesh with `<uvs>`.

Plain Python (zlib for the PNGs); run: python3 examples/meshes/make_textured.py
"""
import math
import os
import struct
import zlib

here = os.path.dirname(os.path.abspath(__file__))


def write_png(name, width, height, pixel):
    """8-bit RGB PNG; pixel(x, y) -> (r, g, b), y = 0 the top row."""
    rows = b"".join(
        b"\0" + bytes(c for x in range(width) for c in pixel(x, y)) for y in range(height)
    )

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    png = b"\x89PNG\r\n\x1a\n"
    png += chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(rows, 9))
    png += chunk(b"IEND", b"")
    with open(os.path.join(here, name), "wb") as f:
        f.write(png)


def noise(x, y):
    """A deterministic hash in [0, 1), for a little variation per texel."""
    h = (x * 374761393 + y * 668265263) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    return ((h ^ (h >> 16)) & 0xFFFF) / 65536.0


def brick(x, y):
    # 8 courses of 32 texels; 4 bricks of 64 a course, every other course
    # shifted by half a brick; 4-texel mortar joints.
    course, row = divmod(y, 16)
    shift = 32 if course % 2 else 0
    col, px = divmod((x + shift) % 256, 64)
    if row < 3 or px < 3:
        g = int(190 + 25 * noise(x, y))
        return (g, g - 6, g - 16)
    tone = noise(col, course)
    n = 18 * noise(x, y)
    return (int(150 + 50 * tone + n), int(62 + 25 * tone + n / 2), int(45 + 15 * tone + n / 3))


def die(x, y):
    cell_x, px = divmod(x, 128)
    cell_y, py = divmod(y, 128)
    pips = 1 + cell_x + 3 * cell_y  # 1 2 3 on the top row of the atlas, 4 5 6 below
    spots = {
        1: [(0, 0)],
        2: [(-1, -1), (1, 1)],
        3: [(-1, -1), (0, 0), (1, 1)],
        4: [(-1, -1), (1, -1), (-1, 1), (1, 1)],
        5: [(-1, -1), (1, -1), (0, 0), (-1, 1), (1, 1)],
        6: [(-1, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (1, 1)],
    }[pips]
    if px < 4 or py < 4 or px > 123 or py > 123:
        return (60, 60, 70)
    for sx, sy in spots:
        dx, dy = px - (64 + 34 * sx), py - (64 + 34 * sy)
        if dx * dx + dy * dy < 13 * 13:
            return (200, 20, 30) if pips == 1 else (25, 25, 35)
    return (245, 240, 225)


def tiles(x, y):
    light = ((x // 32) + (y // 32)) % 2 == 0
    edge = x % 32 in (0, 31) or y % 32 in (0, 31)
    if edge:
        return (90, 85, 80)
    return (205, 200, 185) if light else (120, 130, 140)


def ring():
    R, r, U, V = 1.0, 0.38, 48, 24
    out = ["# a torus R=%s r=%s, %dx%d quads with vt, made by make_textured.py" % (R, r, U, V),
           "mtllib bricks.mtl"]
    for i in range(U):
        a = 2 * math.pi * i / U
        for j in range(V):
            b = 2 * math.pi * j / V
            out.append("v %.6f %.6f %.6f" % (
                (R + r * math.cos(b)) * math.cos(a), r * math.sin(b), (R + r * math.cos(b)) * math.sin(a)))
    # (U + 1) x (V + 1) texture coordinates: the seams get their own. The
    # bricks repeat 3 times round the ring (u) and once round the tube (v),
    # through texture-scale-like factors baked in here.
    for i in range(U + 1):
        for j in range(V + 1):
            out.append("vt %.6f %.6f" % (3.0 * i / U, 1.0 * j / V))
    out.append("usemtl bricks")
    for i in range(U):
        for j in range(V):
            p = lambda di, dj: ((i + di) % U) * V + (j + dj) % V + 1
            t = lambda di, dj: (i + di) * (V + 1) + (j + dj) + 1
            corners = [(0, 0), (0, 1), (1, 1), (1, 0)]  # counter-clockwise seen from outside
            out.append("f " + " ".join("%d/%d" % (p(*c), t(*c)) for c in corners))
    with open(os.path.join(here, "ring.obj"), "w") as f:
        f.write("\n".join(out) + "\n")
    with open(os.path.join(here, "bricks.mtl"), "w") as f:
        f.write("# made by make_textured.py: the image is the colour (no Kd), a faint highlight\n"
                "newmtl bricks\nKs 0.15 0.15 0.15\nNs 24\nillum 2\nmap_Kd brick.png\n")


def cube():
    # Faces of the unit cube centred on the origin, each a quad wound
    # outwards, with the atlas cell it shows (column, row from the top).
    faces = [
        ((0, 0, 1), (1, 0, 0), (0, 1, 0), (0, 0)),    # +z: one
        ((1, 0, 0), (0, 0, -1), (0, 1, 0), (1, 0)),   # +x: two
        ((0, 1, 0), (1, 0, 0), (0, 0, -1), (2, 0)),   # +y: three
        ((0, -1, 0), (1, 0, 0), (0, 0, 1), (0, 1)),   # -y: four
        ((-1, 0, 0), (0, 0, 1), (0, 1, 0), (1, 1)),   # -x: five
        ((0, 0, -1), (-1, 0, 0), (0, 1, 0), (2, 1)),  # -z: six
    ]
    verts, index, polys = [], {}, []
    for n, right, up, (cx, cy) in faces:
        corners, uv = [], []
        for su, sv in [(-1, -1), (1, -1), (1, 1), (-1, 1)]:
            p = tuple(0.5 * (n[k] + su * right[k] + sv * up[k]) for k in range(3))
            if p not in index:
                index[p] = len(verts)
                verts.append(p)
            corners.append(index[p])
            # Cell (cx, cy) of a 3 x 2 atlas; v = 0 is the image's bottom row.
            uv += [(cx + (su + 1) / 2) / 3, 1 - (cy + 1 - (sv + 1) / 2) / 2]
        polys.append((corners, uv))
    lines = ["ply", "format ascii 1.0", "comment a die, made by make_textured.py",
             "element vertex %d" % len(verts),
             "property float x", "property float y", "property float z",
             "element face %d" % len(polys),
             "property list uchar int vertex_indices",
             "property list uchar float texcoord", "end_header"]
    lines += ["%g %g %g" % v for v in verts]
    for corners, uv in polys:
        lines.append("4 %s 8 %s" % (" ".join(map(str, corners)), " ".join("%.6g" % x for x in uv)))
    with open(os.path.join(here, "die.ply"), "w") as f:
        f.write("\n".join(lines) + "\n")


write_png("brick.png", 256, 128, brick)
write_png("die.png", 384, 256, die)
write_png("tiles.png", 64, 64, tiles)
ring()
cube()
