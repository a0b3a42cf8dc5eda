#!/usr/bin/env python3
"""Equal-error comparison of Trevi with its peers on the area-lit Cornell box
(the scene bench/mitsuba/cornell_area.py writes for Trevi and Mitsuba 3, built
here for Blender Cycles from the same triangles), single-threaded, at a ladder
of sample counts, against a converged reference; in one run, with versions.

    python3 bench/peers.py reference [SPP [RES]] [--scene spot]   # Mitsuba (llvm if it loads), -> target/peers/
    python3 bench/peers.py ladder [RENDERERS] [--spp 1,4,16,64,256] [--res 64] [--scene spot]
                                  [--target 2e-2,1e-2]
    python3 bench/peers.py bias [SPP] [--threads 2] [--scene spot]   # Trevi converged vs reference
        RENDERERS: comma list of trevi, trevi-denoised, mitsuba-scalar,
        mitsuba-llvm, cycles, cycles-oidn (default: all that are installed)

--scene spot: the textured real-mesh variant (Spot the cow with its texture
in place of the boxes; cornell_area.py's `spot`; needs ../shared/meshes).

Each render is timed as the CPU time of the work alone (Trevi: the
trevi-submit child's user+system time, start to written file; Mitsuba:
mi.render; Cycles: bpy.ops.render.render, in this process), one thread
each. Errors: RMSE of linear RGB against the reference, and SSIM of the
luminance (7x7 box windows), both over the whole frame; and the RMSE away
from the light (rmse_off: the light and a one-pixel border left out, where
a denoiser's error at the light's edge, values up to 15, otherwise sets the
RMSE). The equal-error ratio of a peer at a sample count is Trevi's CPU time
to reach the peer's RMSE (log-log interpolation on Trevi's ladder) over the
peer's CPU time: below 1, Trevi is faster at equal error. Also printed:
samples per CPU-second, and the samples (and CPU time) each renderer needs
for the --target errors, both interpolated on its ladder. The reference
prints its own estimated RMSE (from two independent halves).

Installs (docs/speed-accuracy.md, "Equal-time error with denoising"): pip
install mitsuba bpy==5.0.1 OpenEXR numpy pyoidn==2.5.1.0; Debian's libllvm19
for mitsuba-llvm (bookworm main); trevi needs cargo build --release --bin
trevi-submit, trevi-denoised also a build of the trevi-denoise example (cargo
build --release -p trevi-denoise --features oidn --example denoise_exr, with
OIDN_DIR=<pyoidn's directory>/oidn; docs/denoise.md).
"""
import math
import os
import resource
import shutil
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


def ref_path(res, scene):
    tail = "" if scene == "boxes" else "_" + scene
    return os.path.join(OUT, "reference_%d%s.npy" % (res, tail))


# ------------------------------------------------------------- renderers

def trevi(res, spp, seed, tmp, scene, denoise=False):
    """trevi-submit --threads 1 on supersample sqrt(spp); CPU of the child."""
    n = int(round(math.sqrt(spp)))
    assert n * n == spp, "Trevi's strata: spp must be a square"
    name = "trevi_%d_%d" % (spp, seed)
    extra = ' aovs="albedo normal"' if denoise else ""
    xml_path = os.path.join(tmp, name + ".xml")
    with open(xml_path, "w") as f:
        f.write(ca.xml(width=res, height=res, supersample=n, seed=seed, output=name + ".exr",
                       extra=extra, scene=scene))
    for t in ca.textures(scene):
        shutil.copyfile(t, os.path.join(tmp, os.path.basename(t)))
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
    def render(res, spp, seed, tmp, scene_name):
        import mitsuba as mi
        import numpy as np
        mi.set_variant(variant)
        scene = mitsuba_scene(res, spp, scene_name)
        # Once untimed at the same sample count: the LLVM variant compiles
        # its kernels on the first render (the compile is not the render).
        mi.render(scene, spp=spp, seed=seed + 1)
        t = time.process_time()
        img = mi.render(scene, spp=spp, seed=seed)
        img = np.array(img, dtype=np.float64)[:, :, :3]
        return img, time.process_time() - t
    return render


def mitsuba_scene(res, spp, scene_name):
    """cornell_area's Mitsuba scene in the variant already set, one thread."""
    import drjit as dr
    import mitsuba as mi
    dr.set_thread_count(1)
    # cornell_area sets scalar_rgb itself: keep the variant chosen here.
    set_variant = mi.set_variant
    mi.set_variant = lambda *_: None
    try:
        return ca.mitsuba_scene(res=res, spp=spp, sampler="multijitter", scene_name=scene_name)
    finally:
        mi.set_variant = set_variant


def cycles(denoise):
    def render(res, spp, seed, tmp, scene):
        import bpy
        build_cycles(res, spp, seed, denoise, scene)
        path = os.path.join(tmp, "cycles_%d_%d_%d.exr" % (spp, seed, denoise))
        bpy.context.scene.render.filepath = path
        t = time.process_time()
        bpy.ops.render.render(write_still=True)
        cpu = time.process_time() - t
        return read_exr(path), cpu
    return render


def build_cycles(res, spp, seed, denoise, scene):
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
    for oid, verts, tris, kd, le, tex in ca.objects(scene):
        mesh = bpy.data.meshes.new(oid)
        mesh.from_pydata([tuple(v) for v in verts], [], [tuple(t) for t in tris])
        if tex is not None:
            layer = mesh.uv_layers.new(name="uv")
            for loop in mesh.loops:
                layer.data[loop.index].uv = tex[0][loop.vertex_index]
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
            if tex is not None:
                # sRGB PNG, bilinear ("Linear"), repeating; kd is 1 1 1.
                img = nodes.new("ShaderNodeTexImage")
                img.image = bpy.data.images.load(tex[1])
                img.image.colorspace_settings.name = "sRGB"
                img.interpolation = "Linear"
                img.extension = "REPEAT"
                mat.node_tree.links.new(img.outputs["Color"], shader.inputs["Color"])
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
    "trevi": lambda res, spp, seed, tmp, scene: trevi(res, spp, seed, tmp, scene),
    "trevi-denoised": lambda res, spp, seed, tmp, scene: trevi(res, spp, seed, tmp, scene,
                                                               denoise=True),
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
        import drjit
        import mitsuba
        out.append("mitsuba %s (drjit %s, LLVM %s)" % (
            mitsuba.__version__, drjit.__version__,
            os.environ.get("DRJIT_LIBLLVM_PATH", "found by drjit")))
    except Exception:
        pass
    try:
        from importlib.metadata import version
        out.append("pyoidn %s" % version("pyoidn"))
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


def off_light(ref):
    """The pixels away from the light: those whose reference luminance is
    below 2 and none of whose 8 neighbours' is (the light's radiance is 12-15;
    lit walls stay below 1). A denoiser's error at the light's anti-aliased
    edge, a few pixels of value up to 15, otherwise dominates the RMSE."""
    import numpy as np
    light = np.pad(ref @ np.array([0.2126, 0.7152, 0.0722]) > 2.0, 1)
    h, w = ref.shape[:2]
    near = np.zeros((h, w), dtype=bool)
    for dy in range(3):
        for dx in range(3):
            near |= light[dy:dy + h, dx:dx + w]
    return ~near


def rmse_masked(img, ref, mask):
    import numpy as np
    return float(np.sqrt(((img - ref) ** 2)[mask].mean()))


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


def cpu_model():
    with open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("model name"):
                return "%d CPUs: %s" % (os.cpu_count(), line.split(":", 1)[1].strip())
    return "%d CPUs" % os.cpu_count()


def load_avg():
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def x_at_error(points, target):
    """x (CPU time or spp) at RMSE `target`, log-log interpolated on a ladder
    (points: (x, rmse)); None outside it."""
    pts = sorted(points, key=lambda p: -p[1])
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if e1 <= target <= e0:
            f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))
    return None


# ------------------------------------------------------------- commands

def scene_arg(argv):
    """Takes `--scene NAME` out of argv; returns NAME (default boxes)."""
    if "--scene" in argv:
        i = argv.index("--scene")
        name = argv[i + 1]
        del argv[i:i + 2]
        if name not in ca.SCENES:
            sys.exit("--scene: one of %s" % ", ".join(ca.SCENES))
        return name
    return "boxes"


def cmd_reference(argv):
    import numpy as np
    argv = list(argv)
    scene_name = scene_arg(argv)
    spp = int(argv[0]) if argv else 65536
    res = int(argv[1]) if len(argv) > 1 else ca.RES
    import mitsuba as mi
    try:
        mi.set_variant("llvm_ad_rgb")
    except Exception:
        mi.set_variant("scalar_rgb")
    scene = mitsuba_scene(res, spp, scene_name)
    t = time.time()
    # Chunks of 4096 spp, an even number of them, summed in two halves: the
    # RMSE between the halves' means, halved, estimates the reference's own
    # RMSE against the converged image (independent chunks: the mean of two
    # halves has half the variance of one, their difference twice).
    chunks = max(2, spp // 4096)
    chunks += chunks % 2
    halves = [None, None]
    for c in range(chunks):
        img = np.array(mi.render(scene, spp=spp // chunks, seed=90_000 + c), dtype=np.float64)[:, :, :3]
        h = c % 2
        halves[h] = img if halves[h] is None else halves[h] + img
    os.makedirs(OUT, exist_ok=True)
    a, b = halves[0] / (chunks // 2), halves[1] / (chunks // 2)
    np.save(ref_path(res, scene_name), (a + b) / 2)
    print("reference %s %dx%d, %d spp (%s, %s): %.0f s wall -> %s" % (
        scene_name, res, res, spp // chunks * chunks, mi.variant(), versions(), time.time() - t,
        ref_path(res, scene_name)))
    print("its own estimated RMSE: %.2e (half the RMSE between its two halves, %.2e)" % (
        rmse(a, b) / 2, rmse(a, b)))


def cmd_ladder(argv):
    import numpy as np
    names = list(RENDERERS)
    spps = [1, 4, 16, 64, 256]
    res = ca.RES
    args = list(argv)
    scene = scene_arg(args)
    targets = [2e-2, 1e-2]
    while args:
        a = args.pop(0)
        if a == "--spp":
            spps = [int(s) for s in args.pop(0).split(",")]
        elif a == "--res":
            res = int(args.pop(0))
        elif a == "--target":
            targets = [float(s) for s in args.pop(0).split(",")]
        else:
            names = a.split(",")
    ref = np.load(ref_path(res, scene))
    names = [n for n in names if available(n)]
    mask = off_light(ref)
    tmp = tempfile.mkdtemp(prefix="trevi-peers-")
    print("# %s; scene %s %dx%d; one thread each; reference %s" % (
        versions(), scene, res, res, ref_path(res, scene)))
    print("# %s; %s; load average %s" % (time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                                        cpu_model(), load_avg()))
    print("# rmse_off: RMSE over the %d of %d pixels away from the light (off_light)" % (
        mask.sum(), mask.size))
    print("%-15s %6s %9s %11s %11s %7s %12s" % ("renderer", "spp", "cpu_s", "rmse", "rmse_off",
                                                "ssim", "Msamples/s"))
    rows = {}
    for name in names:
        for spp in spps:
            img, cpu = RENDERERS[name](res, spp, 7, tmp, scene)
            e, s, eo = rmse(img, ref), ssim(img, ref), rmse_masked(img, ref, mask)
            rows.setdefault(name, []).append((spp, cpu, e, s, eo))
            print("%-15s %6d %9.3f %11.4e %11.4e %7.4f %12.3f" % (
                name, spp, cpu, e, eo, s, res * res * spp / cpu / 1e6), flush=True)
    print("# %s; load average at the end %s" % (
        time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), load_avg()))
    for col, label in ((2, "rmse"), (4, "rmse_off")):
        print("\nsamples per pixel (and CPU seconds) each needs for a %s of %s"
              " (log-log interpolation on its ladder; '-' outside it)"
              % (label, " / ".join("%.0e" % t for t in targets)))
        for name, rs in rows.items():
            cells = []
            for target in targets:
                n = x_at_error([(r[0], r[col]) for r in rs], target)
                t = x_at_error([(r[1], r[col]) for r in rs], target)
                if n is not None:
                    cells.append("%.0f spp (%.3f s)" % (n, t))
                elif rs[0][col] <= target:  # below the target from the first rung on
                    cells.append("<= %d spp (%.3f s)" % (rs[0][0], rs[0][1]))
                else:
                    cells.append("-")
            print("%-15s %s" % (name, " / ".join(cells)))
    if "trevi" not in rows:
        return
    for col, label in ((2, "rmse"), (4, "rmse_off")):
        pts = [(r[1], r[col]) for r in rows["trevi"]]
        print("\nequal %s: Trevi's CPU time to reach the peer's %s / the peer's CPU time"
              % (label, label))
        for name, rs in rows.items():
            if name == "trevi":
                continue
            inside = []
            cells = []
            for r in rs:
                t = x_at_error(pts, r[col])
                cells.append("%d: %s" % (r[0], "-" if t is None else "%.2f" % (t / r[1])))
                if t is not None:
                    inside.append(t / r[1])
            gm = "-"
            if inside:
                gm = "%.2f" % math.exp(sum(math.log(x) for x in inside) / len(inside))
            print("%-15s %s; geometric mean %s" % (name, ", ".join(cells), gm))


def cmd_bias(argv):
    """Trevi's converged image against the reference: two renders of SPP
    (a square; default 4096) with seeds 11 and 12 on THREADS threads (default
    2; not timed); the RMSE of their mean, of its own noise (half the RMSE
    between the two) and what remains, sqrt(mean^2 - noise^2): the difference
    between Trevi's and Mitsuba's converged images plus the reference's own
    noise. Also the mean signed difference per channel, away from the light."""
    import numpy as np
    args = list(argv)
    scene = scene_arg(args)
    threads = "2"
    if "--threads" in args:
        i = args.index("--threads")
        threads = args[i + 1]
        del args[i:i + 2]
    spp = int(args[0]) if args else 4096
    res = ca.RES
    n = int(round(math.sqrt(spp)))
    assert n * n == spp, "Trevi's strata: spp must be a square"
    ref = np.load(ref_path(res, scene))
    mask = off_light(ref)
    tmp = tempfile.mkdtemp(prefix="trevi-bias-")
    for t in ca.textures(scene):
        shutil.copyfile(t, os.path.join(tmp, os.path.basename(t)))
    print("# %s; scene %s %dx%d, Trevi %d spp on %s threads, seeds 11 and 12; %s; load average %s"
          % (versions(), scene, res, res, spp, threads,
             time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), load_avg()))
    imgs = []
    for seed in (11, 12):
        name = "bias_%d_%d" % (spp, seed)
        xml_path = os.path.join(tmp, name + ".xml")
        with open(xml_path, "w") as f:
            f.write(ca.xml(width=res, height=res, supersample=n, seed=seed, output=name + ".exr",
                           scene=scene))
        subprocess.run([SUBMIT, xml_path, "--quiet", "--threads", threads], check=True)
        imgs.append(read_exr(os.path.join(tmp, name + ".exr")))
        img = imgs[-1]
        print("seed %d: rmse %.3e, away from the light %.3e" % (
            seed, rmse(img, ref), rmse_masked(img, ref, mask)))
    a, b = imgs
    m = (a + b) / 2
    whole = np.ones(mask.shape, dtype=bool)
    for label, sel in (("whole frame", whole), ("away from the light", mask)):
        e, noise = rmse_masked(m, ref, sel), rmse_masked(a, b, sel) / 2
        rest = math.sqrt(max(e * e - noise * noise, 0.0))
        print("%s: mean of the two %.3e, its own noise %.3e, remaining difference %.3e" % (
            label, e, noise, rest))
    d = (m - ref)[mask].reshape(-1, 3).mean(0)
    print("mean signed difference away from the light (R G B): %.2e %.2e %.2e" % tuple(d))
    print("# load average at the end %s" % load_avg())


def main():
    cmds = {"reference": cmd_reference, "ladder": cmd_ladder, "bias": cmd_bias}
    if len(sys.argv) < 2 or sys.argv[1] not in cmds:
        print(__doc__)
        sys.exit(2)
    cmds[sys.argv[1]](sys.argv[2:])


if __name__ == "__main__":
    main()
