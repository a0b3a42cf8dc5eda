#!/usr/bin/env python3
"""The Cornell box with an area light, for Trevi and for Mitsuba 3, from one
description; Mitsuba's reference image; the comparison with Trevi.

One geometry (world-space triangles below) is written both as the AISXML
example `examples/cornell-area.xml` and as a Mitsuba 3 scene (scalar_rgb,
`path` integrator, box filter), so the two renderers see the same triangles,
the same camera and the same light. See docs/speed-accuracy.md
("Ground truth: Mitsuba 3") for the commands and the numbers.

    python3 bench/mitsuba/cornell_area.py xml          # writes examples/cornell-area.xml
    python3 bench/mitsuba/cornell_area.py reference 8192 4   # Mitsuba, 64x64, 4 seeds -> core/tests/data/
    python3 bench/mitsuba/cornell_area.py compare A.exr B.exr ...   # Trevi renders (seeds) vs the reference
    python3 bench/mitsuba/cornell_area.py trevi SS SEEDS [TREVI_SUBMIT]  # render those with Trevi, then compare
    python3 bench/mitsuba/cornell_area.py time SPP     # Mitsuba's wall time for SPP at 64x64
    python3 bench/mitsuba/cornell_area.py equal-time [SAMPLER [TREVI_SUBMIT]]  # Trevi's RMSE in Mitsuba's 64-spp time

Conventions matched (checked in core/src/camera.rs and the AISXML spec):
* `fov` is the horizontal field of view -> Mitsuba `fov_axis="x"`.
* a pixel is the square [i, i+1) x [r, r+1), row 0 at the top; Trevi's jittered
  n x n strata cover it uniformly, Mitsuba's box filter of radius 0.5 too.
* Trevi's `emission` is radiance, as Mitsuba's `area` emitter `radiance`.
* Trevi's `max-bounces` N is Mitsuba's `max_depth` N + 1 (both count the
  camera ray's hit as depth 1 in Mitsuba, bounce 0 in Trevi); both use
  Russian roulette, which does not bias.
* no ambient in path mode, black background (the front of the box is open;
  escaping rays return 0 in both).
* flat triangles (face normals), diffuse walls two-sided in both
  (Mitsuba: `twosided`), the light emits on its front (down) only.
* linear RGB compared as float EXR/arrays, never sRGB.
"""
import json
import math
import os
import sys
import time

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
XML_PATH = os.path.join(ROOT, "examples", "cornell-area.xml")
REF_PATH = os.path.join(ROOT, "core", "tests", "data", "cornell_area_mitsuba.txt")
NPY_PATH = os.path.join(ROOT, "target", "cornell_area_mitsuba_64.npy")

# Reference settings.
RES = 64              # Mitsuba reference resolution (the test uses 32x32: 2x2 box means)
MAX_BOUNCES = 1000    # Trevi max-bounces; Mitsuba max_depth = MAX_BOUNCES + 1
CAMERA = dict(position=(0.0, 1.0, 3.4), lookat=(0.0, 1.0, 0.0), up=(0.0, 1.0, 0.0), fov=42.0)

WHITE = (0.75, 0.75, 0.75)
RED = (0.75, 0.15, 0.15)
GREEN = (0.15, 0.6, 0.15)
LIGHT_LE = (15.0, 12.0, 8.0)


def quad(a, b, c, d):
    """Two triangles (a,b,c) (a,c,d); front = (b-a)x(c-a)."""
    return [a, b, c, d], [(0, 1, 2), (0, 2, 3)]


def box(cx, cz, hx, hy, hz, angle_deg):
    """An axis-aligned box of half sizes (hx,hy,hz) standing on y=0 at
    (cx, cz), turned by angle_deg about +y; five faces (no bottom), outwards."""
    t = math.radians(angle_deg)
    c, s = math.cos(t), math.sin(t)

    def p(x, y, z):
        # rotate about y (right-handed: x -> x cos + z sin, z -> -x sin + z cos)
        return (round(cx + x * c + z * s, 6), round(y, 6), round(cz - x * s + z * c, 6))

    y0, y1 = 0.0, 2 * hy
    faces = [
        # top (+y)
        (p(-hx, y1, -hz), p(-hx, y1, hz), p(hx, y1, hz), p(hx, y1, -hz)),
        # +z
        (p(-hx, y0, hz), p(hx, y0, hz), p(hx, y1, hz), p(-hx, y1, hz)),
        # -z
        (p(hx, y0, -hz), p(-hx, y0, -hz), p(-hx, y1, -hz), p(hx, y1, -hz)),
        # +x
        (p(hx, y0, hz), p(hx, y0, -hz), p(hx, y1, -hz), p(hx, y1, hz)),
        # -x
        (p(-hx, y0, -hz), p(-hx, y0, hz), p(-hx, y1, hz), p(-hx, y1, -hz)),
    ]
    verts, tris = [], []
    for f in faces:
        base = len(verts)
        verts += list(f)
        tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return verts, tris


# The textured real-mesh variant ("spot"): Spot the cow (Keenan Crane, public
# domain; ../shared/meshes/spot/, see its README) in place of the two boxes,
# flat-shaded (the OBJ has no normals), its 1024 x 1024 sRGB texture read
# bilinearly (Trevi's path mode, Mitsuba's bitmap, Cycles' Linear), repeating.
SPOT_DIR = os.path.normpath(os.path.join(ROOT, "..", "shared", "meshes", "spot"))
SPOT_OBJ = os.path.join(SPOT_DIR, "spot_triangulated.obj")
SPOT_PNG = os.path.join(SPOT_DIR, "spot_texture.png")
SCENES = ("boxes", "spot")


def spot():
    """Spot in world space: scaled by 0.9, turned -145 degrees about +y (its face to the camera),
    standing on the floor at the box's centre. One vertex per distinct
    (position, uv) pair of the OBJ's faces, so each vertex has one uv (OBJ
    convention: v = 0 is the image's bottom row)."""
    pos, uv, tris, index = [], [], [], {}
    verts, uvs = [], []
    with open(SPOT_OBJ) as f:
        for line in f:
            w = line.split()
            if not w:
                continue
            if w[0] == "v":
                pos.append(tuple(float(x) for x in w[1:4]))
            elif w[0] == "vt":
                uv.append(tuple(float(x) for x in w[1:3]))
            elif w[0] == "f":
                tri = []
                for corner in w[1:4]:
                    vi, ti = (int(x) - 1 for x in corner.split("/")[:2])
                    if (vi, ti) not in index:
                        index[(vi, ti)] = len(verts)
                        verts.append(pos[vi])
                        uvs.append(uv[ti])
                    tri.append(index[(vi, ti)])
                tris.append(tuple(tri))
    scale, t = 0.9, math.radians(-145.0)
    c, s = math.cos(t), math.sin(t)
    lift = -min(p[1] for p in pos) * scale
    zmid = (min(p[2] for p in pos) + max(p[2] for p in pos)) / 2

    def world(p):
        x, y, z = p[0] * scale, p[1] * scale + lift, (p[2] - zmid) * scale
        return (round(x * c + z * s, 6), round(y, 6), round(-x * s + z * c, 6))
    return [world(p) for p in verts], tris, uvs


def objects(scene="boxes"):
    """(id, vertices, triangles, diffuse, emission, texture) in world
    space; texture is None or (per-vertex uvs, PNG path), the diffuse
    colour multiplying the texture's."""
    assert scene in SCENES, scene
    L = 1.0
    objs = []
    v, t = quad((-L, 0, -L), (-L, 0, L), (L, 0, L), (L, 0, -L))  # floor, +y
    objs.append(("floor", v, t, WHITE, None))
    # The ceiling, -y, a 3 x 3 grid of quads whose centre cell is the light:
    # the light sits in the ceiling's plane, so nothing inside the box sees
    # its back (in AISXML `sided="front"` makes the back invisible; in
    # Mitsuba it would be a black occluder) and the edges are shared.
    xs, zs = (-L, -0.25, 0.25, L), (-L, -0.2, 0.2, L)
    v, t = [], []
    for i in range(3):
        for j in range(3):
            if (i, j) == (1, 1):
                continue
            qv, qt = quad((xs[i], 2, zs[j]), (xs[i + 1], 2, zs[j]), (xs[i + 1], 2, zs[j + 1]),
                          (xs[i], 2, zs[j + 1]))
            t += [tuple(k + len(v) for k in tr) for tr in qt]
            v += qv
    objs.append(("ceiling", v, t, WHITE, None))
    v, t = quad((-L, 0, -L), (L, 0, -L), (L, 2, -L), (-L, 2, -L))  # back, +z
    objs.append(("back", v, t, WHITE, None))
    v, t = quad((-L, 0, -L), (-L, 2, -L), (-L, 2, L), (-L, 0, L))  # left, +x
    objs.append(("left", v, t, RED, None))
    v, t = quad((L, 0, -L), (L, 0, L), (L, 2, L), (L, 2, -L))  # right, -x
    objs.append(("right", v, t, GREEN, None))
    if scene == "spot":
        v, t, uv = spot()
        objs.append(("spot", v, t, (1.0, 1.0, 1.0), None, (uv, SPOT_PNG)))
    else:
        v, t = box(0.35, 0.3, 0.3, 0.3, 0.3, -17.0)
        objs.append(("short-box", v, t, WHITE, None))
        v, t = box(-0.35, -0.3, 0.3, 0.6, 0.3, 20.0)
        objs.append(("tall-box", v, t, WHITE, None))
    # The light: 0.5 x 0.4, the ceiling's centre cell, facing down.
    y = 2.0
    v, t = quad((-0.25, y, -0.2), (0.25, y, -0.2), (0.25, y, 0.2), (-0.25, y, 0.2))
    objs.append(("light", v, t, (0.0, 0.0, 0.0), LIGHT_LE))
    return [o if len(o) == 6 else o + (None,) for o in objs]


def fmt(x):
    s = ("%.6f" % x).rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def xml(width=256, height=256, supersample=16, seed=0, output="cornell-area.png",
        integrator="path", extra="", scene="boxes"):
    """The AISXML scene; the render line is the one thing the callers vary
    (and the variant: a textured scene names its texture by file name, to be
    copied beside the XML: see `textures`)."""
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           "<!-- The Cornell box with an area light: diffuse walls, two diffuse boxes, a",
           "     0.5 x 0.4 light of radiance 15 12 8 set in the ceiling, no point",
           "     light, no ambient. Generated by bench/mitsuba/cornell_area.py, which",
           "     writes the same triangles for Mitsuba 3 (the ground truth of",
           "     docs/speed-accuracy.md and core/tests/mitsuba.rs): edit it there.",
           "     trevi-submit examples/cornell-area.xml -->",
           '<scene version="1">',
           '  <settings background="0 0 0" ambient="0 0 0"/>']
    for oid, verts, tris, kd, le, tex in objects(scene):
        out.append('  <mesh id="%s-mesh">' % oid)
        out.append("    <vertices>%s</vertices>" % "  ".join(" ".join(fmt(c) for c in p) for p in verts))
        if tex is not None:
            out.append("    <uvs>%s</uvs>" % "  ".join(" ".join(fmt(c) for c in p) for p in tex[0]))
        out.append("    <triangles>%s</triangles>" % "  ".join(" ".join(str(i) for i in tr) for tr in tris))
        out.append("  </mesh>")
        surf = 'diffuse="%s" specular="0 0 0"' % " ".join(fmt(c) for c in kd)
        if tex is not None:
            surf += ' diffuse-texture="%s"' % os.path.basename(tex[1])
        if le is not None:
            surf += ' emission="%s" sided="front"' % " ".join(fmt(c) for c in le)
        out.append('  <model id="%s" mesh="%s-mesh"><surface %s/></model>' % (oid, oid, surf))
    c = CAMERA
    out.append('  <camera id="front" position="%s" lookat="%s" up="%s" fov="%s">' % (
        " ".join(fmt(x) for x in c["position"]), " ".join(fmt(x) for x in c["lookat"]),
        " ".join(fmt(x) for x in c["up"]), fmt(c["fov"])))
    out.append('    <render width="%d" height="%d" supersample="%d" jitter="true" seed="%d"'
               ' integrator="%s" max-bounces="%d"%s output="%s"/>' % (
                   width, height, supersample, seed, integrator, MAX_BOUNCES, extra, output))
    out.append("  </camera>")
    out.append("</scene>")
    return "\n".join(out) + "\n"


def textures(scene="boxes"):
    """The texture files the scene's XML names, to copy beside it."""
    return [tex[1] for *_, tex in objects(scene) if tex is not None]


# ---------------------------------------------------------------- Mitsuba

def mitsuba_scene(res=RES, spp=64, sampler="independent", scene_name="boxes"):
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    import tempfile
    tmp = tempfile.mkdtemp(prefix="cornell-mi-")
    c = CAMERA
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": MAX_BOUNCES + 1},
        "sensor": {
            "type": "perspective",
            "fov": c["fov"],
            "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=c["position"], target=c["lookat"], up=c["up"]),
            "film": {"type": "hdrfilm", "width": res, "height": res,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb",
                     "component_format": "float32"},
            "sampler": {"type": sampler, "sample_count": spp},
        },
    }
    for oid, verts, tris, kd, le, tex in objects(scene_name):
        path = os.path.join(tmp, oid + ".obj")
        with open(path, "w") as f:
            for p in verts:
                f.write("v %r %r %r\n" % p)
            if tex is None:
                for tr in tris:
                    f.write("f %d %d %d\n" % tuple(i + 1 for i in tr))
            else:
                for p in tex[0]:
                    f.write("vt %r %r\n" % p)
                for tr in tris:
                    f.write("f %d/%d %d/%d %d/%d\n" % tuple(i + 1 for i in tr for _ in (0, 1)))
        reflectance = {"type": "rgb", "value": list(kd)}
        if tex is not None:
            # Mitsuba's OBJ loader flips v (flip_tex_coords), its bitmap's
            # row 0 being the top: the OBJ convention, as Trevi reads it.
            # An 8-bit PNG is sRGB-decoded; bilinear; repeat.
            reflectance = {"type": "bitmap", "filename": tex[1], "filter_type": "bilinear",
                           "wrap_mode": "repeat"}
        shape = {"type": "obj", "filename": path, "face_normals": True,
                 "bsdf": {"type": "twosided",
                          "bsdf": {"type": "diffuse", "reflectance": reflectance}}}
        if le is not None:
            shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": list(le)}}
        scene[oid] = shape
    return mi.load_dict(scene)


def mitsuba_render(scene, spp, seed):
    import mitsuba as mi
    import numpy as np
    img = mi.render(scene, spp=spp, seed=seed)
    return np.array(img, dtype=np.float64)[:, :, :3]


def read_exr(path):
    import mitsuba as mi
    import numpy as np
    mi.set_variant("scalar_rgb")
    return np.array(mi.Bitmap(path), dtype=np.float64)[:, :, :3]


def down2(img):
    h, w, c = img.shape
    return img.reshape(h // 2, 2, w // 2, 2, c).mean(axis=(1, 3))


def reference(spp, seeds):
    """Mitsuba at RES x RES, `seeds` independent renders of `spp` each: the
    mean and, per pixel, the standard error of that mean."""
    import numpy as np
    scene = mitsuba_scene(spp=spp)
    imgs = []
    t0 = time.time()
    for s in range(seeds):
        t = time.time()
        imgs.append(mitsuba_render(scene, spp, 1000 + s))
        print("seed %d: %.1f s" % (s, time.time() - t), flush=True)
    imgs = np.stack(imgs)
    mean = imgs.mean(axis=0)
    se = imgs.std(axis=0, ddof=1) / math.sqrt(seeds)
    return mean, se, imgs, time.time() - t0


def cmd_reference(argv):
    import numpy as np
    spp = int(argv[0]) if argv else 8192
    seeds = int(argv[1]) if len(argv) > 1 else 4
    mean, se, imgs, secs = reference(spp, seeds)
    np.save(NPY_PATH, imgs)
    store(imgs, spp, secs, load_avg())


def store(imgs, spp, secs, ld):
    """The test's data: 32x32 (2x2 box means of the 64x64 render, exactly a
    32x32 box-filtered pixel), per pixel mean RGB and its standard error."""
    import numpy as np
    seeds = imgs.shape[0]
    mean = imgs.mean(axis=0)
    se = imgs.std(axis=0, ddof=1) / math.sqrt(seeds)
    m32 = down2(mean)
    s32 = np.sqrt(down2(se ** 2) / 4.0)
    import mitsuba
    lines = [
        "# Mitsuba %s scalar_rgb, path integrator (max_depth %d), box filter:" % (mitsuba.__version__, MAX_BOUNCES + 1),
        "# examples/cornell-area.xml, camera front, 32x32 linear RGB (2x2 means of 64x64),",
        "# %d seeds x %d spp at 64x64 = %d samples per 32x32 pixel; %.0f s, load average %s." % (
            seeds, spp, 4 * seeds * spp, secs, ld),
        "# Made by: python3 bench/mitsuba/cornell_area.py reference %d %d" % (spp, seeds),
        "# One line per pixel, row 0 (top) first, left to right:",
        "# mean R G B, standard error of the mean R G B (from the spread of the seeds).",
    ]
    for y in range(32):
        for x in range(32):
            lines.append(" ".join("%.6e" % v for v in list(m32[y, x]) + list(s32[y, x])))
    os.makedirs(os.path.dirname(REF_PATH), exist_ok=True)
    with open(REF_PATH, "w") as f:
        f.write("\n".join(lines) + "\n")
    print("mean over image (RGB):", mean.mean(axis=(0, 1)))
    print("relative standard error of the image mean:",
          np.sqrt((se ** 2).sum(axis=(0, 1))) / (RES * RES) / mean.mean(axis=(0, 1)))
    print("wrote", REF_PATH)


def load_avg():
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def compare(trevi_imgs, ref_imgs):
    """Trevi (several seeds) against Mitsuba (several seeds): mean bias,
    per-pixel chi-square with variances from the seeds, and the same
    statistic for Mitsuba's seeds split in two halves (what agreement looks
    like)."""
    import numpy as np

    def stats(a, b):
        ma, mb = a.mean(axis=0), b.mean(axis=0)
        va = a.var(axis=0, ddof=1) / a.shape[0]
        vb = b.var(axis=0, ddof=1) / b.shape[0]
        # pool the variance estimate over 4x4 blocks (smooth, more dof)
        def pool(v):
            h, w, c = v.shape
            p = v.reshape(h // 4, 4, w // 4, 4, c).mean(axis=(1, 3))
            return np.repeat(np.repeat(p, 4, axis=0), 4, axis=1)
        var = pool(va) + pool(vb)
        z = (ma - mb) / np.sqrt(var)
        bias = ma.mean(axis=(0, 1)) / mb.mean(axis=(0, 1)) - 1.0
        se_bias = np.sqrt(var.sum(axis=(0, 1))) / (ma.shape[0] * ma.shape[1]) / mb.mean(axis=(0, 1))
        return dict(bias=bias, se_bias=se_bias, chi2=float((z ** 2).mean()),
                    frac3=float((np.abs(z) > 3).mean()), zmax=float(np.abs(z).max()))

    t = stats(trevi_imgs, ref_imgs)
    h = ref_imgs.shape[0] // 2
    m = stats(ref_imgs[:h], ref_imgs[h:2 * h])
    return t, m


def cmd_compare(argv):
    import numpy as np
    ref = np.load(NPY_PATH)
    tr = np.stack([read_exr(p) for p in argv])
    t, m = compare(tr, ref)
    fmtd = lambda d: ("mean bias R G B = %s %% (± %s %% s.e.), per-pixel mean z^2 = %.3f, |z|>3: %.2f %%, max |z| = %.2f" % (
        " ".join("%+.3f" % (100 * x) for x in d["bias"]),
        " ".join("%.3f" % (100 * x) for x in d["se_bias"]), d["chi2"], 100 * d["frac3"], d["zmax"]))
    print("Trevi vs Mitsuba:            ", fmtd(t))
    print("Mitsuba half vs Mitsuba half:", fmtd(m))


def cmd_time(argv):
    spp = int(argv[0])
    res = int(argv[1]) if len(argv) > 1 else RES
    scene = mitsuba_scene(res=res, spp=spp)
    mitsuba_render(scene, 1, 7)  # warm-up (JIT-free in scalar mode, but loads)
    best = None
    for rep in range(3):
        t = time.time()
        img = mitsuba_render(scene, spp, 11 + rep)
        dt = time.time() - t
        best = dt if best is None else min(best, dt)
    import numpy as np
    out = os.path.join(ROOT, "target", "mitsuba_%dspp_%d.npy" % (spp, res))
    np.save(out, img)
    print("mitsuba %d spp %dx%d: best of 3 %.2f s, load %s -> %s" % (spp, res, res, best, load_avg(), out))


def cmd_equal_time(argv):
    """Equal-time error: the RMSE (against the Mitsuba reference of
    `reference`) Trevi reaches in the time Mitsuba 3 needs for 64 spp, both
    on this machine's cores, measured interleaved (Mitsuba, then each Trevi
    setting, three rounds; best of the three per renderer and setting) so
    that both see the same background load. Trevi is timed as the whole
    `trevi-submit` process (start, parse, BVH, render, EXR); Mitsuba as
    `mi.render` alone (scene loaded before), which favours Mitsuba."""
    import subprocess
    import tempfile
    import numpy as np
    sampler = argv[0] if argv else "independent"
    submit = argv[1] if len(argv) > 1 else os.path.join(ROOT, "target", "release", "trevi-submit")
    ref = np.load(NPY_PATH).mean(axis=0)
    rmse = lambda img: float(np.sqrt(((img - ref) ** 2).mean()))
    scene = mitsuba_scene(res=RES, spp=64, sampler=sampler)
    mitsuba_render(scene, 1, 7)
    tmp = tempfile.mkdtemp(prefix="trevi-equal-time-")
    ladder = [1, 4, 6, 8, 11, 16]
    for n in ladder:
        with open(os.path.join(tmp, "ss%d.xml" % n), "w") as f:
            f.write(xml(width=RES, height=RES, supersample=n, seed=7, output="ss%d.exr" % n))
    t_mi, e_mi = [], []
    t_tr = {n: [] for n in ladder}
    e_tr = {}
    loads = [load_avg()]
    for rnd in range(3):
        t = time.time()
        img = mitsuba_render(scene, 64, 11 + rnd)
        t_mi.append(time.time() - t)
        e_mi.append(rmse(img))
        for n in ladder:
            t = time.time()
            subprocess.run([submit, os.path.join(tmp, "ss%d.xml" % n), "--quiet", "--threads",
                            str(os.cpu_count())], check=True)
            t_tr[n].append(time.time() - t)
            e_tr[n] = rmse(read_exr(os.path.join(tmp, "ss%d.exr" % n)))
        loads.append(load_avg())
    tm = min(t_mi)
    print("load averages (1, 5, 15 min) before and after each round:", " | ".join(loads))
    print("Mitsuba %s scalar_rgb, sampler %s, 64 spp, %dx%d: %.2f s (best of 3: %s), RMSE %.4e (mean of 3: %s)" % (
        __import__("mitsuba").__version__, sampler, RES, RES, tm, " ".join("%.2f" % x for x in t_mi),
        float(np.mean(e_mi)), " ".join("%.4e" % x for x in e_mi)))
    pts = []
    for n in ladder:
        tt = min(t_tr[n])
        pts.append((tt, e_tr[n]))
        print("Trevi supersample %2d (%4d spp): %.2f s (best of 3: %s), RMSE %.4e" % (
            n, n * n, tt, " ".join("%.2f" % x for x in t_tr[n]), e_tr[n]))
    pts.sort()
    at = None
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if t0 <= tm <= t1:
            f = (math.log(tm) - math.log(t0)) / (math.log(t1) - math.log(t0))
            at = math.exp(math.log(e0) + f * (math.log(e1) - math.log(e0)))
    if at is None:
        print("Mitsuba's time is outside Trevi's ladder")
    else:
        print("Trevi's RMSE in Mitsuba's 64-spp time (log-log interpolation): %.4e; Mitsuba's %.4e; ratio Trevi/Mitsuba %.2f" % (
            at, float(np.mean(e_mi)), at / float(np.mean(e_mi))))


def cmd_trevi(argv):
    """Renders the scene with Trevi at 64x64, supersample SS, SEEDS seeds
    (trevi-submit, release), then compares with the Mitsuba reference."""
    import subprocess
    import tempfile
    ss, seeds = int(argv[0]), int(argv[1])
    submit = argv[2] if len(argv) > 2 else os.path.join(ROOT, "target", "release", "trevi-submit")
    tmp = tempfile.mkdtemp(prefix="trevi-cornell-area-")
    paths = []
    for s in range(seeds):
        x = os.path.join(tmp, "seed%d.xml" % s)
        with open(x, "w") as f:
            f.write(xml(width=RES, height=RES, supersample=ss, seed=2000 + s, output="seed%d.exr" % s))
        t = time.time()
        subprocess.run([submit, x, "--quiet"], check=True)
        print("trevi seed %d: %.1f s, load %s" % (s, time.time() - t, load_avg()), flush=True)
        paths.append(os.path.join(tmp, "seed%d.exr" % s))
    cmd_compare(paths)


def main():
    if len(sys.argv) < 2:
        print(__doc__)
        sys.exit(2)
    cmd, argv = sys.argv[1], sys.argv[2:]
    if cmd == "xml":
        with open(XML_PATH, "w") as f:
            f.write(xml())
        print("wrote", XML_PATH)
    elif cmd == "xml-variant":
        # xml-variant OUT WIDTH SUPERSAMPLE SEED [OUTPUT]
        out, w, ss, seed = argv[0], int(argv[1]), int(argv[2]), int(argv[3])
        with open(out, "w") as f:
            f.write(xml(width=w, height=w, supersample=ss, seed=seed,
                        output=argv[4] if len(argv) > 4 else "out.exr"))
    elif cmd == "reference":
        cmd_reference(argv)
    elif cmd == "store":
        # store SPP SECONDS LOAD: rewrite the test data from target/*.npy
        import numpy as np
        store(np.load(NPY_PATH), int(argv[0]), float(argv[1]), argv[2])
    elif cmd == "compare":
        cmd_compare(argv)
    elif cmd == "trevi":
        cmd_trevi(argv)
    elif cmd == "time":
        cmd_time(argv)
    elif cmd == "equal-time":
        cmd_equal_time(argv)
    else:
        print(__doc__)
        sys.exit(2)


if __name__ == "__main__":
    main()
