#!/usr/bin/env python3
"""Progressive renders on the farm: error against time, and what a pass costs.

Measures, in one run (issue 38, docs/speed-accuracy.md "Progressive renders"):

1. the error-vs-time curve: one progressive farm render of N samples in passes
   of P (wall time at the end of each pass, from the client's per-pass progress
   lines time-stamped as they arrive), the one-shot renders (`--samples k
   --pass k`) of some of the same k with their wall times, and the RMSE of each
   against a converged reference (REF samples); the output after the final
   pass and after one intermediate pass is compared byte for byte with the
   one-shot render of that many samples;
2. the per-pass overhead of passes of 1, 4, 16 and 64 samples (N = 64): wall
   time each, (T(P) - T(64)) / (passes(P) - 1), and the coordinator's CPU
   seconds (utime + stime of /proc/PID/stat) per pass per pixel;
3. the coordinator's and the worker's peak RSS (VmHWM) on a big progressive
   job (a small sphere, one point light, `--samples 2 --pass 1`, tile 64), the
   state files' size and the wall time.

The scene of 1 and 2 is a copy of examples/cornell.xml, camera `front`,
written at 160x160 (everything else as in the example) into the work dir.
Every render runs on one farm: `trevi-coordinator` (RUST_LOG=info, its log
kept in the work dir) and one `trevi-worker --threads 2 --cpu-priority
normal`, on 127.0.0.1; part 3 starts a farm of its own with a fresh data dir,
which it removes afterwards.

Run (from the repository root; Linux only, it reads /proc):

    TREVI_BIN=/work/bench-bin python3 bench/progressive.py [--big 8192,4096] [--reuse-ref] \
        [--ref 1024] [--work /tmp/trevi-progressive-bench] > out.txt

The binaries are found in $TREVI_BIN, else target/release, else target/debug.
`--big 0` skips part 3; check the free disk first: the states of an S x S job
take 2 x 64 x S^2 bytes (8 GiB at 8192).  Python 3 standard library only.
"""

import argparse
import glob
import math
import os
import shutil
import struct
import subprocess
import sys
import threading
import time
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TICK = os.sysconf("SC_CLK_TCK")


def find_bin(name):
    dirs = []
    if os.environ.get("TREVI_BIN"):
        dirs.append(os.environ["TREVI_BIN"])
    dirs += [os.path.join(ROOT, "target", "release"), os.path.join(ROOT, "target", "debug")]
    for d in dirs:
        p = os.path.join(d, name)
        if os.access(p, os.X_OK):
            return p
    sys.exit(f"{name} not found in {dirs}")


def say(*a):
    print(*a, flush=True)


# ---------------------------------------------------------------- PNG decoding


def read_png(path):
    """8-bit grey/RGB/RGBA PNG -> (width, height, channels, flat list of floats 0..1)."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG")
    pos, idat, w = 8, [], None
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + n]
        pos += 12 + n
        if kind == b"IHDR":
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            if depth != 8 or interlace or ctype not in (0, 2, 6):
                raise ValueError(f"{path}: unsupported PNG (depth {depth}, type {ctype})")
            ch = {0: 1, 2: 3, 6: 4}[ctype]
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    raw = zlib.decompress(b"".join(idat))
    stride = w * ch
    out = bytearray(stride * h)
    prev = bytearray(stride)
    p = 0
    for y in range(h):
        ft = raw[p]
        line = bytearray(raw[p + 1 : p + 1 + stride])
        p += 1 + stride
        if ft == 1:
            for i in range(ch, stride):
                line[i] = (line[i] + line[i - ch]) & 255
        elif ft == 2:
            for i in range(stride):
                line[i] = (line[i] + prev[i]) & 255
        elif ft == 3:
            for i in range(stride):
                a = line[i - ch] if i >= ch else 0
                line[i] = (line[i] + ((a + prev[i]) >> 1)) & 255
        elif ft == 4:
            for i in range(stride):
                a = line[i - ch] if i >= ch else 0
                b = prev[i]
                c = prev[i - ch] if i >= ch else 0
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                pr = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[i] = (line[i] + pr) & 255
        out[y * stride : (y + 1) * stride] = line
        prev = line
    return w, h, ch, out


def rmse(a_path, b_path):
    """RMSE over the RGB channels, in 0..1 units of the 8-bit output."""
    wa, ha, ca, a = read_png(a_path)
    wb, hb, cb, b = read_png(b_path)
    if (wa, ha) != (wb, hb):
        raise ValueError("sizes differ")
    s, n = 0, 0
    for i in range(wa * ha):
        for c in range(min(3, ca, cb)):
            d = a[i * ca + c] - b[i * cb + c]
            s += d * d
            n += 1
    return math.sqrt(s / n) / 255.0


def same_bytes(a, b):
    with open(a, "rb") as fa, open(b, "rb") as fb:
        return fa.read() == fb.read()


# ---------------------------------------------------------------- the farm


def cpu_seconds(pid):
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime, stime


def vm_hwm_kib(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    return None


class Farm:
    def __init__(self, work, name):
        self.data = os.path.join(work, f"data-{name}")
        shutil.rmtree(self.data, ignore_errors=True)
        os.makedirs(self.data)
        env = dict(os.environ, RUST_LOG=os.environ.get("RUST_LOG", "info"))
        self.clog = open(os.path.join(work, f"coordinator-{name}.log"), "w")
        self.wlog = open(os.path.join(work, f"worker-{name}.log"), "w")
        self.coord = subprocess.Popen(
            [find_bin("trevi-coordinator"), "--listen", "127.0.0.1:0", "--data-dir", self.data],
            stdout=subprocess.PIPE, stderr=self.clog, env=env, text=True)
        addr = None
        for line in self.coord.stdout:
            if line.startswith("listening on "):
                addr = line.split()[-1]
                break
        if not addr:
            raise RuntimeError("the coordinator printed no address")
        # Keep draining its stdout so it never blocks.
        threading.Thread(target=lambda: [None for _ in self.coord.stdout], daemon=True).start()
        self.url = f"http://{addr}"
        self.worker = subprocess.Popen(
            [find_bin("trevi-worker"), "--coordinator", self.url, "--threads", "2",
             "--cpu-priority", "normal"],
            stdout=self.wlog, stderr=subprocess.STDOUT, env=env)

    def jobs(self):
        return set(os.listdir(os.path.join(self.data, "jobs"))) if os.path.isdir(
            os.path.join(self.data, "jobs")) else set()

    def submit(self, scene, out, samples, pass_, snapshot=None):
        """samples None: a plain (not progressive) job of the scene's own samples."""
        """Run one job; returns (wall s, coordinator CPU s, [(spp, t since start, coordinator
        CPU s since start)], job dir, client lines); self.last_worker_cpu is the worker's CPU s.

        snapshot: a sample count after whose pass the coordinator's copy of the
        output is copied to out + '.at<spp>.png' as soon as the line arrives.
        """
        before = self.jobs()
        c0 = cpu_seconds(self.coord.pid)
        w0 = cpu_seconds(self.worker.pid)
        t0 = time.monotonic()
        p = subprocess.Popen(
            [find_bin("trevi-submit"), scene, "--coordinator", self.url, "--camera", "front",
             "-o", out] + ([] if samples is None else ["--samples", str(samples), "--pass", str(pass_)]),
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        marks, seen, lines = [], 0, []
        for line in p.stderr:
            t = time.monotonic() - t0
            lines.append(line.rstrip())
            # "front: pass 2, 4/8 spp done, ..." / "front: pass 2, 8/8 spp, ..."
            for word in line.replace(",", " ").split():
                if "/" in word and word.split("/")[0].isdigit():
                    k = int(word.split("/")[0])
                    if k > seen:
                        seen = k
                        marks.append((k, t, cpu_seconds(self.coord.pid) - c0))
                        if snapshot == k:
                            new = sorted(self.jobs() - before, key=int)
                            for f in glob.glob(os.path.join(self.data, "jobs", new[-1], "*.png")) if new else []:
                                shutil.copy(f, out + f".at{k}.png")
                    break
        rc = p.wait()
        wall = time.monotonic() - t0
        cpu = cpu_seconds(self.coord.pid) - c0
        self.last_worker_cpu = cpu_seconds(self.worker.pid) - w0
        if rc != 0:
            raise RuntimeError(f"trevi-submit exited {rc}: {lines[-5:]}")
        new = sorted(self.jobs() - before, key=int)
        return wall, cpu, marks, (os.path.join(self.data, "jobs", new[-1]) if new else None), lines

    def stop(self, remove=False):
        for p in (self.worker, self.coord):
            p.terminate()
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        if remove:
            shutil.rmtree(self.data, ignore_errors=True)


# ---------------------------------------------------------------- the parts


def uptime():
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def write_small_cornell(work, size):
    src = open(os.path.join(ROOT, "examples", "cornell.xml")).read()
    old = 'width="480" height="480"'
    if old not in src:
        sys.exit("examples/cornell.xml: camera front's size not found")
    path = os.path.join(work, f"cornell-{size}.xml")
    with open(path, "w") as f:
        f.write(src.replace(old, f'width="{size}" height="{size}"'))
    return path


def part1(farm, work, scene, n, p, ref_samples, reuse_ref):
    say(f"== 1. error against time: N = {n}, passes of {p}, reference {ref_samples} samples")
    ref = os.path.join(work, f"ref{ref_samples}.png")
    if reuse_ref and os.path.exists(ref):
        say(f"reference: {ref_samples} samples in one pass, reused from an earlier run ({ref})")
    else:
        wall, _, _, _, _ = farm.submit(scene, ref, ref_samples, ref_samples)
        say(f"reference: {ref_samples} samples in one pass, {wall:.2f} s, worker CPU "
            f"{farm.last_worker_cpu:.1f} s")
    mid = (n // 2 // p) * p
    prog = os.path.join(work, f"prog{n}x{p}.png")
    wall, cpu, marks, jobdir, lines = farm.submit(scene, prog, n, p, snapshot=mid)
    pw = farm.last_worker_cpu
    say(f"progressive: {n} in passes of {p}: {wall:.2f} s wall, coordinator CPU {cpu:.2f} s, "
        f"worker CPU {pw:.2f} s")
    for line in lines:
        say("  client: " + line)
    at = {k: t for k, t, _ in marks}
    ks = [k for k in (p, 2 * p, 4 * p, 8 * p, 16 * p, 32 * p) if k <= n]
    if n not in ks:
        ks.append(n)
    say("| samples | one-shot s | one-shot worker CPU s | progressive s at that pass | "
        "RMSE one-shot | RMSE progressive |")
    say("|---|---|---|---|---|---|")
    rows = {}
    for k in ks:
        one = os.path.join(work, f"one{k}.png")
        w1, _, _, _, _ = farm.submit(scene, one, k, k)
        e1 = rmse(one, ref)
        ep = "—"
        if k == n:
            ep = f"{rmse(prog, ref):.4e}"
        elif os.path.exists(prog + f".at{k}.png"):
            ep = f"{rmse(prog + f'.at{k}.png', ref):.4e}"
        rows[k] = one
        tp = f"{at[k]:.2f}" if k in at else "—"
        say(f"| {k} | {w1:.2f} | {farm.last_worker_cpu:.2f} | {tp} | {e1:.4e} | {ep} |")
    say("progressive pass ends (samples: s since submission): "
        + ", ".join(f"{k}: {t:.2f}" for k, t, _ in marks))
    say(f"final output == one-shot {n}: {same_bytes(prog, rows[n])}")
    snap = prog + f".at{mid}.png"
    if mid in rows and os.path.exists(snap):
        say(f"output after pass {mid // p} ({mid} samples, copied from {jobdir}) == one-shot {mid}: "
            f"{same_bytes(snap, rows[mid])}")
    else:
        say(f"intermediate output at {mid} samples: not compared (no copy or no one-shot of it)")
    say(f"reference noise: {ref_samples} samples; if the error falls as 1/sqrt(samples), its own "
        f"RMSE is sqrt({n}/{ref_samples}) = {math.sqrt(n / ref_samples):.3f} of the {n}-sample "
        "render's true error, and the measured RMSE of a k-sample render is "
        f"sqrt(1 + k/{ref_samples}) times its true error")


def part2(farm, work, scene, size, n=64):
    say(f"== 2. per-pass overhead: N = {n} at {size}x{size}, farm of one worker with 2 threads")
    res = {}
    for p in (64, 16, 4, 1):
        out = os.path.join(work, f"over{p}.png")
        wall, cpu, marks, _, _ = farm.submit(scene, out, n, p)
        res[p] = (wall, cpu, n // p, farm.last_worker_cpu)
    say("| pass size | passes | wall s | overhead per pass s | worker CPU s | coordinator CPU s | "
        "coordinator CPU per pass per pixel ns |")
    say("|---|---|---|---|---|---|---|")
    t64 = res[64][0]
    for p in (64, 16, 4, 1):
        wall, cpu, passes, wcpu = res[p]
        over = "—" if passes == 1 else f"{(wall - t64) / (passes - 1):.3f}"
        say(f"| {p} | {passes} | {wall:.2f} | {over} | {wcpu:.2f} | {cpu:.2f} | "
            f"{cpu / passes / (size * size) * 1e9:.0f} |")


BIG_SCENE = """<?xml version="1.0" encoding="UTF-8"?>
<scene version="1">
  <settings background="0 0 0" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 0 0" radius="0.3">
    <surface diffuse="0.8 0.5 0.3"/>
  </sphere>
  <light type="point" position="2 3 4" color="1 1 1" intensity="1"/>
  <camera id="front" position="0 0 3" lookat="0 0 0" fov="40">
    <render width="{s}" height="{s}" output="big.png"/>
  </camera>
</scene>
"""


def part3(work, size):
    say(f"== 3. coordinator RSS on a {size}x{size} progressive job (--samples 2 --pass 1, tile 64)")
    say("df -h / before: " + subprocess.run(["df", "-h", "/"], capture_output=True, text=True)
        .stdout.strip().splitlines()[-1])
    scene = os.path.join(work, f"big{size}.xml")
    with open(scene, "w") as f:
        f.write(BIG_SCENE.replace("{s}", str(size)))
    farm = Farm(work, f"big{size}")
    try:
        time.sleep(0.5)  # let the worker register; the wall time includes its first lease
        c_hwm0 = vm_hwm_kib(farm.coord.pid)
        out = os.path.join(work, f"big{size}.png")
        # First a plain job of the same frame (1 sample a pixel, no states): the
        # stitching baseline of the coordinator's CPU and memory.
        wall0, cpu0, _, _, _ = farm.submit(scene, out, None, None)
        c_hwm_plain = vm_hwm_kib(farm.coord.pid)
        say(f"plain job first (1 sample a pixel, not progressive): wall {wall0:.1f} s, coordinator CPU "
            f"{cpu0:.1f} s ({cpu0 / (size * size) * 1e9:.0f} ns a pixel), worker CPU "
            f"{farm.last_worker_cpu:.1f} s, coordinator VmHWM after it {c_hwm_plain / 1024:.1f} MiB")
        os.remove(out)
        peak_state = [0]
        stop = threading.Event()

        def watch():
            while not stop.is_set():
                total = 0
                for f in glob.glob(os.path.join(farm.data, "jobs", "*", "state.*")):
                    try:
                        total += os.stat(f).st_blocks * 512
                    except OSError:
                        pass
                peak_state[0] = max(peak_state[0], total)
                stop.wait(1.0)

        th = threading.Thread(target=watch, daemon=True)
        th.start()
        wall, cpu, marks, jobdir, lines = farm.submit(scene, out, 2, 1)
        stop.set()
        th.join()
        c_hwm = vm_hwm_kib(farm.coord.pid)
        w_hwm = vm_hwm_kib(farm.worker.pid)
        states = {os.path.basename(f): (os.path.getsize(f), os.stat(f).st_blocks * 512)
                  for f in glob.glob(os.path.join(jobdir, "state.*"))}
        say(f"wall {wall:.1f} s; pass ends (samples: s since submission, coordinator CPU s): "
            + ", ".join(f"{k}: {t:.1f} s, {c:.1f} s" for k, t, c in marks))
        px = size * size
        say(f"coordinator CPU {cpu:.1f} s ({cpu / 2 / px * 1e9:.0f} ns a pixel a pass), worker CPU "
            f"{farm.last_worker_cpu:.1f} s; VmHWM coordinator {c_hwm / 1024:.1f} MiB "
            f"(at start {c_hwm0 / 1024:.1f} MiB), worker {w_hwm / 1024:.1f} MiB")
        for name, (size_b, used) in sorted(states.items()):
            say(f"{name}: {size_b / 2**30:.3f} GiB long, {used / 2**30:.3f} GiB on disk")
        say(f"largest on-disk total of the state files seen while it ran: {peak_state[0] / 2**30:.3f} GiB")
        say(f"output {os.path.getsize(out) / 2**20:.1f} MiB")
        for line in lines:
            say("  client: " + line)
    finally:
        farm.stop(remove=True)
        for f in glob.glob(os.path.join(work, f"big{size}*.png")):
            os.remove(f)
    say("df -h / after (data dir removed): " + subprocess.run(["df", "-h", "/"], capture_output=True,
        text=True).stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="/tmp/trevi-progressive-bench")
    ap.add_argument("--size", type=int, default=160)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--pass", dest="pass_", type=int, default=4)
    ap.add_argument("--ref", type=int, default=1024)
    ap.add_argument("--big", default="8192", help="part 3's frame edges, comma-separated; 0 skips it")
    ap.add_argument("--reuse-ref", action="store_true",
                    help="keep the reference render already in the work dir, if any")
    ap.add_argument("--parts", default="123")
    a = ap.parse_args()
    os.makedirs(a.work, exist_ok=True)
    say("uptime before: " + uptime())
    say(f"binaries: {os.path.dirname(find_bin('trevi-submit'))}; cores: {os.cpu_count()}")
    scene = write_small_cornell(a.work, a.size)
    say(f"scene: examples/cornell.xml camera front written at {a.size}x{a.size} to {scene}")
    t0 = time.monotonic()
    if "1" in a.parts or "2" in a.parts:
        farm = Farm(a.work, "small")
        try:
            time.sleep(0.5)
            if "1" in a.parts:
                part1(farm, a.work, scene, a.samples, a.pass_, a.ref, a.reuse_ref)
            if "2" in a.parts:
                part2(farm, a.work, scene, a.size)
            c0 = cpu_seconds(farm.coord.pid)
            time.sleep(5)
            say(f"coordinator CPU while idle: {(cpu_seconds(farm.coord.pid) - c0) / 5 * 1000:.1f} ms/s")
        finally:
            farm.stop()
        say(f"coordinator log: {farm.clog.name}")
    if "3" in a.parts:
        for big in (int(b) for b in a.big.split(",") if int(b) > 0):
            part3(a.work, big)
    say(f"total {time.monotonic() - t0:.0f} s")
    say("uptime after: " + uptime())


if __name__ == "__main__":
    main()
