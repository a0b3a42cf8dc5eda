#!/usr/bin/env python3
"""Equal-error comparison of Trevi with its peers on the area-lit Cornell box
(the scene bench/mitsuba/cornell_area.py writes for Trevi and Mitsuba 3, built
here for Blender Cycles from the same triangles), single-threaded, at a ladder
of sample counts, against a converged reference; in one run, with versions.

    python3 bench/peers.py reference [SPP]        # Mitsuba (llvm if it loads), -> target/peers/
    python3 bench/peers.py ladder [RENDERERS] [--spp 1,4,16,64,256] [--res 64]
        RENDERERS: comma list of trevi, trevi-denoised, mitsuba-scalar,
        mitsuba-llvm, cycles, cycles-oidn (default: all that are installed)

Each render is timed as the CPU time of the work alone (Trevi: the
trevi-submit child's user+system time, start to written file; Mitsuba:
mi.render; Cycles: bpy.ops.render.render, in this process), one thread
each. Errors: RMSE of linear RGB against the reference, and SSIM of the
luminance (7x7 box windows), both over the whole frame. The equal-error
ratio of a peer at a sample count is Trevi's CPU time to reach the peer's
RMSE (log-log interpolation on Trevi's ladder) over the peer's CPU time:
below 1, Trevi is faster at equal error.

Installs (docs/speed-accuracy.md): pip install mitsuba bpy==5.0.1 OpenEXR
numpy; Debian's libllvm19 for mitsuba-llvm; trevi-denoised needs a build of the
trevi-denoise example (cargo build --release -p trevi-denoise --features oidn
--example denoise_exr, OIDN_DIR set; docs/denoise.md).
"""
import math
import os
import resource
import subprocess
import sys
import tempfile
import time

# Mitsuba's LLVM variant needs LLVM 16 or newer (Debian 12's default llvm,
# 14, fails in code generation): `apt-get install libllvm19`.
for _llvm in ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", "/usr/lib/x86_64-linux-gnu/libLLVM-16.so.1"):
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(_llvm):
        os.environ["DRJIT_LIBLLVM_PATH"] = _llvm

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, ".."))
sys.path.insert(0, os.path.join(HERE, "mitsuba"))
import cornell_area as ca  # noqa: E402  (the one description of the scene)

OUT = os.path.join(ROOT, "target", "peers")
SUBMIT = os.path.join(ROOT, "target", "release", "trevi-submit")
DENOISE = os.path.join(ROOT, "target", "release", "examples", "denoise_exr")


def read_exr(path):
    import numpy as np
    import OpenEXR
    with OpenEXR.File(path) as f:
        ch = f.channels()
        if "RGB" in ch:
            img = ch["RGB"].pixels
        elif "RGBA" in ch:
            img = ch["RGBA"].pixels[:, :, :3]
        else:
            img = np.stack([ch[c].pixels for c in "RGB"], axis=-1)
    return np.asarray(img, dtype=np.float64)


def ref_path(res):
    return os.path.join(OUT, "reference_%d.npy" % res)


# ------------------------------------------------------------- renderers

def trevi(res, spp, seed, tmp, denoise=False):
    """trevi-submit --threads 1 on supersample sqrt(spp); CPU of the child."""
    n = int(round(math.sqrt(spp)))
    assert n * n == spp, "Trevi's strata: spp must be a square"
    name = "trevi_%d_%d" % (spp, seed)
    extra = ' aovs="albedo normal"' if denoise else ""
    xml_path = os.path.join(tmp, name + ".xml")
    with open(xml_path, "w") as f:
        f.write(ca.xml(width=res, height=res, supersample=n, seed=seed, output=name + ".exr",
                       extra=extra))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([SUBMIT, xml_path, "--quiet", "--threads", "1"], check=True)
    out = os.path.join(tmp, name + ".exr")
    if denoise:
        clean = os.path.join(tmp, name + "_denoised.exr")
        subprocess.run([DENOISE, out, clean, "--threads", "1"], check=True)
        out = clean
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return read_exr(out), cpu


def mitsuba(variant):
    def render(res, spp, seed, tmp):
        import mitsuba as mi
        import numpy as np
        mi.set_variant(variant)
        scene = mitsuba_scene(res, spp)
        # Once untimed at the same sample count: the LLVM variant compiles
        # its kernels on the first render (the compile is not the render).
        mi.render(scene, spp=spp, seed=seed + 1)
        t = time.process_time()
        img = mi.render(scene, spp=spp, seed=seed)
        img = np.array(img, dtype=np.float64)[:, :, :3]
        return img, time.process_time() - t
    return render


def mitsuba_scene(res, spp):
    """cornell_area's Mitsuba scene in the variant already set, one thread."""
    import drjit as dr
    import mitsuba as mi
    dr.set_thread_count(1)
    # cornell_area sets scalar_rgb itself: keep the variant chosen here.
    set_variant = mi.set_variant
    mi.set_variant = lambda *_: None
    try:
        return ca.mitsuba_scene(res=res, spp=spp, sampler="multijitter")
    finally:
        mi.set_variant = set_variant


def cycles(denoise):
    def render(res, spp, seed, tmp):
        import bpy
        build_cycles(res, spp, seed, denoise)
        path = os.path.join(tmp, "cycles_%d_%d_%d.exr" % (spp, seed, denoise))
        bpy.context.scene.render.filepath = path
        t = time.process_time()
        bpy.ops.render.render(write_still=True)
        cpu = time.process_time() - t
        return read_exr(path), cpu
    return render


def build_cycles(res, spp, seed, denoise):
    """The same triangles, camera and light in Blender; one CPU thread, box
    filter of one pixel, no clamping, no adaptive sampling."""
    import bpy
    from mathutils import Matrix, Vector
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.samples = spp
    cy.use_adaptive_sampling = False
    cy.seed = seed
    cy.use_denoising = denoise
    if denoise:
        cy.denoiser = "OPENIMAGEDENOISE"
    cy.max_bounces = cy.diffuse_bounces = ca.MAX_BOUNCES
    cy.glossy_bounces = cy.transmission_bounces = cy.volume_bounces = 0
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    cy.pixel_filter_type = "BOX"
    cy.filter_width = 1.0
    sc.render.threads_mode = "FIXED"
    sc.render.threads = 1
    sc.render.resolution_x = sc.render.resolution_y = res
    sc.render.resolution_percentage = 100
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    sc.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    sc.world = world
    for oid, verts, tris, kd, le in ca.objects():
        mesh = bpy.data.meshes.new(oid)
        mesh.from_pydata([tuple(v) for v in verts], [], [tuple(t) for t in tris])
        mesh.update()
        obj = bpy.data.objects.new(oid, mesh)
        sc.collection.objects.link(obj)
        mat = bpy.data.materials.new(oid)
        mat.use_nodes = True
        nodes = mat.node_tree.nodes
        nodes.clear()
        out = nodes.new("ShaderNodeOutputMaterial")
        if le is not None:
            s = max(le)
            shader = nodes.new("ShaderNodeEmission")
            shader.inputs["Color"].default_value = (le[0] / s, le[1] / s, le[2] / s, 1.0)
            shader.inputs["Strength"].default_value = s
        else:
            shader = nodes.new("ShaderNodeBsdfDiffuse")
            shader.inputs["Color"].default_value = (kd[0], kd[1], kd[2], 1.0)
        mat.node_tree.links.new(shader.outputs[0], out.inputs["Surface"])
        mesh.materials.append(mat)
    cam_data = bpy.data.cameras.new("cam")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = math.radians(ca.CAMERA["fov"])
    cam = bpy.data.objects.new("cam", cam_data)
    sc.collection.objects.link(cam)
    pos = Vector(ca.CAMERA["position"])
    f = (Vector(ca.CAMERA["lookat"]) - pos).normalized()
    r = f.cross(Vector(ca.CAMERA["up"])).normalized()
    u = r.cross(f)
    m = Matrix((r, u, -f)).transposed().to_4x4()
    m.translation = pos
    cam.matrix_world = m
    sc.camera = cam


RENDERERS = {
    "trevi": lambda res, spp, seed, tmp: trevi(res, spp, seed, tmp),
    "trevi-denoised": lambda res, spp, seed, tmp: trevi(res, spp, seed, tmp, denoise=True),
    "mitsuba-scalar": mitsuba("scalar_rgb"),
    "mitsuba-llvm": mitsuba("llvm_ad_rgb"),
    "cycles": cycles(False),
    "cycles-oidn": cycles(True),
}


def available(name):
    try:
        if name.startswith("trevi"):
            ok = os.path.exists(SUBMIT)
            return ok and (name == "trevi" or os.path.exists(DENOISE))
        if name.startswith("mitsuba"):
            import mitsuba as mi
            mi.set_variant("llvm_ad_rgb" if name.endswith("llvm") else "scalar_rgb")
            return True
        if name.startswith("cycles"):
            import bpy  # noqa: F401
            return True
    except Exception as e:  # an uninstalled peer is reported, not fatal
        print("%s: not available (%s)" % (name, e), file=sys.stderr)
    return False


def versions():
    out = []
    try:
        import mitsuba
        out.append("mitsuba %s" % mitsuba.__version__)
    except Exception:
        pass
    try:
        import bpy
        out.append("blender %s" % bpy.app.version_string)
    except Exception:
        pass
    git = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"],
                         capture_output=True, text=True).stdout.strip()
    out.append("trevi %s" % git)
    return ", ".join(out)


# ------------------------------------------------------------- measures

def rmse(img, ref):
    import numpy as np
    return float(np.sqrt(((img - ref) ** 2).mean()))


def ssim(img, ref):
    """SSIM of the luminance with 7x7 box windows (Wang et al. 2004,
    constants for a dynamic range of 1)."""
    import numpy as np
    w = np.array([0.2126, 0.7152, 0.0722])
    x, y = img @ w, ref @ w
    k = 7

    def box(a):
        c = np.cumsum(np.cumsum(np.pad(a, ((1, 0), (1, 0))), 0), 1)
        return (c[k:, k:] - c[:-k, k:] - c[k:, :-k] + c[:-k, :-k]) / (k * k)
    mx, my = box(x), box(y)
    vx, vy = box(x * x) - mx * mx, box(y * y) - my * my
    cxy = box(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return float(s.mean())


def trevi_time_at(points, target):
    """Trevi's CPU time at RMSE `target`, log-log interpolated on its ladder
    (points: (cpu, rmse)); None outside it."""
    pts = sorted(points, key=lambda p: -p[1])
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if e1 <= target <= e0:
            f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))
    return None


# ------------------------------------------------------------- commands

def cmd_reference(argv):
    import numpy as np
    spp = int(argv[0]) if argv else 65536
    res = int(argv[1]) if len(argv) > 1 else ca.RES
    import mitsuba as mi
    try:
        mi.set_variant("llvm_ad_rgb")
    except Exception:
        mi.set_variant("scalar_rgb")
    scene = mitsuba_scene(res, spp)
    t = time.time()
    acc = None
    chunks = max(1, spp // 4096)
    for c in range(chunks):
        img = np.array(mi.render(scene, spp=spp // chunks, seed=90_000 + c), dtype=np.float64)[:, :, :3]
        acc = img if acc is None else acc + img
    os.makedirs(OUT, exist_ok=True)
    np.save(ref_path(res), acc / chunks)
    print("reference %dx%d, %d spp (%s): %.0f s -> %s" % (res, res, spp, mi.variant(),
                                                       time.time() - t, ref_path(res)))


def cmd_ladder(argv):
    import numpy as np
    names = list(RENDERERS)
    spps = [1, 4, 16, 64, 256]
    res = ca.RES
    args = list(argv)
    while args:
        a = args.pop(0)
        if a == "--spp":
            spps = [int(s) for s in args.pop(0).split(",")]
        elif a == "--res":
            res = int(args.pop(0))
        else:
            names = a.split(",")
    ref = np.load(ref_path(res))
    names = [n for n in names if available(n)]
    tmp = tempfile.mkdtemp(prefix="trevi-peers-")
    print("# %s; %dx%d; one thread each; reference %s" % (versions(), res, res, ref_path(res)))
    print("%-15s %6s %9s %11s %7s" % ("renderer", "spp", "cpu_s", "rmse", "ssim"))
    rows = {}
    for name in names:
        for spp in spps:
            img, cpu = RENDERERS[name](res, spp, 7, tmp)
            e, s = rmse(img, ref), ssim(img, ref)
            rows.setdefault(name, []).append((spp, cpu, e, s))
            print("%-15s %6d %9.3f %11.4e %7.4f" % (name, spp, cpu, e, s), flush=True)
    if "trevi" not in rows:
        return
    pts = [(cpu, e) for _, cpu, e, _ in rows["trevi"]]
    print("\nequal error: Trevi's CPU time to reach the peer's RMSE / the peer's CPU time")
    for name, rs in rows.items():
        if name == "trevi":
            continue
        for spp, cpu, e, _ in rs:
            t = trevi_time_at(pts, e)
            ratio = "outside Trevi's ladder" if t is None else "%.2f" % (t / cpu)
            print("%-15s %6d spp: %s" % (name, spp, ratio))


def main():
    cmds = {"reference": cmd_reference, "ladder": cmd_ladder}
    if len(sys.argv) < 2 or sys.argv[1] not in cmds:
        print(__doc__)
        sys.exit(2)
    cmds[sys.argv[1]](sys.argv[2:])


if __name__ == "__main__":
    main()
