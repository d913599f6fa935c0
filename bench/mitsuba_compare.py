#!/usr/bin/env python3
"""Time to a relative MSE of 1e-3 on the same scene, kalos against Mitsuba 3,
in one invocation on one machine.

Usage: python3 bench/mitsuba_compare.py [--scene scenes/cbox/cbox.xml]
           [--ref refs/cbox.pfm] [--spp 64] [--repeats 3]

Installs Mitsuba 3 into bench/.venv when it is missing (pip install mitsuba).
For each renderer and integrator it renders the scene at a fixed spp, times
the render (scene loading excluded for both), measures relMSE against the
reference with `kalos compare`, and converts to the time to relMSE 1e-3 as
t · relMSE / 1e-3 (for an unbiased estimator relMSE falls as 1/time; the
reference's own error, ~4e-6, is negligible at 1e-3). Medians over repeats
with different seeds. Pairs: kalos path vs Mitsuba path (scalar_rgb, and
llvm_ad_rgb when it runs), kalos light vs Mitsuba ptracer.
"""
import argparse, os, re, subprocess, sys, time, statistics, shutil, glob

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VENV = os.path.join(ROOT, "bench", ".venv")
KALOS = os.path.join(ROOT, "target", "release", "kalos")


def ensure_mitsuba():
    py = os.path.join(VENV, "bin", "python")
    try:
        subprocess.run([py, "-c", "import mitsuba"], check=True, capture_output=True)
    except Exception:
        subprocess.run([sys.executable, "-m", "venv", VENV], check=True)
        subprocess.run([py, "-m", "pip", "install", "-q", "mitsuba"], check=True)
    return py


def llvm_env():
    env = dict(os.environ)
    if "DRJIT_LIBLLVM_PATH" not in env:
        cands = sorted(glob.glob("/usr/lib/llvm-19/lib/libLLVM*.so*") + glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM*19*.so*"))
        if cands:
            env["DRJIT_LIBLLVM_PATH"] = cands[0]
    return env


MI_SCRIPT = r"""
import sys, time, mitsuba as mi
variant, scene_file, integrator, spp, seed, out = sys.argv[1:7]
mi.set_variant(variant)
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


def rel_mse(img, ref):
    out = subprocess.run([KALOS, "compare", img, ref], check=True, capture_output=True, text=True).stdout
    return float(re.search(r"relMSE\s+(\S+)", out).group(1))


def run_mitsuba(py, variant, scene, integrator, spp, seed, out, env):
    r = subprocess.run([py, "-c", MI_SCRIPT, variant, scene, integrator, str(spp), str(seed), out],
                       capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-2000:])
    return float(re.search(r"TIME (\S+)", r.stdout).group(1))


def run_kalos(scene, method, spp, seed, out):
    r = subprocess.run([KALOS, "render", scene, "--method", method, "--spp", str(spp), "--seed", str(seed),
                        "-o", out, "-q"], check=True, capture_output=True, text=True)
    # "..., 1.23 s (+0.01 s load/build), ..." : render time without loading
    return float(re.search(r"passes, (\S+) s", r.stdout).group(1))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=os.path.join(ROOT, "scenes/cbox/cbox.xml"))
    ap.add_argument("--ref", default=os.path.join(ROOT, "refs/cbox.pfm"))
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--pairs", default="path,light")
    ap.add_argument("--ensure-only", action="store_true",
                    help="only install Mitsuba into bench/.venv (if missing) and exit")
    args = ap.parse_args()
    if args.ensure_only:
        ensure_mitsuba()
        return
    if not os.path.exists(KALOS):
        subprocess.run(["cargo", "build", "--release"], cwd=ROOT, check=True)
    py = ensure_mitsuba()
    env = llvm_env()
    tmp = os.path.join(ROOT, "target", "bench-out")
    os.makedirs(tmp, exist_ok=True)
    rows = []

    def measure(label, fn):
        ts, es = [], []
        for k in range(args.repeats):
            out = os.path.join(tmp, f"{label.replace(' ', '_')}_{k}.exr")
            t = fn(k, out)
            e = rel_mse(out, args.ref)
            ts.append(t * e / 1e-3)
            es.append(e)
        r = (label, statistics.median(es), statistics.median(ts))
        print(f"{label:32s} relMSE@{args.spp}spp {r[1]:.3e}  time to 1e-3: {r[2]:.2f} s", flush=True)
        rows.append(r)
        return r

    pairs = args.pairs.split(",")
    if "path" in pairs:
        k = measure("kalos path", lambda s, o: run_kalos(args.scene, "path", args.spp, s, o))
        m = measure("mitsuba path scalar_rgb", lambda s, o: run_mitsuba(py, "scalar_rgb", args.scene, "path", args.spp, s, o, env))
        print(f"ratio kalos path / mitsuba path scalar_rgb: {k[2]/m[2]:.3f}")
        try:
            ml = measure("mitsuba path llvm_ad_rgb", lambda s, o: run_mitsuba(py, "llvm_ad_rgb", args.scene, "path", args.spp, s, o, env))
            print(f"ratio kalos path / mitsuba path llvm_ad_rgb: {k[2]/ml[2]:.3f}")
        except RuntimeError as e:
            print("llvm_ad_rgb did not run:", str(e).strip().splitlines()[-1])
    if "light" in pairs:
        k = measure("kalos light", lambda s, o: run_kalos(args.scene, "light", args.spp, s, o))
        m = measure("mitsuba ptracer scalar_rgb", lambda s, o: run_mitsuba(py, "scalar_rgb", args.scene, "ptracer", args.spp, s, o, env))
        print(f"ratio kalos light / mitsuba ptracer scalar_rgb: {k[2]/m[2]:.3f}")
        try:
            ml = measure("mitsuba ptracer llvm_ad_rgb", lambda s, o: run_mitsuba(py, "llvm_ad_rgb", args.scene, "ptracer", args.spp, s, o, env))
            print(f"ratio kalos light / mitsuba ptracer llvm_ad_rgb: {k[2]/ml[2]:.3f}")
        except RuntimeError as e:
            print("llvm_ad_rgb did not run:", str(e).strip().splitlines()[-1])


if __name__ == "__main__":
    main()
