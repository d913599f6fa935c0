#!/usr/bin/env python3
"""Time to a relative MSE of 1e-3 on the same scene, kalos against Mitsuba 3,
in one invocation on one machine.

Usage: python3 bench/mitsuba_compare.py [--scene cbox|big-room-textured|FILE.xml]
           [--ref FILE] [--spp 64] [--repeats 3] [--pairs path,light]
           [--variants scalar_rgb,llvm_ad_rgb] [--kalos [LABEL=]BIN ...]
           [--ref-spp 1024] [--mi-samplers independent,multijitter,ldsampler]
           [--kalos-samplers independent,sobol]

Installs Mitsuba 3 into bench/.venv when it is missing (pip install mitsuba
numpy).
Pairs: kalos `path` against Mitsuba `path`, kalos `light` against Mitsuba
`ptracer`, each Mitsuba variant in --variants (`llvm_ad_rgb` needs Debian's
libllvm19; DRJIT_LIBLLVM_PATH is set to it when found).

Scenes: `cbox` is scenes/cbox/cbox.xml against refs/cbox.pfm. `big-room-textured`
is written by `kalos gen big-room-textured` into bench/.cache/ (not committed),
and its reference is rendered there by Mitsuba `path` at --ref-spp as two halves
of different seeds (llvm_ad_rgb when it runs, else scalar_rgb); the reference's
own relMSE, relMSE(half1, half2) / 4, is subtracted from every measured
relMSE. Any other XML file needs --ref.

For each renderer the scene is rendered at a fixed spp, the render is timed
(scene loading excluded for both; Mitsuba after a 1-spp warm-up, which
compiles the llvm kernels), relMSE is measured against the reference with
`kalos compare`, and the time to relMSE 1e-3 is t · relMSE / 1e-3 (for an
unbiased estimator relMSE falls as 1/time). The renderers run alternately,
one repeat of each in turn with the repeat's seed, so that a change in the
machine's load falls on all of them; the load average is printed before and
after. The figures are medians over repeats; a ratio is the median of
the ratios within each repeat (the runs of one repeat are back to back).

Several --kalos binaries (e.g. builds for different target CPUs) are timed
alternately with each other; `--variants none` leaves Mitsuba out.

Samplers: without --mi-samplers Mitsuba uses the scene file's sampler. With
it, every Mitsuba variant runs once per listed sampler type (independent,
multijitter, ldsampler, orthogonal, stratified): the scene's `<sampler>`
elements (includes inlined; one is added to a sensor that has none) get that
type and keep their other parameters, and the sample count is --spp as
before. --kalos-samplers runs kalos `path` and `light` once per `--sampler`
value. All these configurations
still run alternately within each repeat. Each pair then prints, per
Mitsuba variant, the best kalos configuration over the best Mitsuba one
(best: the lowest median time to relMSE 1e-3).
"""
import argparse, glob, json, os, re, statistics, subprocess, sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VENV = os.path.join(ROOT, "bench", ".venv")
CACHE = os.path.join(ROOT, "bench", ".cache")
KALOS = os.path.join(ROOT, "target", "release", "kalos")
TARGET = 1e-3
MI_INTEGRATOR = {"path": "path", "light": "ptracer"}


def ensure_mitsuba():
    py = os.path.join(VENV, "bin", "python")
    try:
        subprocess.run([py, "-c", "import mitsuba, numpy"], check=True, capture_output=True)
    except Exception:
        if not os.path.exists(py):
            subprocess.run([sys.executable, "-m", "venv", VENV], check=True)
        subprocess.run([py, "-m", "pip", "install", "-q", "mitsuba", "numpy"], check=True)
    return py


def llvm_env():
    env = dict(os.environ)
    if "DRJIT_LIBLLVM_PATH" not in env:
        cands = sorted(glob.glob("/usr/lib/llvm-19/lib/libLLVM*.so*")
                       + glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM*19*.so*"))
        if cands:
            env["DRJIT_LIBLLVM_PATH"] = cands[0]
    return env


MI_SCRIPT = r"""
import os, sys, time, mitsuba as mi
variant, scene_file, integrator, spp, seed, out = sys.argv[1:7]
sampler = sys.argv[7] if len(sys.argv) > 7 else ''
mi.set_variant(variant)
if sampler:
    # The scene with its includes inlined and every sampler set to `sampler`;
    # the scene's directory stays on the file resolver for meshes and textures
    import xml.etree.ElementTree as ET
    def inline(path):
        root = ET.parse(path).getroot()
        def walk(el):
            for i, c in reversed(list(enumerate(el))):
                if c.tag == 'include':
                    sub = inline(os.path.join(os.path.dirname(path), c.get('filename')))
                    el[i:i + 1] = list(sub)
                else:
                    walk(c)
        walk(root)
        return root
    root = inline(scene_file)
    for sensor in root.iter('sensor'):
        if sensor.find('sampler') is None:
            ET.SubElement(sensor, 'sampler', {'type': sampler})
    for s in root.iter('sampler'):
        s.set('type', sampler)
    fr = mi.file_resolver() if hasattr(mi, 'file_resolver') else mi.Thread.thread().file_resolver()
    fr.prepend(os.path.dirname(os.path.abspath(scene_file)))
    scene = mi.load_string(ET.tostring(root, encoding='unicode'))
else:
    scene = mi.load_file(scene_file)
integ = mi.load_dict({'type': integrator, 'max_depth': -1})
# warm-up (JIT compilation for llvm) not timed
mi.render(scene, integrator=integ, spp=1, seed=999)
t = time.perf_counter()
img = mi.render(scene, integrator=integ, spp=int(spp), seed=int(seed))
if variant.startswith('llvm'):
    import drjit as dr
    dr.eval(img); dr.sync_thread()
t = time.perf_counter() - t
mi.util.write_bitmap(out, img)
print(f"TIME {t}")
"""


def rel_mse(kalos, img, ref):
    out = subprocess.run([kalos, "compare", img, ref], check=True, capture_output=True, text=True).stdout
    return float(re.search(r"relMSE\s+(\S+)", out).group(1))


def run_mitsuba(py, variant, scene, integrator, spp, seed, out, env, sampler=""):
    r = subprocess.run([py, "-c", MI_SCRIPT, variant, scene, integrator, str(spp), str(seed), out]
                       + ([sampler] if sampler else []),
                       capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-2000:])
    return float(re.search(r"TIME (\S+)", r.stdout).group(1))


def run_kalos(kalos, scene, method, spp, seed, out, sampler=""):
    r = subprocess.run([kalos, "render", scene, "--method", method, "--spp", str(spp), "--seed", str(seed),
                        "-o", out, "-q"] + (["--sampler", sampler] if sampler else []),
                       check=True, capture_output=True, text=True)
    # "..., 1.23 s (+0.01 s load/build), ..." : render time without loading
    return float(re.search(r"passes, (\S+) s", r.stdout).group(1))


def loadavg():
    return "load average %.2f %.2f %.2f" % os.getloadavg()


def big_room(kalos, py, env, ref_spp):
    """The generated textured room and its Mitsuba reference, in bench/.cache."""
    d = os.path.join(CACHE, "big-room-textured")
    scene = os.path.join(d, "scene.xml")
    if not os.path.exists(scene):
        subprocess.run([kalos, "gen", "big-room-textured", "-o", d], check=True)
    ref = os.path.join(d, f"ref-{ref_spp}spp.exr")
    meta = ref + ".json"
    if not (os.path.exists(ref) and os.path.exists(meta)):
        variant = "llvm_ad_rgb"
        halves = [os.path.join(d, f"ref-half{k}.exr") for k in (1, 2)]
        for k, h in enumerate(halves):
            if os.path.exists(h):
                continue  # left by a run that stopped before averaging
            print(f"rendering the reference: Mitsuba path, half {k + 1}, {ref_spp // 2} spp", flush=True)
            try:
                run_mitsuba(py, variant, scene, "path", ref_spp // 2, 1000 + k, h, env)
            except RuntimeError:
                variant = "scalar_rgb"
                run_mitsuba(py, variant, scene, "path", ref_spp // 2, 1000 + k, h, env)
        avg = r"""
import sys, mitsuba as mi, numpy as np
mi.set_variant('scalar_rgb')
a, b, out = sys.argv[1:4]
x = (np.array(mi.Bitmap(a)) + np.array(mi.Bitmap(b))) * 0.5
mi.Bitmap(x.astype(np.float32)).write(out)
"""
        subprocess.run([py, "-c", avg, halves[0], halves[1], ref], check=True, env=env)
        e_ref = rel_mse(kalos, halves[0], halves[1]) / 4.0
        with open(meta, "w") as f:
            json.dump({"spp": ref_spp, "variant": variant, "relmse_self": e_ref}, f)
        for h in halves:
            os.remove(h)
    with open(meta) as f:
        e_ref = json.load(f)["relmse_self"]
    return scene, ref, e_ref


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="cbox")
    ap.add_argument("--ref")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--pairs", default="path,light")
    ap.add_argument("--variants", default="scalar_rgb,llvm_ad_rgb")
    ap.add_argument("--kalos", action="append", help="[LABEL=]BIN, repeatable")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--mi-samplers", default="",
                    help="comma-separated Mitsuba sampler types, each run per variant "
                         "(default: the scene file's sampler)")
    ap.add_argument("--kalos-samplers", default="",
                    help="comma-separated kalos --sampler values for `path` and `light` (default: kalos's default)")
    ap.add_argument("--ensure-only", action="store_true",
                    help="only install Mitsuba into bench/.venv (if missing) and exit")
    args = ap.parse_args()
    if args.ensure_only:
        ensure_mitsuba()
        return
    kalos_bins = []
    for k in args.kalos or [KALOS]:
        label, _, path = k.rpartition("=")
        kalos_bins.append((f"kalos[{label}]" if label else "kalos", os.path.abspath(path)))
    if not os.path.exists(kalos_bins[0][1]):
        subprocess.run(["cargo", "build", "--release"], cwd=ROOT, check=True)
    kalos = kalos_bins[0][1]
    py = ensure_mitsuba()
    env = llvm_env()
    variants = [v for v in args.variants.split(",") if v and v != "none"]

    e_ref = 0.0
    if args.scene == "cbox":
        scene, ref = os.path.join(ROOT, "scenes/cbox/cbox.xml"), os.path.join(ROOT, "refs/cbox.pfm")
    elif args.scene == "big-room-textured":
        scene, ref, e_ref = big_room(kalos, py, env, args.ref_spp)
    else:
        scene, ref = args.scene, args.ref
        if not ref:
            sys.exit("--ref is needed with a scene file")
    if args.ref:
        ref = args.ref
    tmp = os.path.join(ROOT, "target", "bench-out")
    os.makedirs(tmp, exist_ok=True)
    print(f"scene {scene}, reference {ref} (own relMSE {e_ref:.2e} subtracted), {args.spp} spp, "
          f"{args.repeats} repeats, {loadavg()}", flush=True)

    mi_samplers = [s for s in args.mi_samplers.split(",") if s] or [""]
    kalos_samplers = [s for s in args.kalos_samplers.split(",") if s] or [""]
    for method in args.pairs.split(","):
        mi_integ = MI_INTEGRATOR[method]
        ks = kalos_samplers if method in ("path", "light") else [""]
        runners, kalos_runners = [], {}  # kalos_runners: binary label -> its runner labels
        for label, b in kalos_bins:
            for ksamp in ks:
                name = f"{label} {method}" + (f" {ksamp}" if ksamp else "")
                runners.append((name, lambda s, o, b=b, ksamp=ksamp:
                                run_kalos(b, scene, method, args.spp, s, o, ksamp)))
                kalos_runners.setdefault(label, []).append(name)
        mi_runners = {}  # variant -> its runner labels
        for v in variants:
            for msamp in mi_samplers:
                name = f"mitsuba {mi_integ} {v}" + (f" {msamp}" if msamp else "")
                runners.append((name, lambda s, o, v=v, msamp=msamp:
                                run_mitsuba(py, v, scene, mi_integ, args.spp, s, o, env, msamp)))
                mi_runners.setdefault(v, []).append(name)
        width = max(34, max(len(label) for label, _ in runners))
        results = {label: ([], []) for label, _ in runners}
        dead = set()
        # Step the renderers alternately: repeat k of each, then k + 1
        for k in range(args.repeats):
            for label, fn in runners:
                if label in dead:
                    continue
                out = os.path.join(tmp, f"{label.replace(' ', '_')}_{k}.exr")
                try:
                    t = fn(k + 1, out)
                except RuntimeError as e:
                    print(f"{label} did not run: {str(e).strip().splitlines()[-1]}", flush=True)
                    dead.add(label)
                    continue
                e = max(rel_mse(kalos, out, ref) - e_ref, 1e-12)
                results[label][0].append(t)
                results[label][1].append(e)
                print(f"  {label:{width}s} seed {k + 1}: {t:7.2f} s, relMSE {e:.3e}", flush=True)
        rows = {}
        for label, (ts, es) in results.items():
            if ts:
                ttt = [t * e / TARGET for t, e in zip(ts, es)]
                rows[label] = (statistics.median(ts), statistics.median(es), statistics.median(ttt))
        print(f"{method}: median render time, relMSE at {args.spp} spp, time to relMSE {TARGET:g}")
        for label, (t, e, ttt) in rows.items():
            print(f"  {label:{width}s} {t:7.2f} s  {e:.3e}  {ttt:8.2f} s")
        # Ratios of the same repeat, then their median: a repeat's renderers
        # ran back to back, so a load that changes between repeats cancels
        def paired(a, b):
            (ta, ea), (tb, eb) = results[a], results[b]
            return statistics.median(x * y / (u * v) for x, y, u, v in zip(ta, ea, tb, eb))
        if len(ks) == 1 and len(mi_samplers) == 1:
            for label, _ in kalos_bins:
                mine = kalos_runners[label][0]
                for other in rows:
                    if mine in rows and other != mine and (label == kalos_bins[0][0] or not other.startswith("kalos")):
                        print(f"ratio {mine} / {other}: {paired(mine, other):.3f} "
                              f"(median of the repeats' ratios; ratio of the medians {rows[mine][2] / rows[other][2]:.3f})")
        else:
            # Each side at its best configuration: the lowest median time to the target
            def best(names):
                names = [n for n in names if n in rows]
                return min(names, key=lambda n: rows[n][2]) if names else None
            for label, _ in kalos_bins:
                mine = best(kalos_runners[label])
                for v in variants:
                    other = best(mi_runners[v])
                    if mine and other:
                        print(f"best ratio {v}: {mine} / {other}: {rows[mine][2] / rows[other][2]:.3f} "
                              f"(ratio of the medians; median of the repeats' ratios {paired(mine, other):.3f})")
        print(loadavg(), flush=True)


if __name__ == "__main__":
    main()
