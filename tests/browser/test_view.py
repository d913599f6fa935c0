#!/usr/bin/env python3
"""The viewer in a real browser: `kalos view`, `kalos render --view` and
`kalos bake --lightmap --view`, driven by Playwright in Debian's Chromium
with software WebGL (SwiftShader).

Run from the repository root, after `cargo build --release`:

    python3 tests/browser/test_view.py [--kalos target/release/kalos] [--keep DIR]
    python3 tests/browser/test_view.py --lightmap DIR [--kalos ...] [--keep DIR]
    python3 tests/browser/test_view.py --live-lightmap [--kalos ...] [--keep DIR]

It needs `pip install playwright` (never `playwright install`: the browser
is /usr/bin/chromium, or $CHROMIUM). It prints one line per check and exits
non-zero on the first failure. `--keep DIR` leaves the screenshots and
images there; otherwise everything lives in a temporary folder that is
removed.

`--lightmap DIR` runs only the lightmap checks, on the textured cube and
its lightmapped .glb that `KALOS_LIGHTMAP_GLB_DIR=DIR cargo test --release
--test it lightmap_glb` leaves in DIR (`cube.gltf`, `cube.glb`).
`--live-lightmap` runs only the check of a lightmap bake shown live (which
the default run includes).
"""

import argparse
import os
import json
import re
import signal
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request
import zlib

from playwright.sync_api import sync_playwright

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--headless",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]

# The bake and its render: small enough for CI, the same settings for both
# so that the render's view pass reads the same display mesh the .glb holds.
PARTICLES = "200000"
SEED = "1"

# Largest difference of a channel mean (0..255 sRGB) between the viewer's
# screenshot and kalos's own render of the same bake from the same camera.
# Measured over seeds 1..5 (docs/notebook/viewer-python.md, "Viewer (issue #16)"): the
# difference is systematic (rasterised against ray-traced edges and
# interpolation), at most 0.29 in any channel, and moves by at most 0.02
# between seeds. The tolerance is above that by more than three times, and
# below what a fault does: an exposure off by 0.1 stop moves the red mean by
# 2.5, an orbit of 5 pixels by 4.7 (measured the same way).
MEAN_TOLERANCE = 1.0

# The lightmapped cube (tests/it/lightmap_glb.rs; a glTF dielectric without
# a specular layer, KHR_materials_specular's factor 0, since the viewer has
# no sky for a coat to reflect): kalos renders the .gltf
# (its albedo under a white sky of radiance 1: convex, so every face's
# irradiance is π), the viewer shows the .glb's lightmap of π times the
# same albedo texture. Measured at 256², 16 spp (docs/lightmaps.md):
# - where the texture is flat (3×3 neighbourhoods within 2 levels in
#   kalos's render), the viewer's linear radiance is kalos's × 1.004: the
#   lightmap's scale, π convention and colour spaces agree; a fault moves it
#   far more (a 0.1-stop error: 7 %). Tolerance 2 %.
# - per pixel on the cube, viewer against kalos: 7.7 levels (0..255) on
#   average, against 7.3 between two seeds of kalos itself (the checker's
#   fine detail, sampled differently); tolerance: 1.5 × kalos's own
#   seed-to-seed difference, measured in the run.
# - channel means on the cube differ by 3.0 (texture filtering: mipmaps
#   against supersampling, on a high-contrast checker); tolerance 4.5, below
#   what a 0.1-stop exposure error gives (about 7).
LIGHTMAP_FLAT_RATIO = 0.02

# The live lightmap bake (`kalos bake --lightmap --view`): the built-in
# Cornell box with particles enough for a few previews (about 6 s of
# tracing on 2 cores), on a small atlas.
LIVE_PARTICLES = "2000000"
LIVE_SIZE = 64
# Largest difference of a channel mean (0..255) between the live page's
# final picture and `kalos view` of the .glb the bake wrote. The two show
# the same atlas, over the same scale and clipped the same way, through
# half floats from f32 (live) or from 16-bit PNG (the .glb): measured
# 0.004. The error map's false colour jumps from green to yellow at 5 %,
# so that texels at 5 % flip: measured 0.13. Tolerances 0.1 and 0.5, below
# what showing a stale atlas gives (the first preview against the final:
# 0.38 in the same run).
LIVE_MEAN_TOLERANCE = 0.1
LIVE_ERROR_MAP_TOLERANCE = 0.5
LIGHTMAP_NOISE_FACTOR = 1.5
LIGHTMAP_MEAN_TOLERANCE = 4.5


def png_pixels(data):
    """(width, height, rows of (r, g, b)) of an 8-bit RGB or RGBA,
    non-interlaced PNG, decoded with the standard library."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos, idat, w = 8, b"", None
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert depth == 8 and ctype in (2, 6) and interlace == 0, "unsupported PNG"
            bpp = 3 if ctype == 2 else 4
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    stride = w * bpp
    rows, prev = [], bytearray(stride)
    for y in range(h):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - bpp] if i >= bpp else 0
            b = prev[i]
            c = prev[i - bpp] if i >= bpp else 0
            if f == 1:
                line[i] = (line[i] + a) & 255
            elif f == 2:
                line[i] = (line[i] + b) & 255
            elif f == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[i] = (line[i] + pred) & 255
        rows.append([tuple(line[x * bpp:x * bpp + 3]) for x in range(w)])
        prev = line
    return w, h, rows


def means(rows, x0=0.0, x1=1.0):
    """Channel means over the columns from x0 to x1 (fractions of the width)."""
    w = len(rows[0])
    a, b = int(x0 * w), int(x1 * w)
    n = len(rows) * (b - a)
    return [sum(r[x][c] for r in rows for x in range(a, b)) / n for c in range(3)]


def read_pfm(path):
    """(width, height, pixels top row first) of a colour PFM."""
    with open(path, "rb") as f:
        data = f.read()
    parts = data.split(b"\n", 3)
    assert parts[0].strip() == b"PF", "not a colour PFM"
    w, h = map(int, parts[1].split())
    scale = float(parts[2])
    fmt = "<" if scale < 0 else ">"
    vals = struct.unpack(f"{fmt}{w * h * 3}f", parts[3][:w * h * 12])
    # PFM stores the bottom row first
    rows = [vals[(h - 1 - y) * w * 3:(h - y) * w * 3] for y in range(h)]
    return w, h, rows


def check(ok, what):
    print(("ok    " if ok else "FAIL  ") + what, flush=True)
    if not ok:
        sys.exit(1)


class Served:
    """A kalos process serving the viewer; its URL read from its output."""

    def __init__(self, args, stream):
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        pipe = self.proc.stdout if stream == "stdout" else self.proc.stderr
        self.url = None
        self.lines = []
        for line in pipe:
            self.lines.append(line)
            m = re.search(r"http://127\.0\.0\.1:\d+/", line)
            if m:
                self.url = m.group(0)
                break
        if self.url is None:
            self.proc.wait()
            raise SystemExit(f"no URL from {' '.join(args)}: {''.join(self.lines)}"
                             f"{self.proc.stderr.read() if stream == 'stdout' else ''}")

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait()


def run(args):
    """Runs kalos; its output is shown only when it fails."""
    r = subprocess.run(args, capture_output=True, text=True)
    if r.returncode != 0:
        print(r.stdout + r.stderr)
    check(r.returncode == 0, "kalos " + args[1] + " runs")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--kalos", default="target/release/kalos")
    ap.add_argument("--keep", help="folder to leave the screenshots and images in")
    ap.add_argument("--seed", default=SEED, help="seed of the bake and its render")
    ap.add_argument("--lightmap", help="folder with cube.gltf and cube.glb: lightmap checks only")
    ap.add_argument("--live-lightmap", action="store_true",
                    help="only the check of a lightmap bake shown live")
    a = ap.parse_args()
    kalos = os.path.abspath(a.kalos)
    chromium = os.environ.get("CHROMIUM", "/usr/bin/chromium")
    t_start = time.time()
    with tempfile.TemporaryDirectory(prefix="kalos-browser-") as tmp:
        out = a.keep or tmp
        os.makedirs(out, exist_ok=True)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            try:
                if a.lightmap:
                    lightmap_checks(browser, kalos, out, a.lightmap)
                elif a.live_lightmap:
                    live_lightmap_checks(browser, kalos, out)
                else:
                    mesh_checks(browser, kalos, out, a.seed)
                    image_checks(browser, kalos, out)
                    live_checks(browser, kalos, out)
                    live_lightmap_checks(browser, kalos, out)
            finally:
                browser.close()
    print(f"browser test passed in {time.time() - t_start:.1f} s")


def mesh_checks(browser, kalos, out, seed):
    glb = os.path.join(out, "cbox.glb")
    run([kalos, "bake", "scenes/cbox/cbox.xml", "-o", glb, "--particles", PARTICLES,
         "--seed", seed, "-q"])
    # kalos's own render of the bake: the density method's view pass reads
    # the diffuse surfaces from the same display mesh, from the scene's camera
    ref_png = os.path.join(out, "cbox-kalos.png")
    run([kalos, "render", "scenes/cbox/cbox.xml", "--method", "density", "--particles",
         PARTICLES, "--seed", seed, "--spp", "16", "-q", "-o", ref_png])
    with open(ref_png, "rb") as f:
        w, h, ref = png_pixels(f.read())

    served = Served([kalos, "view", glb], "stdout")
    try:
        page = browser.new_page(viewport={"width": w, "height": h}, device_scale_factor=1)
        page.goto(served.url)
        page.wait_for_function("window.kalos && (window.kalos.ready || window.kalos.error)",
                               timeout=60000)
        check(page.evaluate("window.kalos.error") is None, "the .glb loads in three.js")
        check(page.evaluate("window.kalos.sceneCamera"), "the bake recorded the scene's camera")
        page.evaluate("document.getElementById('panel').style.display = 'none'")
        shot = page.screenshot()
        with open(os.path.join(out, "cbox-view.png"), "wb") as f:
            f.write(shot)
        sw, sh, rows = png_pixels(shot)
        check((sw, sh) == (w, h), f"screenshot is {sw}x{sh}, the render {w}x{h}")
        m_view, m_ref = means(rows), means(ref)
        diff = [abs(p - q) for p, q in zip(m_view, m_ref)]
        print(f"      channel means: viewer {[round(v, 2) for v in m_view]}, "
              f"kalos {[round(v, 2) for v in m_ref]}, difference {[round(d, 2) for d in diff]}")
        check(max(diff) <= MEAN_TOLERANCE,
              f"viewer and kalos render agree in every channel mean within {MEAN_TOLERANCE}")
        # the walls fill these columns from cbox's camera; the light is
        # orange, so the green wall shows green only a little above red
        left, right = means(rows, 0.02, 0.15), means(rows, 0.82, 0.95)
        check(left[0] > 3 * left[1] and left[0] > 3 * left[2],
              f"red wall on the left (means {[round(v) for v in left]})")
        check(right[1] > 1.05 * right[0] and right[1] > 3 * right[2],
              f"green wall on the right (means {[round(v) for v in right]})")
        # exposure −2 stops darkens the picture by about a factor 4 in linear
        page.evaluate("window.kalos.setExposure(-2)")
        dark = means(png_pixels(page.screenshot())[2])
        check(all(d < 0.8 * v for d, v in zip(dark, m_view)), "the exposure slider darkens")
        page.close()
    finally:
        served.stop()


def pixel_difference(a, b, mask=None):
    """Mean absolute difference per pixel and channel (0..255), over the
    pixels `mask` (rows of booleans) keeps, or all."""
    total, n = 0.0, 0
    for y, (ra, rb) in enumerate(zip(a, b)):
        for x, (p, q) in enumerate(zip(ra, rb)):
            if mask is None or mask[y][x]:
                total += sum(abs(p[c] - q[c]) for c in range(3))
                n += 3
    return total / max(n, 1)


def masked_means(rows, mask):
    """Channel means over the pixels `mask` keeps."""
    px = [p for r, m in zip(rows, mask) for p, k in zip(r, m) if k]
    return [sum(p[c] for p in px) / max(len(px), 1) for c in range(3)]


def flat_ratio(view, ref, mask):
    """Viewer over kalos, in linear radiance summed over the cube's pixels
    whose 3×3 neighbourhood in kalos's render is flat (within 2 levels in
    every channel)."""
    lin = [((c / 255) / 12.92 if c / 255 <= 0.04045 else ((c / 255 + 0.055) / 1.055) ** 2.4)
           for c in range(256)]
    sv = sr = 0.0
    for y in range(1, len(ref) - 1):
        for x in range(1, len(ref[0]) - 1):
            if not mask[y][x]:
                continue
            nb = [ref[j][i] for j in (y - 1, y, y + 1) for i in (x - 1, x, x + 1)]
            if all(max(p[c] for p in nb) - min(p[c] for p in nb) <= 2 for c in range(3)):
                sv += sum(lin[c] for c in view[y][x])
                sr += sum(lin[c] for c in ref[y][x])
    return sv / max(sr, 1e-9)


def cube_mask(view, ref):
    """The pixels of the cube: not background (kalos shows the white sky,
    the viewer black), and not next to it (the two antialias the silhouette
    against different backgrounds). A texel the viewer wrongly shows black
    stays in: there kalos shows the texture, not white."""
    h, w = len(view), len(view[0])
    bg = [[max(view[y][x]) <= 1 and min(ref[y][x]) >= 254 for x in range(w)] for y in range(h)]
    return [[not any(bg[j][i] for j in range(max(y - 1, 0), min(y + 2, h))
                     for i in range(max(x - 1, 0), min(x + 2, w)))
             for x in range(w)] for y in range(h)]


def lightmap_checks(browser, kalos, out, src):
    gltf, glb = os.path.join(src, "cube.gltf"), os.path.join(src, "cube.glb")
    size = 256
    refs = []
    for seed in ("1", "2"):
        png = os.path.join(out, f"cube-kalos-{seed}.png")
        # independent numbers: the per-pixel tolerance is measured against
        # their seed-to-seed difference (Sobol's, less than half of it, is
        # below the texture filtering's own difference from the viewer)
        run([kalos, "render", gltf, "--spp", "16", "--res", f"{size}x{size}", "--seed", seed,
             "--sampler", "independent", "-q", "-o", png])
        with open(png, "rb") as f:
            refs.append(png_pixels(f.read())[2])
    noise = pixel_difference(refs[0], refs[1])
    served = Served([kalos, "view", glb], "stdout")
    try:
        page = browser.new_page(viewport={"width": size, "height": size}, device_scale_factor=1)
        page.goto(served.url)
        page.wait_for_function("window.kalos && (window.kalos.ready || window.kalos.error)",
                               timeout=60000)
        check(page.evaluate("window.kalos.error") is None, "the lightmapped .glb loads in three.js")
        check(page.evaluate("window.kalos.lightmapped"), "the viewer found MOZ_lightmap")
        check(page.evaluate("window.kalos.sceneCamera"), "the .glb kept the scene's camera")
        page.evaluate("document.getElementById('panel').style.display = 'none'")
        shot = page.screenshot()
        with open(os.path.join(out, "cube-view.png"), "wb") as f:
            f.write(shot)
        rows = png_pixels(shot)[2]
        mask = cube_mask(rows, refs[0])
        area = sum(map(sum, mask)) / (size * size)
        check(0.2 < area < 0.8, f"the cube covers {area:.0%} of the view")
        noise = pixel_difference(refs[0], refs[1], mask)
        print(f"      kalos's own noise on the cube: {noise:.3f} per pixel and channel "
              f"(two seeds)")
        m_view, m_ref = masked_means(rows, mask), masked_means(refs[0], mask)
        diff = [abs(p - q) for p, q in zip(m_view, m_ref)]
        px = pixel_difference(rows, refs[0], mask)
        print(f"      channel means on the cube: viewer {[round(v, 2) for v in m_view]}, "
              f"kalos {[round(v, 2) for v in m_ref]}, difference "
              f"{[round(d, 2) for d in diff]}; per pixel {px:.3f}")
        ratio = flat_ratio(rows, refs[0], mask)
        print(f"      where the texture is flat: viewer / kalos = {ratio:.4f} (linear)")
        check(abs(ratio - 1) <= LIGHTMAP_FLAT_RATIO,
              f"viewer and kalos agree where the texture is flat within "
              f"{LIGHTMAP_FLAT_RATIO:.0%}")
        check(px <= LIGHTMAP_NOISE_FACTOR * noise,
              f"viewer and kalos agree per pixel within {LIGHTMAP_NOISE_FACTOR} × kalos's "
              f"own seed-to-seed difference")
        check(max(diff) <= LIGHTMAP_MEAN_TOLERANCE,
              f"viewer and kalos agree in every channel mean within {LIGHTMAP_MEAN_TOLERANCE}")
        page.evaluate("window.kalos.setExposure(-1)")
        dark = means(png_pixels(page.screenshot())[2])
        check(all(d < 0.8 * v for d, v in zip(dark, m_view)), "the exposure slider darkens")
        page.evaluate("window.kalos.setExposure(0)")
        page.evaluate("window.kalos.setErrorMap(true)")
        err = page.screenshot()
        with open(os.path.join(out, "cube-error-map.png"), "wb") as f:
            f.write(err)
        em = means(png_pixels(err)[2])
        # 2 % of 10 %: the ramp's first fifth, blue to green, no red
        check(em[2] > em[0] and em[1] > em[0],
              f"the error map shows the cube's 2 % in blue-green (means {[round(v) for v in em]})")
        page.close()
    finally:
        served.stop()


def image_checks(browser, kalos, out):
    # the same render (same seed) as EXR and as PFM, which this script reads;
    # kalos compare shows that the two hold the same numbers
    exr, pfm = os.path.join(out, "small.exr"), os.path.join(out, "small.pfm")
    for o in (exr, pfm):
        run([kalos, "render", "--spp", "4", "--res", "64x48", "--seed", "3", "-q", "-o", o])
    cmp = subprocess.run([kalos, "compare", exr, pfm], check=True, capture_output=True,
                         text=True).stdout
    check(re.search(r"RMSE\s+0\.0+e0", cmp) is not None, "the EXR and the PFM hold the same pixels")
    _, _, px = read_pfm(pfm)
    served = Served([kalos, "view", exr], "stdout")
    try:
        page = browser.new_page(viewport={"width": 600, "height": 400}, device_scale_factor=1)
        page.goto(served.url)
        page.wait_for_function("window.kalos && (window.kalos.ready || window.kalos.error)")
        check(page.evaluate("window.kalos.error") is None, "the EXR loads")
        box = page.locator("#stage canvas").bounding_box()
        x, y = 37, 21
        page.mouse.move(box["x"] + x + 0.5, box["y"] + y + 0.5)
        page.wait_for_function("window.kalos.pixel !== undefined")
        shown = page.evaluate("window.kalos.pixel")
        text = page.inner_text("#pixel")
        want = px[y][3 * x:3 * x + 3]
        got = [float(re.search(rf"{c} (\S+)", text).group(1)) for c in "RGB"]
        print(f"      pixel ({x}, {y}): page {got}, file {list(want)}")
        check((shown["x"], shown["y"]) == (x, y), "the hovered pixel is the one under the pointer")
        # the page prints 7 significant digits of the f32
        check(all(abs(g - v) <= 1e-6 * max(abs(v), 1e-6) for g, v in zip(got, want)),
              "the hovered pixel's value is the file's")
        page.check("#falsecolor")
        check(page.is_visible("#legend"), "false colour shows its legend")
        page.close()
    finally:
        served.stop()


def live_checks(browser, kalos, out):
    # a reference for the convergence curve, at the live render's size
    ref = os.path.join(out, "ref.exr")
    run([kalos, "render", "--spp", "64", "--res", "96x96", "--seed", "9", "-q", "-o", ref])
    live_out = os.path.join(out, "live.exr")
    # a budget far beyond the test: it ends the render with Ctrl-C
    served = Served([kalos, "render", "--view", "--time", "600", "--res", "96x96", "-q",
                     "--ref", ref, "-o", live_out], "stderr")
    try:
        page = browser.new_page(viewport={"width": 600, "height": 400}, device_scale_factor=1)
        page.goto(served.url)
        page.wait_for_function("window.kalos && (window.kalos.ready || window.kalos.error)",
                               timeout=60000)
        first = page.evaluate("[window.kalos.passes, window.kalos.version, window.kalos.imageSum]")
        page.wait_for_timeout(3000)
        later = page.evaluate("[window.kalos.passes, window.kalos.version, window.kalos.imageSum]")
        print(f"      passes, image version, image sum: {first} then {later}")
        check(later[0] > first[0], "the pass count grows")
        check(later[1] > first[1] and later[2] != first[2], "the image changes")
        check(page.is_visible("#curve"), "the convergence curve is drawn (--ref)")
        page.close()
        # closing the page does not stop the render: it goes on passing
        time.sleep(2)
        with urllib.request.urlopen(served.url + "status") as r:
            passes = json.load(r)["passes"]
        check(served.proc.poll() is None and passes > later[0],
              f"the render goes on after the page is closed ({passes} passes)")
        # Ctrl-C still saves the image, and exits with 130
        served.proc.send_signal(signal.SIGINT)
        code = served.proc.wait(timeout=60)
        check(code == 130 and os.path.exists(live_out),
              f"Ctrl-C saves the image and exits with 130 (exit {code})")
    finally:
        served.stop()


def shot_means(page, path):
    """Channel means of a screenshot of `page` (saved at `path`)."""
    shot = page.screenshot()
    with open(path, "wb") as f:
        f.write(shot)
    return means(png_pixels(shot)[2])


def live_lightmap_checks(browser, kalos, out):
    glb = os.path.join(out, "live-cbox.glb")
    t0 = time.time()
    # previews as often as their cost allows (--view-every 0): one after
    # the first batch of particles at least, then the final atlas
    served = Served([kalos, "bake", "scenes/cbox/cbox.xml", "--lightmap", "--view",
                     "--view-every", "0", "--particles", LIVE_PARTICLES, "--lightmap-size",
                     str(LIVE_SIZE), "--seed", "1", "-q", "-o", glb], "stderr")
    try:
        page = browser.new_page(viewport={"width": 256, "height": 256}, device_scale_factor=1)
        page.goto(served.url)
        page.wait_for_function("window.kalos && (window.kalos.atlasVersion > 0 "
                               "|| window.kalos.error)", timeout=60000)
        check(page.evaluate("window.kalos.error") is None, "the live bake's asset loads")
        check(page.evaluate("window.kalos.lightmapped"), "the live asset has its MOZ_lightmap")
        # a mark that a reload would lose
        page.evaluate("window.kalosMark = 1")
        page.evaluate("document.getElementById('panel').style.display = 'none'")
        first = shot_means(page, os.path.join(out, "live-first.png"))
        first_particles = page.evaluate("window.kalos.atlasParticles")
        page.wait_for_function("window.kalos.done || window.kalos.error", timeout=120000)
        k = page.evaluate("[window.kalos.atlasVersion, window.kalos.atlasSums, "
                          "window.kalos.atlasParticles, window.kalosMark, window.kalos.phase]")
        print(f"      atlases shown: {k[0]}, from {first_particles} then {k[2]} particles; "
              f"sums {[round(v, 3) for v in k[1]]}; {time.time() - t0:.1f} s")
        check(k[0] >= 2 and len(set(k[1])) >= 2, "at least two distinct atlases arrive")
        check(k[3] == 1, "the atlases are swapped in place (the page was not reloaded)")
        check(k[4] == "finished" and k[2] == int(LIVE_PARTICLES),
              "the page shows the bake finished, its atlas from every particle")
        final = shot_means(page, os.path.join(out, "live-final.png"))
        page.evaluate("window.kalos.setExposure(-1)")
        dark = shot_means(page, os.path.join(out, "live-dark.png"))
        check(all(d < 0.8 * v for d, v in zip(dark, final)), "the exposure slider darkens")
        page.evaluate("window.kalos.setExposure(0)")
        page.evaluate("window.kalos.setErrorMap(true)")
        err = shot_means(page, os.path.join(out, "live-error-map.png"))
        check(max(abs(a - b) for a, b in zip(err, final)) > 5, "the error map toggles")
        # the bake stays served once written; Ctrl-C ends it with 0
        check(served.proc.poll() is None and os.path.exists(glb),
              "the .glb is written and the page stays up")
        served.proc.send_signal(signal.SIGINT)
        code = served.proc.wait(timeout=30)
        check(code == 0, f"Ctrl-C then ends kalos with 0, the bake written (exit {code})")
        page.close()
    finally:
        served.stop()
    # the written .glb, shown by `kalos view`: the same picture
    view = Served([kalos, "view", glb], "stdout")
    try:
        page = browser.new_page(viewport={"width": 256, "height": 256}, device_scale_factor=1)
        page.goto(view.url)
        page.wait_for_function("window.kalos && (window.kalos.ready || window.kalos.error)",
                               timeout=60000)
        page.evaluate("document.getElementById('panel').style.display = 'none'")
        written = shot_means(page, os.path.join(out, "live-written.png"))
        page.evaluate("window.kalos.setErrorMap(true)")
        written_err = shot_means(page, os.path.join(out, "live-written-error-map.png"))
        page.close()
    finally:
        view.stop()
    diff = max(abs(a - b) for a, b in zip(final, written))
    diff_err = max(abs(a - b) for a, b in zip(err, written_err))
    diff_first = max(abs(a - b) for a, b in zip(first, written))
    print(f"      channel means: live final {[round(v, 2) for v in final]}, written .glb "
          f"{[round(v, 2) for v in written]}; first atlas {[round(v, 2) for v in first]}")
    print(f"      largest difference: final {diff:.3f}, error map {diff_err:.3f}, "
          f"first atlas {diff_first:.3f}")
    check(diff <= LIVE_MEAN_TOLERANCE,
          f"the live page's final picture is the written .glb's within {LIVE_MEAN_TOLERANCE}")
    check(diff_err <= LIVE_ERROR_MAP_TOLERANCE,
          f"so is its error map, within {LIVE_ERROR_MAP_TOLERANCE}")


if __name__ == "__main__":
    main()
