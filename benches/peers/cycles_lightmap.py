"""Blender Cycles' diffuse bake on kalos's own lightmap atlas, against a reference.

A peer benchmark for `kalos bake --lightmap` (issue 34); it runs outside CI.

Needs: Python 3.11 with Blender's `bpy` module (pip `bpy`, 5.0.1 measured)
and numpy (a dependency of bpy), in a virtual environment; a lightmapped
.glb written by kalos (`kalos bake SCENE --lightmap --lightmap-size 512 -o
cbox.glb`), whose TEXCOORD_1 is the atlas layout every bake here uses.

What a bake is: the .glb imported with Blender's glTF importer, its meshes
joined into one object, each material replaced by a Lambertian `Diffuse
BSDF` of the material's base colour (glTF's metallic-roughness model adds a
specular layer, which the Mitsuba Cornell box has not), plus, on emitters,
an `Emission` of the imported colour × strength that emits from the front
face only (Mitsuba's area lights are one-sided; Cycles' emission is
two-sided). Then Cycles' `DIFFUSE` bake with direct and indirect light and
no colour, on the uv map of TEXCOORD_1 (`UVMap.001`), into one float image
of the atlas's size: margin 4 px (`EXTEND`), 64 bounces (max and diffuse),
no clamping, no denoising, no adaptive sampling, 2 threads. Cycles' value
with colour off is the diffuse lighting before albedo, E/π; the images
written here are multiplied by π so that they hold E, as kalos's atlas
(`OUT.lightmap.exr`) does, in the same orientation (row 0 at the top).

The error of a bake X against a reference R (the mean of two independent
halves A and B) is the per-texel relative RMS over the texels the kalos atlas
covers (every texel a uv triangle touches, as kalos rasterises them:
conservatively) whose channels all exceed 1e-3 × their median there (the
occluded ones, under the boxes and behind the luminaire, are 0), over the
three channels: sqrt(mean(((X − R)/R)²) − mean(((A − B)/(2R))²)), the
second term being the reference's own noise, subtracted in quadrature.
Also printed: the same on luminance, and both normalised by the mean over
texels instead of each texel's own value.

Commands (PY is the venv's python):

    PY benches/peers/cycles_lightmap.py reference cbox.glb OUTDIR --samples 4096 [--chunk 256]
        calls of `chunk` samples with seeds 1, 2, 3...: each written as
        OUTDIR/chunk-256-seedKK.exr; the odd seeds make half a, the even
        half b; after each pair the halves and their mean so far are written
        as OUTDIR/cbox-512-cycles-N-a.exr, -b.exr and cbox-512-cycles-N.exr
        (N the samples so far), so a partial reference is there before the
        whole one; also OUTDIR/covered.exr (1 where kalos's atlas covers)
    PY benches/peers/cycles_lightmap.py curve cbox.glb REF.exr REF-a.exr REF-b.exr \
            --samples 16,64,256,1024 [--keep OUTDIR]
        bakes at each sample count (seed 3), prints wall and CPU time,
        Cycles' fixed cost (a 1-sample bake) and the errors against REF
    PY benches/peers/cycles_lightmap.py bake cbox.glb 'OUT-{n}.exr' --samples 1,16,64 --seed 101
        bakes only, each written ({n}: the sample count), with wall and CPU
        time (to score later with compare)
    PY benches/peers/cycles_lightmap.py compare cbox.glb REF.exr REF-a.exr REF-b.exr X.exr...
        the errors of any atlas (a kalos bake's .lightmap.exr) and its mean
        ratio to REF; the last error leaves out the texels whose centre
        lies inside geometry (`inside_geometry`)

Options: --threads (2), --margin (4), --bounces (64), --seed (curve, bake).
Times are of `bpy.ops.object.bake` alone (import and set-up excluded): wall
clock, and the process's CPU time (all threads), which says more on a
loaded machine. The atlas size is read from the kalos EXR beside the .glb
(OUT.lightmap.exr), 512 without it.
"""

import argparse
import math
import os
import sys
import time

import numpy as np

import bpy

# The depth by which a triangle must enter a texel's square to cover it, in
# texels (kalos's raster::TOUCH).
TOUCH = 1e-4


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def load_glb(glb):
    """Imports the .glb into an empty scene and joins its meshes into one
    object, which it returns (selected and active)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=glb)
    meshes = [o for o in bpy.data.objects if o.type == "MESH"]
    if not meshes:
        sys.exit(f"{glb}: no meshes")
    bpy.ops.object.select_all(action="DESELECT")
    for o in meshes:
        o.select_set(True)
    bpy.context.view_layer.objects.active = meshes[0]
    if len(meshes) > 1:
        bpy.ops.object.join()
    obj = bpy.context.view_layer.objects.active
    uvs = [u.name for u in obj.data.uv_layers]
    if len(uvs) < 2:
        sys.exit(f"{glb}: no second uv set (TEXCOORD_1); uv maps: {uvs}")
    return obj


def principled_values(mat):
    """The base colour and emitted radiance (colour × strength, as Blender's
    importer set them) of an imported material."""
    base, emit = (0.8, 0.8, 0.8), (0.0, 0.0, 0.0)
    nt = mat.node_tree
    for n in nt.nodes:
        if n.type == "BSDF_PRINCIPLED":
            base = tuple(n.inputs["Base Color"].default_value[:3])
            c = n.inputs["Emission Color"].default_value[:3]
            s = n.inputs["Emission Strength"].default_value
            emit = tuple(x * s for x in c)
            if n.inputs["Base Color"].is_linked or n.inputs["Emission Color"].is_linked:
                log(f"warning: material {mat.name!r} has textures; only factors are used")
    return base, emit


def lambertian_materials(obj, image):
    """Replaces each material's nodes by a Diffuse BSDF (+ a front-face
    Emission on emitters) and an active Image Texture node holding `image`,
    the bake target."""
    for mat in obj.data.materials:
        base, emit = principled_values(mat)
        nt = mat.node_tree
        nt.nodes.clear()
        out = nt.nodes.new("ShaderNodeOutputMaterial")
        diff = nt.nodes.new("ShaderNodeBsdfDiffuse")
        diff.inputs["Color"].default_value = (*base, 1.0)
        diff.inputs["Roughness"].default_value = 0.0
        shader = diff.outputs["BSDF"]
        if max(emit) > 0:
            em = nt.nodes.new("ShaderNodeEmission")
            s = max(emit)
            em.inputs["Color"].default_value = (*(x / s for x in emit), 1.0)
            geo = nt.nodes.new("ShaderNodeNewGeometry")
            front = nt.nodes.new("ShaderNodeMath")
            front.operation = "MULTIPLY_ADD"  # backfacing × (−s) + s
            front.inputs[1].default_value = -s
            front.inputs[2].default_value = s
            nt.links.new(geo.outputs["Backfacing"], front.inputs[0])
            nt.links.new(front.outputs[0], em.inputs["Strength"])
            add = nt.nodes.new("ShaderNodeAddShader")
            nt.links.new(shader, add.inputs[0])
            nt.links.new(em.outputs["Emission"], add.inputs[1])
            shader = add.outputs["Shader"]
            mat.cycles.emission_sampling = "FRONT"
            log(f"emitter {mat.name!r}: radiance {emit}, front face only")
        nt.links.new(shader, out.inputs["Surface"])
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image = image
        nt.nodes.active = tex


def setup_cycles(obj, size, threads, bounces):
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    sc.render.threads_mode = "FIXED"
    sc.render.threads = threads
    cy.use_denoising = False
    cy.use_adaptive_sampling = False
    cy.time_limit = 0.0
    cy.max_bounces = bounces
    cy.diffuse_bounces = bounces
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    sc.world = sc.world or bpy.data.worlds.new("black")
    sc.world.use_nodes = True
    bg = sc.world.node_tree.nodes.get("Background")
    if bg is not None:
        bg.inputs["Strength"].default_value = 0.0
    uv1 = obj.data.uv_layers[1]
    obj.data.uv_layers.active = uv1
    image = bpy.data.images.new("lightmap", size, size, alpha=False, float_buffer=True)
    lambertian_materials(obj, image)
    return image


def bake(obj, image, samples, seed, margin):
    """One Cycles DIFFUSE bake into `image`; returns its wall time (s) and
    the atlas as E, an (h, w, 3) array in Blender's row order (row 0 at the
    bottom)."""
    sc = bpy.context.scene
    sc.cycles.samples = samples
    sc.cycles.seed = seed
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    t = time.perf_counter()
    bpy.ops.object.bake(
        type="DIFFUSE",
        pass_filter={"DIRECT", "INDIRECT"},
        margin=margin,
        margin_type="EXTEND",
        use_clear=True,
        target="IMAGE_TEXTURES",
        uv_layer=obj.data.uv_layers[1].name,
    )
    dt = time.perf_counter() - t
    w, h = image.size
    px = np.empty(w * h * 4, dtype=np.float32)
    image.pixels.foreach_get(px)
    return dt, px.reshape(h, w, 4)[:, :, :3] * math.pi


def save_exr(arr, path):
    """Writes an (h, w, 3) array in Blender's row order as a float EXR (the
    file has row 0 at the top, as kalos's atlas)."""
    h, w, _ = arr.shape
    img = bpy.data.images.new(os.path.basename(path), w, h, alpha=True, float_buffer=True)
    # data, not colour: else Blender 5 writes the values sRGB-encoded
    img.colorspace_settings.is_data = True
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[:, :, :3] = arr
    img.pixels.foreach_set(rgba.ravel())
    img.filepath_raw = path
    img.file_format = "OPEN_EXR"
    img.save()
    bpy.data.images.remove(img)


def load_exr(path):
    """An EXR as an (h, w, 3) array in Blender's row order."""
    img = bpy.data.images.load(path)
    img.colorspace_settings.is_data = True
    w, h = img.size
    px = np.empty(w * h * img.channels, dtype=np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, -1)[:, :, :3]


def covered(obj, size):
    """Per texel (Blender's row order), whether a triangle of uv map 1
    touches its square, as kalos's rasteriser decides it (conservatively:
    overlapping the square by more than TOUCH)."""
    me = obj.data
    me.calc_loop_triangles()
    uv = me.uv_layers[1].data
    mask = np.zeros((size, size), dtype=bool)
    for tri in me.loop_triangles:
        p = np.array([uv[i].uv[:] for i in tri.loops], dtype=np.float64) * size
        area = (p[1, 0] - p[0, 0]) * (p[2, 1] - p[0, 1]) - (p[2, 0] - p[0, 0]) * (p[1, 1] - p[0, 1])
        if abs(area) < 1e-12:
            continue
        if area < 0:
            p = p[[0, 2, 1]]
        x0 = max(int(math.floor(p[:, 0].min())), 0)
        x1 = min(int(math.ceil(p[:, 0].max())), size)
        y0 = max(int(math.floor(p[:, 1].min())), 0)
        y1 = min(int(math.ceil(p[:, 1].max())), size)
        if x0 >= x1 or y0 >= y1:
            continue
        xs, ys = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1))
        ok = (
            (p[:, 0].max() > xs + TOUCH)
            & (p[:, 0].min() < xs + 1 - TOUCH)
            & (p[:, 1].max() > ys + TOUCH)
            & (p[:, 1].min() < ys + 1 - TOUCH)
        )
        for k in range(3):
            a, b = p[k], p[(k + 1) % 3]
            e = b - a
            n = np.array([e[1], -e[0]]) / math.hypot(*e)  # outward (ccw)
            # the square's deepest corner into the triangle along −n
            m = np.minimum(n[0] * (xs - a[0]), n[0] * (xs + 1 - a[0])) + np.minimum(
                n[1] * (ys - a[1]), n[1] * (ys + 1 - a[1])
            )
            ok &= m < -TOUCH
        mask[y0:y1, x0:x1] |= ok
    return mask


def inside_geometry(obj, size, rays=32, seed=1):
    """Per texel (Blender's row order), whether its centre lies inside
    geometry: more than a quarter of `rays` cosine-weighted rays from the
    point of uv map 1 under the texel's centre meet the back of a face
    (kalos's rule for a hidden texel, `gather::BACKFACE_SHARE`, computed
    here independently with Blender's BVH). Such texels are the floor
    under a box's foot: Cycles bakes the point under the box (dark), kalos
    the visible floor beside it. Texels whose centre lies on no triangle
    are False."""
    from mathutils import Vector
    from mathutils.bvhtree import BVHTree

    bvh = BVHTree.FromObject(obj, bpy.context.evaluated_depsgraph_get())
    me, mw = obj.data, obj.matrix_world
    me.calc_loop_triangles()
    uv = me.uv_layers[1].data
    rng = np.random.default_rng(seed)
    out = np.zeros((size, size), dtype=bool)
    side = int(math.sqrt(rays))
    for tri in me.loop_triangles:
        p = np.array([uv[i].uv[:] for i in tri.loops], dtype=np.float64) * size
        P = [mw @ me.vertices[v].co for v in tri.vertices]
        n = (mw.to_3x3() @ tri.normal).normalized()
        e1, e2 = p[1] - p[0], p[2] - p[0]
        det = e1[0] * e2[1] - e2[0] * e1[1]
        if abs(det) < 1e-12:
            continue
        t = Vector((1, 0, 0)) if abs(n.x) < 0.9 else Vector((0, 1, 0))
        t = (t - n * n.dot(t)).normalized()
        b = n.cross(t)
        for y in range(max(int(p[:, 1].min()), 0), min(int(p[:, 1].max()) + 1, size)):
            for x in range(max(int(p[:, 0].min()), 0), min(int(p[:, 0].max()) + 1, size)):
                c = np.array([x + 0.5, y + 0.5]) - p[0]
                l1 = (c[0] * e2[1] - e2[0] * c[1]) / det
                l2 = (e1[0] * c[1] - c[0] * e1[1]) / det
                if l1 < 0 or l2 < 0 or l1 + l2 > 1:
                    continue
                q = P[0] * (1 - l1 - l2) + P[1] * l1 + P[2] * l2 + n * 1e-4
                backs = 0
                for k in range(rays):
                    u1 = (k % side + rng.random()) / side
                    u2 = (k // side % side + rng.random()) / side
                    r, ph = math.sqrt(u1), 2 * math.pi * u2
                    w = t * (r * math.cos(ph)) + b * (r * math.sin(ph)) + n * math.sqrt(max(0.0, 1 - u1))
                    loc, nor, _, _ = bvh.ray_cast(q, w)
                    backs += loc is not None and nor.dot(w) > 0
                out[y, x] = backs > rays / 4
    return out


# The luminance weights (Rec. 709) of the luminance metrics.
LUMA = np.array([0.2126, 0.7152, 0.0722])


def metrics(x, ref, a, b, mask, inside=None):
    """The error of atlas x against ref (the mean of halves a and b) over
    the covered texels where every channel of ref is above 1e-3 of its
    median: {name: (error with the reference's noise subtracted in
    quadrature, raw error, the reference's own noise)}. The metrics:
    per-texel relative per channel (the primary one), per-texel relative
    on luminance, and the two normalised by the mean over texels instead
    of each texel's value (dark texels weigh less); with `inside` (the
    texels of `inside_geometry`), the last again without those texels."""
    r = ref[mask].astype(np.float64)
    keep = (r > 1e-3 * np.median(r, axis=0)).all(axis=1)
    r = r[keep]
    e = x[mask][keep].astype(np.float64) - r
    d = (a[mask][keep].astype(np.float64) - b[mask][keep]) / 2
    rl = r @ LUMA
    forms = {
        "per-texel relative, per channel": (e / r, d / r),
        "per-texel relative, luminance": ((e @ LUMA) / rl, (d @ LUMA) / rl),
        "over the channel's mean, per channel": (e / r.mean(0), d / r.mean(0)),
        "over the mean luminance, luminance": ((e @ LUMA) / rl.mean(), (d @ LUMA) / rl.mean()),
    }
    if inside is not None:
        vis = ~inside[mask][keep]
        rv = rl[vis].mean()
        forms["the same, centres on visible surfaces"] = ((e[vis] @ LUMA) / rv, (d[vis] @ LUMA) / rv)
    out = {}
    for name, (ee, dd) in forms.items():
        raw, noise = np.mean(ee**2), np.mean(dd**2)
        out[name] = (math.sqrt(max(raw - noise, 0.0)), math.sqrt(raw), math.sqrt(noise))
    return out


def rel_rms(x, ref, a, b, mask):
    """The primary metric of `metrics`: (error, raw, reference noise)."""
    return metrics(x, ref, a, b, mask)["per-texel relative, per channel"]


def show(m):
    return "; ".join(f"{k}: {100 * c:.2f} % (raw {100 * raw:.2f}, ref. noise {100 * n:.2f})" for k, (c, raw, n) in m.items())


def loadavg():
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cmd", choices=["reference", "curve", "compare", "bake"])
    ap.add_argument("glb")
    ap.add_argument("rest", nargs="*")
    ap.add_argument("--samples", default="4096")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--margin", type=int, default=4)
    ap.add_argument("--bounces", type=int, default=64)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--keep", help="directory to write the curve's bakes in")
    ap.add_argument("--chunk", type=int, default=256, help="samples per bake call of the reference")
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    args = ap.parse_args(argv)

    obj = load_glb(os.path.abspath(args.glb))
    # The atlas size: kalos's EXR beside the .glb, else --size from the reference.
    exr = os.path.splitext(os.path.abspath(args.glb))[0] + ".lightmap.exr"
    kalos = load_exr(exr) if os.path.exists(exr) else None
    size = kalos.shape[0] if kalos is not None else 512
    mask = covered(obj, size)
    log(f"{args.glb}: {size}² atlas, {mask.sum()} covered texels; load {loadavg()}")

    if args.cmd == "reference":
        (outdir,) = args.rest
        n = int(args.samples)
        chunk = min(args.chunk, n // 2)
        image = setup_cycles(obj, size, args.threads, args.bounces)
        name = os.path.splitext(os.path.basename(args.glb))[0]
        stem = os.path.join(outdir, f"{name}-{size}-cycles")
        m = np.repeat(mask[:, :, None], 3, axis=2).astype(np.float32)
        save_exr(m, os.path.join(outdir, "covered.exr"))
        # Chunks of `chunk` samples, seeds 1, 2, 3...: the odd seeds sum to
        # half a, the even ones to half b; after each pair the halves and
        # their mean so far are written (named by their sample count), so
        # that a partial reference is there before the whole one.
        sums = [np.zeros((size, size, 3)), np.zeros((size, size, 3))]
        k = 0
        while 2 * chunk * (k // 2) < n:
            seed = k + 1
            c0 = time.process_time()
            dt, e = bake(obj, image, chunk, seed, args.margin)
            cpu = time.process_time() - c0
            save_exr(e, os.path.join(outdir, f"chunk-{chunk}-seed{seed:02d}.exr"))
            sums[k % 2] += e
            log(f"chunk seed {seed}: {chunk} samples, {dt:.1f} s wall, {cpu:.1f} s cpu; load {loadavg()}")
            k += 1
            if k % 2 == 0:
                total = chunk * k
                a, b = (s / (k // 2) for s in sums)
                ref = 0.5 * (a + b)
                for suffix, arr in (("-a", a), ("-b", b), ("", ref)):
                    save_exr(arr, f"{stem}-{total}{suffix}.exr")
                _, _, noise = rel_rms(ref, ref, a, b, mask)
                line = f"{stem}-{total}.exr: {total} samples, relative noise {100 * noise:.3f} %"
                if kalos is not None:
                    r, kk = ref[mask], kalos[mask]
                    line += f"; kalos/(cycles×π) mean ratio per channel {kk.mean(0) / r.mean(0)}, all {kk.sum() / r.sum():.4f}"
                print(line, flush=True)
        return

    if args.cmd == "bake":
        image = setup_cycles(obj, size, args.threads, args.bounces)
        for n in (int(s) for s in args.samples.split(",")):
            out = args.rest[0].replace("{n}", str(n))
            c0 = time.process_time()
            dt, x = bake(obj, image, n, args.seed, args.margin)
            cpu = time.process_time() - c0
            save_exr(x, out)
            print(f"{out}: {n} samples, seed {args.seed}, {dt:.2f} s wall, {cpu:.2f} s cpu; load {loadavg()}", flush=True)
        return

    ref, a, b = (load_exr(p) for p in args.rest[:3])
    if args.cmd == "compare":
        inside = inside_geometry(obj, size)
        log(f"texels whose centre lies inside geometry: {(inside & mask).sum()}")
        for p in args.rest[3:]:
            x = load_exr(p)
            ratio = x[mask].sum(0) / ref[mask].sum(0)
            print(f"{p}: mean ratio to the reference (R, G, B) {np.round(ratio, 4)}; {show(metrics(x, ref, a, b, mask, inside))}")
        return

    image = setup_cycles(obj, size, args.threads, args.bounces)
    for seed in (args.seed, args.seed + 1):
        c0 = time.process_time()
        dt1, _ = bake(obj, image, 1, seed, args.margin)
        print(f"fixed cost (a 1-sample bake): {dt1:.2f} s wall, {time.process_time() - c0:.2f} s cpu; load {loadavg()}")
    print("samples  wall s  cpu s  errors")
    for n in (int(s) for s in args.samples.split(",")):
        c0 = time.process_time()
        dt, x = bake(obj, image, n, args.seed, args.margin)
        cpu = time.process_time() - c0
        print(f"{n:7d}  {dt:6.1f}  {cpu:6.1f}  {show(metrics(x, ref, a, b, mask))}  load {loadavg()}", flush=True)
        if args.keep:
            save_exr(x, os.path.join(args.keep, f"cycles-{n}.exr"))

if __name__ == "__main__":
    main()
