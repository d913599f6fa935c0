#!/usr/bin/env python3
"""Equal wall time, LuxCore's engines against kalos's methods, on the same
Mitsuba scene, in one invocation on one machine.

Usage: PY bench/luxcore_compare.py SCENE.xml --ref REF.pfm [--time 20]
           [--kalos-methods path,light,plb] [--engines path,bidir,light,photongi]
           [--repeats 1] [--threads 2] [--kalos BIN] [--ref-noise R]

PY is a Python 3.11 with pip `pyluxcore` (2.11.2 measured) and numpy; kalos
runs as a subprocess (`target/release/kalos`, built when missing). It is a
benchmark, not a CI test.

The scene is converted for LuxCore by hand, from the Mitsuba XML (includes,
`<default>`s, `<ref>`s; the shapes `obj`, `cube`, `rectangle` and `sphere`,
the last tessellated; `to_world` made of `translate`, `scale`, `rotate`,
`matrix`, `lookat`):
- `diffuse` → `matte` with kd = reflectance;
- `roughplastic` → `glossy2` with kd = diffuse_reflectance, ks = the
  coat's normal-incidence Fresnel reflectance ((η − 1)/(η + 1))², the
  roughness α as u/v roughness, no multibounce: the nearest LuxCore model,
  *not* the same BSDF (the image means show what that costs);
- an area light → a `matte` whose `emission` is the radiance, with gain 1,
  power 0, efficacy 0 (no normalisation);
- the camera: LuxCore's `fieldofview` spans the longer image axis, so the
  Mitsuba fov is converted to it; LuxCore's perspective camera puts the
  image one row low, so `screenwindow` is shifted by one pixel to lift it;
- film filter NONE (each sample counts in its pixel only, as Mitsuba's box
  filter), a linear image pipeline (no tone map, no gamma);
- every engine: max depth 128, Russian roulette from depth 5, no
  clamping; PhotonGI (indirect cache) with photon depth 16 (on scenes lit
  through a gap the light needs many bounces to reach the camera's room)
  and its cache capped at PHOTON_COUNT photons, built inside the render's
  wall time.

LIGHTCPU leaves an emitter seen directly by the camera black (on cbox the
luminaire), which its relMSE and mean include. LUX_LOG=1 in the
environment prints LuxCore's log.

Engines: `path` PATHCPU (SOBOL), `bidir` BIDIRCPU, `light` LIGHTCPU (both
RANDOM), `photongi` PATHCPU with the PhotonGI indirect cache. Each runs for
--time seconds of wall time (`batch.halttime`, scene set-up excluded; the
PhotonGI cache is built inside that time), each kalos method for --time
seconds (`render --time`, loading excluded). The renderers run one after
the other, alternating over --repeats, so that a change in the machine's
load falls on all of them; the load average is printed before and after.

Each image is measured against --ref with `kalos compare`: relMSE (mean
over pixels and channels of (x − ref)² / (ref² + 0.01)) and the channel
means, printed beside the reference's, so that bias shows. --ref-noise is
the reference's own relMSE (its half-against-half relMSE / 4), subtracted
from every relMSE as in bench/mitsuba_compare.py; the ratio column divides
by the best kalos method's relMSE.
"""
import argparse
import math
import os
import re
import statistics
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KALOS = os.path.join(ROOT, "target", "release", "kalos")
MAX_DEPTH = 128
RR_DEPTH = 5
PHOTON_DEPTH = 16
# Photons the PhotonGI indirect cache stores: LuxCore's default (stop when
# the cache converges) traced 2 M photons and stored 3.4 M in over a minute
# on two-rooms-baffle here, longer than the render; the cache is built
# inside the render's wall time
PHOTON_COUNT = 200_000


# --- Mitsuba XML -----------------------------------------------------------


def load_xml(path, defaults=None):
    """The <scene> element with its includes spliced in, and $name filled."""
    defaults = dict(defaults or {})
    root = ET.parse(path).getroot()
    base = os.path.dirname(path)
    out = ET.Element("scene")
    for el in root:
        if el.tag == "include":
            inc = load_xml(os.path.join(base, el.get("filename")), defaults)
            out.extend(list(inc))
        elif el.tag == "default":
            defaults.setdefault(el.get("name"), el.get("value"))
        else:
            out.append(el)

    def fill(e):
        for k, v in e.attrib.items():
            if v.startswith("$"):
                e.set(k, defaults[v[1:]])
        for c in e:
            fill(c)

    fill(out)
    out.set("_base", base)
    return out


def child(el, tag, name):
    for c in el:
        if c.tag == tag and c.get("name") == name:
            return c
    return None


def value(el, name, default=None):
    for c in el:
        if c.get("name") == name and c.tag in ("float", "integer", "string", "boolean"):
            return c.get("value")
    return default


def rgb(el, name, default=None):
    c = child(el, "rgb", name)
    if c is None:
        f = child(el, "float", name)
        return [float(f.get("value"))] * 3 if f is not None else default
    return [float(x) for x in re.split(r"[,\s]+", c.get("value").strip())]


def vec(el, keys="xyz", default=0.0):
    if el.get("value") is not None:
        return np.array([float(x) for x in re.split(r"[,\s]+", el.get("value").strip())])
    return np.array([float(el.get(k, default)) for k in keys])


def lookat(origin, target, up):
    """Mitsuba's look-at matrix: camera +z forward, +y up, +x left."""
    d = target - origin
    d = d / np.linalg.norm(d)
    left = np.cross(up, d)
    left = left / np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


def transform(el):
    """The 4×4 to_world matrix of a <transform> element (applied in order)."""
    m = np.eye(4)
    if el is None:
        return m
    for t in el:
        a = np.eye(4)
        if t.tag == "translate":
            a[:3, 3] = vec(t)
        elif t.tag == "scale":
            if t.get("value") is not None and len(t.get("value").split(",")) == 1:
                a[:3, :3] *= float(t.get("value"))
            else:
                a[:3, :3] = np.diag(vec(t, default=1.0))
        elif t.tag == "rotate":
            axis = vec(t)
            axis = axis / np.linalg.norm(axis)
            th = math.radians(float(t.get("angle")))
            x, y, z = axis
            c, s, C = math.cos(th), math.sin(th), 1 - math.cos(th)
            a[:3, :3] = [
                [x * x * C + c, x * y * C - z * s, x * z * C + y * s],
                [y * x * C + z * s, y * y * C + c, y * z * C - x * s],
                [z * x * C - y * s, z * y * C + x * s, z * z * C + c],
            ]
        elif t.tag == "matrix":
            a = np.array([float(x) for x in re.split(r"[,\s]+", t.get("value").strip())]).reshape(4, 4)
        elif t.tag == "lookat":
            a = lookat(vec(ET.Element("v", value=t.get("origin"))), vec(ET.Element("v", value=t.get("target"))),
                       vec(ET.Element("v", value=t.get("up"))))
        else:
            sys.exit(f"unsupported transform <{t.tag}>")
        m = a @ m
    return m


def read_obj(path):
    pos, tris = [], []
    for line in open(path):
        f = line.split()
        if not f:
            continue
        if f[0] == "v":
            pos.append([float(x) for x in f[1:4]])
        elif f[0] == "f":
            idx = [int(x.split("/")[0]) for x in f[1:]]
            idx = [i - 1 if i > 0 else len(pos) + i for i in idx]
            for k in range(1, len(idx) - 1):
                tris.append([idx[0], idx[k], idx[k + 1]])
    return np.array(pos, dtype=np.float64), np.array(tris, dtype=np.int64)


def cube():
    """Mitsuba's cube, [−1, 1]³, outward faces."""
    pos, tris = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = [(axis + 1) % 3, (axis + 2) % 3]
            base = len(pos)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = [0.0, 0.0, 0.0]
                p[axis], p[u], p[v] = sign, a, b
                pos.append(p)
            # (u, v, axis) is right-handed: counter-clockwise seen from +axis
            if sign > 0:
                tris += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
            else:
                tris += [[base, base + 2, base + 1], [base, base + 3, base + 2]]
    return np.array(pos), np.array(tris)


def rectangle():
    """Mitsuba's rectangle, [−1, 1]² at z = 0, facing +z."""
    return np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64), np.array([[0, 1, 2], [0, 2, 3]])


def sphere(center, radius, n_theta=96, n_phi=192):
    pos, tris = [], []
    for i in range(n_theta + 1):
        th = math.pi * i / n_theta
        for j in range(n_phi):
            ph = 2 * math.pi * j / n_phi
            pos.append(center + radius * np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)]))
    for i in range(n_theta):
        for j in range(n_phi):
            a, b = i * n_phi + j, i * n_phi + (j + 1) % n_phi
            c, d = a + n_phi, b + n_phi
            # outward: counter-clockwise seen from outside
            tris += [[a, c, b], [b, c, d]]
    return np.array(pos), np.array(tris)


def convert(scene_path):
    """Meshes (world positions, triangles, material name), materials
    (LuxCore properties), camera and film of a Mitsuba scene."""
    root = load_xml(os.path.abspath(scene_path))
    base = root.get("_base")
    bsdfs, emitters = {}, {}
    for el in root:
        if el.tag == "bsdf" and el.get("id"):
            bsdfs[el.get("id")] = el
        if el.tag == "emitter" and el.get("id"):
            emitters[el.get("id")] = el

    def material(b):
        while b.get("type") == "twosided":
            b = [c for c in b if c.tag == "bsdf"][0]
        t = b.get("type")
        if t == "diffuse":
            return {"type": "matte", "kd": rgb(b, "reflectance", [0.5] * 3)}
        if t == "roughplastic":
            eta = float(value(b, "int_ior", 1.49)) / float(value(b, "ext_ior", 1.000277))
            f0 = ((eta - 1) / (eta + 1)) ** 2
            alpha = float(value(b, "alpha", 0.1))
            return {"type": "glossy2", "kd": rgb(b, "diffuse_reflectance", [0.5] * 3), "ks": [f0] * 3,
                    "uroughness": alpha, "vroughness": alpha, "multibounce": False}
        sys.exit(f"unsupported bsdf {t}")

    meshes, mats = [], {}
    for k, el in enumerate(e for e in root if e.tag == "shape"):
        t = el.get("type")
        m = transform(child(el, "transform", "to_world"))
        if t == "obj":
            pos, tris = read_obj(os.path.join(base, value(el, "filename")))
        elif t == "cube":
            pos, tris = cube()
        elif t == "rectangle":
            pos, tris = rectangle()
        elif t == "sphere":
            c = child(el, "point", "center")
            pos, tris = sphere(vec(c) if c is not None else np.zeros(3), float(value(el, "radius", 1.0)))
        else:
            sys.exit(f"unsupported shape {t}")
        pos = (np.c_[pos, np.ones(len(pos))] @ m.T)[:, :3]
        if np.linalg.det(m[:3, :3]) < 0:
            tris = tris[:, ::-1]
        b = None
        em = None
        for c in el:
            if c.tag == "ref":
                if c.get("id") in bsdfs:
                    b = bsdfs[c.get("id")]
                elif c.get("id") in emitters:
                    em = emitters[c.get("id")]
            elif c.tag == "bsdf":
                b = c
            elif c.tag == "emitter":
                em = c
        mat = material(b) if b is not None else {"type": "matte", "kd": [0.5] * 3}
        if em is not None:
            mat = {"type": "matte", "kd": mat.get("kd", [0.0] * 3), "emission": rgb(em, "radiance")}
        name = f"m{k}"
        mats[name] = mat
        meshes.append((f"s{k}", np.ascontiguousarray(pos, dtype=np.float32),
                       np.ascontiguousarray(tris, dtype=np.uint32), name))

    sensor = [e for e in root if e.tag == "sensor"][0]
    film = [c for c in sensor if c.tag == "film"][0]
    w, h = int(value(film, "width")), int(value(film, "height"))
    cam = transform(child(sensor, "transform", "to_world"))
    fov = float(value(sensor, "fov"))
    axis = value(sensor, "fov_axis", "x")
    if axis == "smaller":
        axis = "x" if w <= h else "y"
    elif axis == "larger":
        axis = "x" if w >= h else "y"
    # The fov about the longer axis, which LuxCore's fieldofview spans
    t = math.tan(math.radians(fov) / 2)
    if axis == "x" and w < h:
        t *= h / w
    elif axis == "y" and h < w:
        t *= w / h
    fov_long = math.degrees(2 * math.atan(t))
    camera = {"orig": cam[:3, 3], "target": cam[:3, 3] + cam[:3, 2], "up": cam[:3, 1], "fov": fov_long}
    return meshes, mats, camera, (w, h)


# --- LuxCore ---------------------------------------------------------------

ENGINES = {
    "path": ("PATHCPU", "SOBOL", False),
    "bidir": ("BIDIRCPU", "RANDOM", False),
    "light": ("LIGHTCPU", "RANDOM", False),
    "photongi": ("PATHCPU", "SOBOL", True),
}


def lux_render(scene_path, engine, seconds, seed, threads, out):
    """Renders for `seconds` of wall time with a LuxCore engine; writes a PFM
    and returns (wall seconds, passes)."""
    import pyluxcore

    meshes, mats, camera, (w, h) = convert(scene_path)
    props = pyluxcore.Properties()
    scene = pyluxcore.Scene()
    for name, m in mats.items():
        p = f"scene.materials.{name}"
        for k, v in m.items():
            if k == "emission":
                props.Set(pyluxcore.Property(f"{p}.emission", [float(x) for x in v]))
                props.Set(pyluxcore.Property(f"{p}.emission.gain", [1.0, 1.0, 1.0]))
                props.Set(pyluxcore.Property(f"{p}.emission.power", 0.0))
                props.Set(pyluxcore.Property(f"{p}.emission.efficency", 0.0))
                props.Set(pyluxcore.Property(f"{p}.emission.normalizebycolor", False))
            elif isinstance(v, list):
                props.Set(pyluxcore.Property(f"{p}.{k}", [float(x) for x in v]))
            else:
                props.Set(pyluxcore.Property(f"{p}.{k}", v))
    for name, pos, tris, mat in meshes:
        scene.DefineMeshExt(name, pos, tris, None, None, None, None, None)
        props.Set(pyluxcore.Property(f"scene.objects.{name}.shape", name))
        props.Set(pyluxcore.Property(f"scene.objects.{name}.material", mat))
    props.Set(pyluxcore.Property("scene.camera.type", "perspective"))
    props.Set(pyluxcore.Property("scene.camera.lookat.orig", [float(x) for x in camera["orig"]]))
    props.Set(pyluxcore.Property("scene.camera.lookat.target", [float(x) for x in camera["target"]]))
    props.Set(pyluxcore.Property("scene.camera.up", [float(x) for x in camera["up"]]))
    props.Set(pyluxcore.Property("scene.camera.fieldofview", camera["fov"]))
    # The screen window spans [−1, 1] along the longer axis, moved down one
    # pixel, which moves the image up one row
    a = max(w, h)
    sx, sy = w / a, h / a
    px = 2.0 / a
    props.Set(pyluxcore.Property("scene.camera.screenwindow", [-sx, sx, -sy - px, sy - px]))
    scene.Parse(props)

    kind, sampler, pgi = ENGINES[engine]
    cfg = [
        ("renderengine.type", kind),
        ("sampler.type", sampler),
        ("renderengine.seed", seed),
        ("native.threads.count", threads),
        ("film.width", w),
        ("film.height", h),
        ("film.filter.type", "NONE"),
        ("film.imagepipelines.0.0.type", "TONEMAP_LINEAR"),
        ("film.imagepipelines.0.0.scale", 1.0),
        ("film.outputs.0.type", "RGB_IMAGEPIPELINE"),
        ("film.outputs.0.filename", "unused.exr"),
        ("path.pathdepth.total", MAX_DEPTH),
        ("path.pathdepth.diffuse", MAX_DEPTH),
        ("path.pathdepth.glossy", MAX_DEPTH),
        ("path.pathdepth.specular", MAX_DEPTH),
        ("path.russianroulette.depth", RR_DEPTH),
        ("path.clamping.variance.maxvalue", 0.0),
        ("light.maxdepth", MAX_DEPTH),
        ("path.maxdepth", MAX_DEPTH),
        ("light.russianroulette.depth", RR_DEPTH),
        ("batch.halttime", seconds),
    ]
    if pgi:
        cfg += [
            ("path.photongi.sampler.type", "METROPOLIS"),
            ("path.photongi.photon.maxdepth", PHOTON_DEPTH),
            ("path.photongi.indirect.maxsize", PHOTON_COUNT),
            ("path.photongi.indirect.enabled", True),
            ("path.photongi.caustic.enabled", False),
        ]
    c = pyluxcore.Properties()
    for k, v in cfg:
        c.Set(pyluxcore.Property(k, v))
    config = pyluxcore.RenderConfig(c, scene)
    session = pyluxcore.RenderSession(config)
    t = time.perf_counter()
    session.Start()
    while not session.HasDone():
        time.sleep(0.05)
        session.UpdateStats()
    session.Stop()
    dt = time.perf_counter() - t
    passes = session.GetStats().Get("stats.renderengine.pass").GetInt()
    buf = np.zeros(w * h * 3, dtype=np.float32)
    session.GetFilm().GetOutputFloat(pyluxcore.FilmOutputType.RGB_IMAGEPIPELINE, buf)
    # LuxCore's rows run bottom to top, as a PFM's do
    write_pfm(out, w, h, buf)
    return dt, passes


def write_pfm(path, w, h, data):
    with open(path, "wb") as f:
        f.write(f"PF\n{w} {h}\n-1.0\n".encode())
        f.write(np.asarray(data, dtype="<f4").tobytes())


# --- kalos and measuring ---------------------------------------------------


def kalos_render(kalos, scene, method, seconds, seed, out):
    args = method.split()
    r = subprocess.run([kalos, "render", scene, "--method", *args, "--time", str(seconds), "--seed", str(seed),
                        "-o", out, "-q"], check=True, capture_output=True, text=True)
    # "..., 20.01 s (+0.01 s load/build), 61.2 M rays, ..."
    t = float(re.search(r"passes, (\S+) s", r.stdout).group(1))
    rays = re.search(r"(\S+ M) rays", r.stdout)
    return t, rays.group(1) + " rays" if rays else ""


def compare(kalos, img, ref):
    """relMSE, the image's channel means and the reference's."""
    out = subprocess.run([kalos, "compare", img, ref], check=True, capture_output=True, text=True).stdout
    e = float(re.search(r"relMSE\s+(\S+)", out).group(1))
    m = re.search(r"image \(([^)]*)\)\s+reference \(([^)]*)\)", out)
    means = [tuple(x.strip() for x in g.split(",")) for g in m.groups()] if m else []
    return e, out, means


def loadavg():
    return "load average %.2f %.2f %.2f" % os.getloadavg()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--ref", required=True)
    ap.add_argument("--time", type=float, default=20.0)
    ap.add_argument("--kalos-methods", default="path,light,plb")
    ap.add_argument("--engines", default="path,bidir,light,photongi")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--kalos", default=KALOS)
    ap.add_argument("--ref-noise", type=float, default=0.0, help="the reference's own relMSE, subtracted")
    ap.add_argument("--out", default=os.path.join(ROOT, "target", "bench-out", "luxcore"))
    ap.add_argument("--one", nargs=4, metavar=("ENGINE", "SECONDS", "SEED", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        # One LuxCore render in this process (pyluxcore crashes at exit, and
        # a fresh process per render keeps the renders independent)
        import pyluxcore

        pyluxcore.Init(print if os.environ.get("LUX_LOG") else (lambda msg: None))
        e, s, seed, out = args.one
        dt, passes = lux_render(args.scene, e, float(s), int(seed), args.threads, out)
        print(f"TIME {dt} PASSES {passes}", flush=True)
        os._exit(0)

    kalos = os.path.abspath(args.kalos)
    if not os.path.exists(kalos):
        subprocess.run(["cargo", "build", "--release"], cwd=ROOT, check=True)
    os.makedirs(args.out, exist_ok=True)
    runners = [(f"kalos {m}", "kalos", m) for m in args.kalos_methods.split(",") if m]
    runners += [(f"LuxCore {ENGINES[e][0]}{' + PhotonGI' if ENGINES[e][2] else ''}", "lux", e)
                for e in args.engines.split(",") if e]
    print(f"scene {args.scene}, reference {args.ref} (own relMSE {args.ref_noise:.2e} subtracted), "
          f"{args.time:g} s each, {args.threads} threads, {loadavg()}", flush=True)
    results = {label: [] for label, _, _ in runners}
    ref_means = None
    for k in range(args.repeats):
        for label, kind, what in runners:
            out = os.path.join(args.out, f"{label.replace(' ', '_').replace('+', '')}_{k}.pfm")
            if kind == "kalos":
                t, note = kalos_render(kalos, args.scene, what, args.time, k + 1, out)
            else:
                r = subprocess.run([sys.executable, os.path.abspath(__file__), args.scene, "--ref", args.ref,
                                    "--threads", str(args.threads), "--one", what, str(args.time), str(k + 1), out],
                                   capture_output=True, text=True)
                m = re.search(r"TIME (\S+) PASSES (\S+)", r.stdout)
                if not m:
                    print(f"  {label} did not run: {(r.stderr or r.stdout).strip()[-500:]}", flush=True)
                    continue
                t, note = float(m.group(1)), f"{m.group(2)} passes"
            e, text, means = compare(kalos, out, args.ref)
            e = max(e - args.ref_noise, 1e-12)
            if len(means) >= 2:
                ref_means = means[1]
            mean = means[0] if means else ("?", "?", "?")
            results[label].append((t, e, mean))
            print(f"  {label:28s} seed {k + 1}: {t:6.2f} s, relMSE {e:.3e}, mean ({', '.join(mean)}), {note}",
                  flush=True)
    best = min((statistics.median(x[1] for x in r) for lab, r in results.items() if r and lab.startswith("kalos")),
               default=None)
    print(f"\n| renderer | relMSE | ÷ best kalos | image mean (R, G, B) |")
    print("| --- | --- | --- | --- |")
    for label, r in results.items():
        if not r:
            continue
        e = statistics.median(x[1] for x in r)
        print(f"| {label} | {e:.2e} | {e / best:.2f} | {', '.join(r[-1][2])} |")
    if ref_means:
        print(f"| reference | – | – | {', '.join(ref_means)} |")
    print(loadavg(), flush=True)


if __name__ == "__main__":
    main()
