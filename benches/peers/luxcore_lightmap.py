"""LuxCore's bake engine (BAKECPU, LIGHTMAP maps) on kalos's own lightmap atlas.

A peer benchmark for `kalos bake --lightmap` (issue 34); it runs outside CI.

Needs: Python 3.11 with pip `pyluxcore` (2.11.2 measured) and numpy, in a
virtual environment; a lightmapped .glb written by kalos (`kalos bake SCENE
--lightmap --lightmap-size 512 -o cbox.glb`), read here by hand (meshes,
base colour factors, emission), whose TEXCOORD_1 is the layout baked into.

What a bake is: each glTF primitive becomes a LuxCore mesh with TEXCOORD_1
as its uv set, each material a `matte` of the base colour factor (emitters:
with `emission` = emissive factor × KHR_materials_emissive_strength, gain 1,
no power normalisation); a BAKECPU render of one LIGHTMAP map of all the
meshes on that uv set, 64 bounces, no clamping, margin 4 px, no pixel
filter (`--filter NONE`: each sample lands in one texel, as Cycles'
do; LuxCore's default Blackman-Harris spreads it over its neighbours),
written through a linear image pipeline (no tone map, no gamma) scaled by
π as a float EXR. LIGHTMAP is the light arriving at the surface (direct
light plus one path along a uniformly sampled hemisphere direction
weighted by its cosine, without albedo) and measures E/π: × π (`--scale`)
its mean over the covered texels is the Cycles reference's × 1.001
(cycles_lightmap.py `compare` prints that ratio).

BAKECPU samples points on the meshes by area, not texels: its "samples per
pixel" (batch.haltspp) count the map's texels, covered or not.

    PY benches/peers/luxcore_lightmap.py cbox.glb OUT.exr --spp 64 [--threads 2] [--seed 1]

prints the wall and CPU time of the render (scene set-up excluded) and
the passes done.
"""

import argparse
import json
import math
import os
import struct
import sys
import time

import numpy as np
import pyluxcore

COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def read_glb(path):
    data = open(path, "rb").read()
    if data[:4] != b"glTF":
        sys.exit(f"{path}: not a .glb")
    n = struct.unpack_from("<I", data, 12)[0]
    j = json.loads(data[20 : 20 + n])
    off = 20 + n
    blen = struct.unpack_from("<I", data, off)[0]
    binary = data[off + 8 : off + 8 + blen]

    def accessor(i):
        a = j["accessors"][i]
        v = j["bufferViews"][a["bufferView"]]
        dt = np.dtype(COMPONENT[a["componentType"]])
        w = WIDTH[a["type"]]
        start = v.get("byteOffset", 0) + a.get("byteOffset", 0)
        stride = v.get("byteStride", dt.itemsize * w)
        rows = [np.frombuffer(binary, dt, w, start + k * stride) for k in range(a["count"])]
        return np.array(rows)

    return j, accessor


def node_matrices(j):
    """World matrix (4×4, column vectors) of each node that holds a mesh."""
    out = []

    def local(n):
        if "matrix" in n:
            return np.array(n["matrix"], dtype=np.float64).reshape(4, 4).T
        t = np.eye(4)
        if "translation" in n:
            t[:3, 3] = n["translation"]
        r = np.eye(4)
        if "rotation" in n:
            x, y, z, w = n["rotation"]
            r[:3, :3] = [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        s = np.eye(4)
        if "scale" in n:
            s[:3, :3] = np.diag(n["scale"])
        return t @ r @ s

    def walk(i, parent):
        n = j["nodes"][i]
        m = parent @ local(n)
        if "mesh" in n:
            out.append((i, n["mesh"], m))
        for c in n.get("children", []):
            walk(c, m)

    scene = j["scenes"][j.get("scene", 0)]
    for i in scene["nodes"]:
        walk(i, np.eye(4))
    return out


def build(glb, spp, threads, seed, out, uvset, bounces, margin, scale, filt):
    j, accessor = read_glb(glb)
    props = pyluxcore.Properties()
    scene = pyluxcore.Scene()
    for k, m in enumerate(j["materials"]):
        base = m.get("pbrMetallicRoughness", {}).get("baseColorFactor", [1, 1, 1, 1])[:3]
        p = f"scene.materials.m{k}"
        props.Set(pyluxcore.Property(f"{p}.type", "matte"))
        props.Set(pyluxcore.Property(f"{p}.kd", [float(x) for x in base]))
        em = m.get("emissiveFactor", [0, 0, 0])
        s = m.get("extensions", {}).get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0)
        if max(em) > 0:
            props.Set(pyluxcore.Property(f"{p}.emission", [float(x * s) for x in em]))
            props.Set(pyluxcore.Property(f"{p}.emission.gain", [1.0, 1.0, 1.0]))
            props.Set(pyluxcore.Property(f"{p}.emission.power", 0.0))
            props.Set(pyluxcore.Property(f"{p}.emission.efficency", 0.0))
    names = []
    for node, mesh, mat in node_matrices(j):
        for pi, prim in enumerate(j["meshes"][mesh]["primitives"]):
            a = prim["attributes"]
            key = f"TEXCOORD_{uvset}"
            if key not in a:
                sys.exit(f"{glb}: mesh {mesh} primitive {pi} has no {key}")
            pos = accessor(a["POSITION"]).astype(np.float64)
            pos = (np.c_[pos, np.ones(len(pos))] @ mat.T)[:, :3].astype(np.float32)
            idx = accessor(prim["indices"]).reshape(-1, 3).astype(np.uint32) if "indices" in prim else np.arange(len(pos), dtype=np.uint32).reshape(-1, 3)
            uv = accessor(a[key]).astype(np.float32).copy()
            name = f"n{node}p{pi}"
            # uv set 0 of the LuxCore mesh is the atlas's uv
            scene.DefineMeshExt(name, pos, idx, None, [uv], None, None, None)
            props.Set(pyluxcore.Property(f"scene.objects.{name}.shape", name))
            props.Set(pyluxcore.Property(f"scene.objects.{name}.material", f"m{prim.get('material', 0)}"))
            names.append(name)
    props.Set(pyluxcore.Property("scene.camera.type", "perspective"))
    props.Set(pyluxcore.Property("scene.camera.lookat.orig", [0.0, 0.0, -1000.0]))
    props.Set(pyluxcore.Property("scene.camera.lookat.target", [0.0, 0.0, 0.0]))
    props.Set(pyluxcore.Property("scene.camera.up", [0.0, 1.0, 0.0]))
    scene.Parse(props)

    exr = os.path.splitext(glb)[0] + ".lightmap.exr"
    width = 512
    if os.path.exists(exr):
        # OpenEXR header: find dataWindow (box2i) to read the atlas's size
        h = open(exr, "rb").read(4096)
        k = h.find(b"dataWindow\0box2i\0")
        if k >= 0:
            x0, y0, x1, y1 = struct.unpack_from("<4i", h, k + len(b"dataWindow\0box2i\0") + 4)
            width = x1 - x0 + 1
    cfg = pyluxcore.Properties()
    for key, val in [
        ("renderengine.type", "BAKECPU"),
        ("sampler.type", "SOBOL"),
        ("renderengine.seed", seed),
        ("native.threads.count", threads),
        ("film.width", 64),
        ("film.height", 64),
        ("film.imagepipelines.0.0.type", "TONEMAP_LINEAR"),
        ("film.imagepipelines.0.0.scale", scale),
        ("film.filter.type", filt),
        ("path.pathdepth.total", bounces),
        ("path.pathdepth.diffuse", bounces),
        ("path.pathdepth.glossy", bounces),
        ("path.pathdepth.specular", bounces),
        ("path.clamping.variance.maxvalue", 0.0),
        ("path.forceblackbackground.enable", True),
        ("batch.haltspp", spp),
        ("bake.margin", margin),
        ("bake.maps.0.type", "LIGHTMAP"),
        ("bake.maps.0.filename", os.path.abspath(out)),
        ("bake.maps.0.imagepipelineindex", 0),
        ("bake.maps.0.width", width),
        ("bake.maps.0.height", width),
        ("bake.maps.0.uvindex", 0),
        ("bake.maps.0.objectnames", names),
    ]:
        cfg.Set(pyluxcore.Property(key, val))
    return pyluxcore.RenderConfig(cfg, scene)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("glb")
    ap.add_argument("out")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--uvset", type=int, default=1, help="the glTF uv set baked into (TEXCOORD_N)")
    ap.add_argument("--bounces", type=int, default=64)
    ap.add_argument("--margin", type=int, default=4)
    ap.add_argument("--scale", type=float, default=math.pi, help="factor on LIGHTMAP's value (π: it is E/π)")
    ap.add_argument("--filter", default="NONE", help="the film's pixel filter (LuxCore's default: BLACKMANHARRIS)")
    args = ap.parse_args()
    pyluxcore.Init(lambda msg: None)
    config = build(os.path.abspath(args.glb), args.spp, args.threads, args.seed, args.out, args.uvset, args.bounces, args.margin, args.scale, args.filter)
    session = pyluxcore.RenderSession(config)
    t, c0 = time.perf_counter(), time.process_time()
    session.Start()
    while not session.HasDone():
        time.sleep(0.05)
        session.UpdateStats()
    session.Stop()
    dt, cpu = time.perf_counter() - t, time.process_time() - c0
    stats = session.GetStats()
    print(f"{args.out}: {args.spp} spp, {dt:.2f} s wall, {cpu:.2f} s cpu, "
          f"{stats.Get('stats.renderengine.pass').GetInt()} passes; load {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    # pyluxcore 2.11.2 segfaults at interpreter exit (after the map is written): leave at once
    os._exit(0)


if __name__ == "__main__":
    main()
