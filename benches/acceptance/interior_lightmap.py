#!/usr/bin/env python3
"""Acceptance figures of the lightmap bake on the textured interior (issue #34):
`kalos bake scenes/interior/interior.glb --lightmap --time 120`, shown by
`kalos view` in Chromium from the scene camera, against a converged kalos
render of the same view. A benchmark, not a CI test.

Needs: a release build of kalos; Python 3 with numpy and playwright
(`pip install numpy playwright`; never `playwright install`: the browser is
Debian's Chromium, /usr/bin/chromium or --chromium), run with software WebGL
(SwiftShader). Run from the repository root:

    python3 benches/acceptance/interior_lightmap.py --work DIR \\
        [--kalos target/release/kalos] [--ref-time 2700] [--reuse]

DIR keeps every image, the bake and a log; with --reuse a step whose output
is already in DIR is not run again (the converged renders take the longest:
two path renders of --ref-time seconds each, one thread each, side by side;
each keeps its checkpoint, ref-SEED.kpart, so that with --reuse, its .pfm
removed and a longer --ref-time, it is continued, not restarted). The bake
runs alone, on --threads (2). --display-mesh measures the paper's display
mesh (kalos bake without --lightmap) instead.

What it measures, each against the converged render of seed A (`ref-A`):

- the painting's fine detail: the Pearson correlation, inside the
  painting's screen rectangle (its canvas's corners projected through the
  glTF camera, less a margin), of the high-passed luminance: luminance
  minus its Gaussian blur of --sigma (2) pixels;
- the wall's lighting shape: the mean luminance of two regions of room B's
  south wall (the painting's), `P`, above the painting, where the sky's
  light lands directly through the door gap, and `S`, the wall's east end,
  which only bounced light reaches (the rectangles are below, in glTF world
  coordinates); each region's mean and the ratio P/S, as % differences.

And two figures the issue does not name, as "before" figures for the
estimator and seam work: the mean of `D`, the door leaf's face toward the
camera, which only room B's light reaches (light from the lightmap beyond
that leaks through the 4 cm leaf), and the RMS relative difference of the
means of 8 × 8-pixel blocks over the whole image (blotches, seams and leaks
anywhere; blocks darker than 0.01 in the reference left out).

Controls, measured the same way against ref-A: the converged render of
seed B (how far "converged" is from itself) and a render of --short-time (60)
seconds with the same method.

Every image is taken to what the screen shows the same way: the viewer's
screenshot is 8-bit sRGB of 2^0 × radiance, clamped (`kalos view` at
exposure 0); a render is tone-mapped as `kalos render -o X.png --tonemap
clamp` writes it (clamp to [0, 1], the sRGB curve, rounding to 8 bits), as
tests/browser/test_view.py compares them. Luminance is then Rec. 709's, of
the linear values decoded from those 8 bits.
"""

import argparse
import json
import math
import os
import re
import resource
import struct
import subprocess
import sys
import time
import zlib

import numpy as np

CHROMIUM_ARGS = ["--no-sandbox", "--headless", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]

# Two regions of room B's south wall, the painting's (its inner face is
# glTF's z = 0; glTF world: x, y up, z = -(the plan's y), in metres), as
# (x range, height range). The sky's light comes in through the door gap
# onto this wall from the plan's x = 4.6 to 7.0, the painting and the wall
# above it; the rest of the wall takes bounced light only (about 7 times
# less).
REGIONS = {
    # above the painting, in the light that comes through the gap
    "P": dict(x=(5.25, 6.75), y=(2.28, 2.6)),
    # the wall's east end, beyond that light: bounced light only
    "S": dict(x=(7.45, 8.05), y=(0.6, 2.4)),
}


def door_quad():
    """The door leaf's face toward room B's camera, as four glTF world
    points: the leaf is 4 cm thick, hinged at the plan's (4.15, 3.09) and
    turned 30° into room B; this is its face at 4 cm from the hinge's
    plane, from 15 to 70 cm from the hinge (the knob is at 78-82 cm) and
    0.3-1.8 m high. Light reaches it only from room B: what the lightmap
    gives it beyond that leaks through the leaf."""
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))

    def world(yl, height):
        x, y = 0.04 * c - yl * s + 4.15, 0.04 * s + yl * c + 3.09
        return (x, height, -y)
    return [world(-0.15, 0.3), world(-0.7, 0.3), world(-0.7, 1.8), world(-0.15, 1.8)]


BLOCK = 8  # pixels per side of the blocks whose means the whole-image figure compares
MARGIN = 4  # pixels left out at the painting rectangle's edges


# --- running ---------------------------------------------------------------

def log(msg, logf=None):
    print(msg, flush=True)
    if logf:
        with open(logf, "a") as f:
            f.write(msg + "\n")


def run_step(name, args, logf):
    """Runs kalos; returns wall time, the children's CPU time and the
    load averages before and after."""
    load0 = os.getloadavg()
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.time()
    log(f"$ {' '.join(args)}", logf)
    r = subprocess.run(args, capture_output=True, text=True)
    wall = time.time() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    out = (r.stdout + r.stderr).strip()
    log(out, logf)
    if r.returncode != 0:
        sys.exit(f"{name} failed ({r.returncode})")
    load1 = os.getloadavg()
    log(f"  {name}: {wall:.1f} s wall, {cpu:.1f} s CPU, load average "
        f"{load0[0]:.2f} before, {load1[0]:.2f} after", logf)
    return dict(wall=wall, cpu=cpu, load=(load0, load1), out=out)


def render_refs(a, scene, res, logf):
    """The two converged renders, side by side, one thread each."""
    procs, t0, load0 = [], time.time(), os.getloadavg()
    for s in a.seeds:
        out = os.path.join(a.work, f"ref-{s}.pfm")
        if a.reuse and os.path.exists(out):
            continue
        kp = os.path.join(a.work, f"ref-{s}.kpart")
        args = [a.kalos, "render", scene, "--method", a.ref_method, "--res", res,
                "--seed", str(s), "--time", str(a.ref_time), "--threads", "1", "-q",
                "--checkpoint", kp, "--checkpoint-every", "300", "-o", out]
        if a.reuse and os.path.exists(kp):
            args += ["--resume", kp]
        log(f"$ {' '.join(args)} &", logf)
        procs.append((s, subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                          text=True)))
    for s, p in procs:
        out = p.communicate()[0].strip()
        log(out, logf)
        if p.returncode != 0:
            sys.exit(f"converged render {s} failed")
    if procs:
        log(f"  converged renders: {time.time() - t0:.0f} s wall, load average "
            f"{load0[0]:.2f} before, {os.getloadavg()[0]:.2f} after", logf)


def screenshot(a, glb, w, h, out, logf):
    """`kalos view GLB` in Chromium from the scene camera, panel hidden,
    exposure 0."""
    from playwright.sync_api import sync_playwright
    p = subprocess.Popen([a.kalos, "view", glb], stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True)
    url = None
    for line in p.stdout:
        m = re.search(r"http://127\.0\.0\.1:\d+/", line)
        if m:
            url = m.group(0)
            break
    if url is None:
        sys.exit("kalos view printed no address")
    try:
        with sync_playwright() as pw:
            b = pw.chromium.launch(executable_path=a.chromium, args=CHROMIUM_ARGS)
            pg = b.new_page(viewport={"width": w, "height": h}, device_scale_factor=1)
            pg.goto(url)
            pg.wait_for_function("window.kalos && (window.kalos.ready || window.kalos.error)",
                                 timeout=120000)
            err = pg.evaluate("window.kalos.error")
            if err:
                sys.exit(f"viewer error: {err}")
            if a.lightmap and not pg.evaluate("window.kalos.lightmapped"):
                sys.exit("the viewer found no MOZ_lightmap")
            if not pg.evaluate("window.kalos.sceneCamera"):
                sys.exit("the .glb has no scene camera")
            pg.evaluate("window.kalos.setExposure(0)")
            pg.evaluate("document.getElementById('panel').style.display = 'none'")
            with open(out, "wb") as f:
                f.write(pg.screenshot())
            b.close()
    finally:
        p.terminate()
        p.wait()
    log(f"  screenshot: {out}", logf)


# --- images ----------------------------------------------------------------

def read_png(path):
    """8-bit RGB(A) non-interlaced PNG -> float array (h, w, 3) of 0..255."""
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path}: not a PNG"
    pos, idat = 8, b""
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert depth == 8 and ctype in (2, 6) and interlace == 0, f"{path}: unsupported PNG"
            bpp = 3 if ctype == 2 else 4
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, w * bpp + 1)
    out = np.zeros((h, w * bpp), dtype=np.int32)
    prev = np.zeros(w * bpp, dtype=np.int32)
    for y in range(h):
        f, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        if f == 0:
            cur = line
        elif f == 1:
            cur = line.copy()
            for i in range(bpp, w * bpp):
                cur[i] = (cur[i] + cur[i - bpp]) & 255
        elif f == 2:
            cur = (line + prev) & 255
        else:
            cur = line.copy()
            for i in range(w * bpp):
                a = cur[i - bpp] if i >= bpp else 0
                b = prev[i]
                if f == 3:
                    cur[i] = (cur[i] + (a + b) // 2) & 255
                else:
                    c = prev[i - bpp] if i >= bpp else 0
                    p = a + b - c
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                    pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                    cur[i] = (cur[i] + pred) & 255
        out[y] = cur
        prev = cur
    return out.reshape(h, w, bpp)[..., :3].astype(np.float64)


def write_png(path, rgb):
    """An 8-bit RGB PNG of an (h, w, 3) array of 0..255."""
    h, w, _ = rgb.shape
    rows = np.concatenate([np.zeros((h, 1), np.uint8),
                           np.clip(rgb, 0, 255).astype(np.uint8).reshape(h, w * 3)], axis=1)

    def chunk(kind, body):
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(rows.tobytes())) + chunk(b"IEND", b""))


def read_pfm(path):
    """Colour PFM -> float array (h, w, 3), top row first."""
    data = open(path, "rb").read()
    parts = data.split(b"\n", 3)
    assert parts[0].strip() == b"PF", f"{path}: not a colour PFM"
    w, h = map(int, parts[1].split())
    dt = "<f4" if float(parts[2]) < 0 else ">f4"
    px = np.frombuffer(parts[3][:w * h * 12], dtype=dt).reshape(h, w, 3)
    return px[::-1].astype(np.float64)


def srgb8(linear):
    """What `kalos render -o X.png` writes at exposure 0, --tonemap clamp:
    a non-finite pixel black, clamp, the sRGB curve, rounding."""
    v = np.where(np.isfinite(linear).all(axis=2, keepdims=True), linear, 0.0)
    v = np.clip(v, 0.0, 1.0)
    s = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    return np.round(s * 255.0)


def luminance(s8):
    """Rec. 709 luminance of the linear values an 8-bit sRGB image encodes."""
    c = s8 / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return lin @ np.array([0.2126, 0.7152, 0.0722])


def gaussian_blur(img, sigma):
    r = int(math.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    p = np.pad(img, r, mode="reflect")
    p = np.apply_along_axis(lambda v: np.convolve(v, k, mode="valid"), 0, p)
    return np.apply_along_axis(lambda v: np.convolve(v, k, mode="valid"), 1, p)


# --- the camera and the regions ------------------------------------------------

def glb_json(path):
    data = open(path, "rb").read()
    n = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20:20 + n]), data[20 + n + 8:]


def trs(node):
    m = np.eye(4)
    if "matrix" in node:
        return np.array(node["matrix"], dtype=float).reshape(4, 4).T
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m[:3, :3] = r * np.array(node.get("scale", [1, 1, 1]))
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def world_matrices(j):
    """Each node's world matrix (the default scene's tree)."""
    out = {}
    stack = [(n, np.eye(4)) for n in j["scenes"][j.get("scene", 0)]["nodes"]]
    while stack:
        i, parent = stack.pop()
        m = parent @ trs(j["nodes"][i])
        out[i] = m
        stack += [(c, m) for c in j["nodes"][i].get("children", [])]
    return out


class Camera:
    """The glTF file's first perspective camera, projecting world points to
    pixels of a w × h image (the render's, and the viewer's viewport)."""

    def __init__(self, j, w, h):
        worlds = world_matrices(j)
        for i, node in enumerate(j["nodes"]):
            if "camera" in node and j["cameras"][node["camera"]]["type"] == "perspective":
                self.view = np.linalg.inv(worlds[i])
                self.t = math.tan(j["cameras"][node["camera"]]["perspective"]["yfov"] / 2)
                break
        else:
            sys.exit("the scene has no perspective camera")
        self.w, self.h = w, h

    def project(self, p):
        q = self.view @ np.array([*p, 1.0])
        x = q[0] / -q[2] / (self.t * self.w / self.h)
        y = q[1] / -q[2] / self.t
        return (x + 1) / 2 * self.w, (1 - y) / 2 * self.h


def painting_rect(j, bin_chunk, cam):
    """The painting's canvas (the primitive whose material is `painting`):
    its front face's corners projected, as a pixel rectangle less MARGIN."""
    worlds = world_matrices(j)
    for i, node in enumerate(j["nodes"]):
        if "mesh" not in node:
            continue
        for prim in j["meshes"][node["mesh"]]["primitives"]:
            mat = j["materials"][prim["material"]] if "material" in prim else {}
            if mat.get("name") == "painting":
                acc = j["accessors"][prim["attributes"]["POSITION"]]
                lo, hi = acc["min"], acc["max"]
                # the canvas is a thin box facing +z (glTF): its front face
                corners = [(x, y, hi[2]) for x in (lo[0], hi[0]) for y in (lo[1], hi[1])]
                px = [cam.project((worlds[i] @ np.array([*c, 1.0]))[:3]) for c in corners]
                xs, ys = [p[0] for p in px], [p[1] for p in px]
                return (int(math.ceil(min(xs))) + MARGIN, int(math.floor(max(xs))) - MARGIN,
                        int(math.ceil(min(ys))) + MARGIN, int(math.floor(max(ys))) - MARGIN)
    sys.exit("the scene has no material named `painting`")


def wall_quad(region):
    """A rectangle on room B's south wall (glTF z = 0) as four world points."""
    (x0, x1), (y0, y1) = region["x"], region["y"]
    return [(x0, y0, 0.0), (x1, y0, 0.0), (x1, y1, 0.0), (x0, y1, 0.0)]


def quad_mask(cam, quad, w, h):
    """Pixels inside the projection of a planar quad of world points."""
    pts = [cam.project(p) for p in quad]
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    cross = [(x1 - x0) * (yy - y0) - (y1 - y0) * (xx - x0)
             for (x0, y0), (x1, y1) in zip(pts, pts[1:] + pts[:1])]
    # inside: on the same side of every edge, whichever the winding
    inside = np.all([c >= 0 for c in cross], axis=0) | np.all([c <= 0 for c in cross], axis=0)
    return inside


# --- the figures -------------------------------------------------------------

def block_means(lum):
    h, w = lum.shape
    h, w = h - h % BLOCK, w - w % BLOCK
    return lum[:h, :w].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK).mean(axis=(1, 3))


def figures(lum, ref, rect, masks, sigma):
    """Painting detail r; each region's mean, % off the reference; the
    ratio P/S, % off; the RMS relative difference of BLOCK² block means
    over the image (blocks the reference shows brighter than 0.01)."""
    x0, x1, y0, y1 = rect
    hp = lum - gaussian_blur(lum, sigma)
    hr = ref - gaussian_blur(ref, sigma)
    a, b = hp[y0:y1, x0:x1].ravel(), hr[y0:y1, x0:x1].ravel()
    r = float(np.corrcoef(a, b)[0, 1])
    m = {k: float(lum[v].mean()) for k, v in masks.items()}
    mr = {k: float(ref[v].mean()) for k, v in masks.items()}
    d = {k: 100 * (m[k] / mr[k] - 1) for k in masks}
    ratio = 100 * ((m["P"] / m["S"]) / (mr["P"] / mr["S"]) - 1)
    bl, br = block_means(lum), block_means(ref)
    keep = br > 0.01
    rms = 100 * float(np.sqrt(np.mean(((bl[keep] - br[keep]) / br[keep]) ** 2)))
    return r, d, ratio, rms

def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kalos", default="target/release/kalos")
    ap.add_argument("--scene", default="scenes/interior/interior.glb")
    ap.add_argument("--work", required=True, help="folder for the images, the bake and the log")
    ap.add_argument("--res", default="480x320", help="the render's and the viewport's size")
    ap.add_argument("--bake-time", type=float, default=120)
    ap.add_argument("--bake-args", default="", help="more arguments for kalos bake")
    ap.add_argument("--display-mesh", dest="lightmap", action="store_false",
                    help="measure the paper's display mesh (kalos bake without --lightmap) "
                         "instead of the lightmap")
    ap.add_argument("--threads", default="2", help="threads of the bake and the short render")
    ap.add_argument("--ref-method", default="path")
    ap.add_argument("--ref-time", type=float, default=2700, help="seconds per converged render")
    ap.add_argument("--short-time", type=float, default=60)
    ap.add_argument("--seeds", default="101,102,103",
                    help="converged renders A and B, and the short render")
    ap.add_argument("--sigma", type=float, default=2.0, help="the high-pass's Gaussian, pixels")
    ap.add_argument("--chromium", default=os.environ.get("CHROMIUM", "/usr/bin/chromium"))
    ap.add_argument("--reuse", action="store_true", help="skip steps whose output exists")
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(",")]
    a.seeds, short_seed = seeds[:2], seeds[2]
    a.kalos = os.path.abspath(a.kalos)
    os.makedirs(a.work, exist_ok=True)
    logf = os.path.join(a.work, "log.txt")
    w, h = map(int, a.res.split("x"))
    scene = os.path.abspath(a.scene)
    log(f"# {time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}", logf)
    log(subprocess.run([a.kalos, "--version"], capture_output=True, text=True).stdout.strip(), logf)

    # 1. the converged renders, side by side
    render_refs(a, scene, a.res, logf)
    # 2. the short render
    short = os.path.join(a.work, f"short-{short_seed}.pfm")
    if not (a.reuse and os.path.exists(short)):
        run_step("short render", [a.kalos, "render", scene, "--method", a.ref_method, "--res",
                                  a.res, "--seed", str(short_seed), "--time", str(a.short_time),
                                  "--threads", a.threads, "-q", "-o", short], logf)
    # 3. the bake, alone
    kind = "lightmap" if a.lightmap else "display-mesh"
    glb = os.path.join(a.work, f"bake-{kind}.glb")
    if not (a.reuse and os.path.exists(glb)):
        run_step("bake", [a.kalos, "bake", scene] + (["--lightmap"] if a.lightmap else [])
                 + ["--time", str(a.bake_time), "--threads", a.threads, "--stats", "-o", glb]
                 + a.bake_args.split(), logf)
    shot = os.path.join(a.work, f"view-{kind}.png")
    if not (a.reuse and os.path.exists(shot)):
        screenshot(a, glb, w, h, shot, logf)

    # the figures
    j, bin_chunk = glb_json(scene)
    cam = Camera(j, w, h)
    rect = painting_rect(j, bin_chunk, cam)
    masks = {k: quad_mask(cam, wall_quad(r), w, h) for k, r in REGIONS.items()}
    masks["D"] = quad_mask(cam, door_quad(), w, h)
    lin = {s: read_pfm(os.path.join(a.work, f"ref-{s}.pfm")) for s in a.seeds}
    ref = luminance(srgb8(lin[a.seeds[0]]))
    view = luminance(read_png(shot))
    short_lum = luminance(srgb8(read_pfm(short)))
    images = [
        (f"viewer, bake{' --lightmap' if a.lightmap else ''} --time {a.bake_time:g}"
         + (f" {a.bake_args}" if a.bake_args else ""), view),
        (f"converged, seed {a.seeds[1]}", luminance(srgb8(lin[a.seeds[1]]))),
        (f"{a.ref_method} {a.short_time:g} s, seed {short_seed}", short_lum),
    ]
    x0, x1, y0, y1 = rect
    log(f"painting rectangle: x {x0}..{x1}, y {y0}..{y1} ({x1 - x0} × {y1 - y0} px); "
        f"wall regions: P {int(masks['P'].sum())} px, S {int(masks['S'].sum())} px; "
        f"high-pass: luminance minus its Gaussian blur, sigma {a.sigma:g} px", logf)
    log(f"door region D {int(masks['D'].sum())} px; converged (seed {a.seeds[0]}): mean "
        f"luminance P {ref[masks['P']].mean():.4f}, S {ref[masks['S']].mean():.4f}, "
        f"D {ref[masks['D']].mean():.4f}", logf)

    def table(title, ref, rows):
        log("", logf)
        log(f"| against {title} | painting detail r | wall P | wall S | ratio P/S "
            f"| door D | {BLOCK}×{BLOCK} blocks, RMS |", logf)
        log("|---|---|---|---|---|---|---|", logf)
        for name, lum in rows:
            r, d, ratio, rms = figures(lum, ref, rect, masks, a.sigma)
            log(f"| {name} | {r:.3f} | {d['P']:+.1f} % | {d['S']:+.1f} % | {ratio:+.1f} % "
                f"| {d['D']:+.1f} % | {rms:.1f} % |", logf)

    table(f"converged seed {a.seeds[0]}", ref, images)
    # the two converged renders averaged: a reference with half the variance
    both = luminance(srgb8(sum(lin.values()) / len(lin)))
    table(f"converged seeds {a.seeds[0]} and {a.seeds[1]} averaged", both,
          [images[0], images[2]])
    # where the rectangles fall, drawn on the viewer's screenshot
    img = read_png(shot)
    img[masks["P"]] = 0.5 * img[masks["P"]] + [127, 0, 0]
    img[masks["S"]] = 0.5 * img[masks["S"]] + [0, 0, 127]
    img[masks["D"]] = 0.5 * img[masks["D"]] + [127, 0, 127]
    img[y0:y1, [x0, x1 - 1]] = img[[y0, y1 - 1], x0:x1] = [0, 255, 0]
    write_png(os.path.join(a.work, f"regions-{kind}.png"), img)
    log(f"regions drawn on the screenshot: {os.path.join(a.work, f'regions-{kind}.png')}", logf)


if __name__ == "__main__":
    main()
