"""Blender add-on: show a kalos lightmap (`MOZ_lightmap`) in imported glTF materials.

`kalos bake SCENE --lightmap -o out.glb` writes each diffuse material with

    "MOZ_lightmap": { "index": T, "texCoord": 1, "intensity": S }

where texture T is a 16-bit linear PNG of E / S, E the irradiance (W/m²
per channel) on uv set 1 (TEXCOORD_1). Blender's own glTF importer knows no
lightmap extension and leaves the image out. This add-on hooks into the
importer (a `glTF2ImportUserExtension`, called after each material is
made): for each material with `MOZ_lightmap` it loads texture T as
Non-Color data, samples it on `TEXCOORD_1` (Blender's uv map `UVMap.001`,
or `UVMap.00N` for texCoord N) with linear filtering clamped at the edge,
and sets the material's surface to

    Emission(base colour × texel × S / π)  +  the material's own emission

which is the radiance L = R·E/π of a Lambertian surface of albedo R (the
base colour, factor × texture, as the importer wired it) under irradiance
E: the baked result, shown by Cycles and Eevee without re-lighting. The
imported Principled BSDF is kept in the node tree, unconnected. Materials
without `MOZ_lightmap` (metals, glass) keep their shading.
Transparency (alpha) is not carried into the emission.

Install (Blender 4.2 or later, or pip `bpy`):
  - Blender: Edit > Preferences > Add-ons > (menu) Install from Disk...,
    choose this file and tick "kalos lightmap"; then File > Import > glTF.
  - Command line: blender -b --python-expr "import sys;
    sys.path.insert(0, 'tools/blender'); import kalos_lightmap;
    kalos_lightmap.enable(); import bpy;
    bpy.ops.import_scene.gltf(filepath='out.glb')"
  - Python with pip `bpy`: the same three lines (`enable()` registers the
    module as an enabled add-on, which is how the importer finds user
    extensions); or run this file:

        python tools/blender/kalos_lightmap.py out.glb [--render out.exr
            --res 256 --samples 16] [--blend out.blend]

    which imports out.glb, reports the uv maps, images and materials, and
    can render the scene camera with emission only (Cycles, no bounces),
    writing a linear EXR (and a PNG beside it).
"""

import math
import os
import sys

import bpy

bl_info = {
    "name": "kalos lightmap",
    "author": "kalos",
    "version": (1, 0, 0),
    "blender": (4, 2, 0),
    "location": "File > Import > glTF 2.0",
    "description": "Wires MOZ_lightmap (a kalos lightmap on TEXCOORD_1) into imported glTF materials",
    "category": "Import-Export",
}

EXTENSION = "MOZ_lightmap"


def _image(gltf, tex_index):
    """The Blender image of glTF texture `tex_index`, created through the
    importer (so it is shared with other users of the same image)."""
    try:
        from io_scene_gltf2.blender.imp.image import BlenderImage
    except ImportError:  # Blender 4.2+'s extension namespace
        from bl_ext.blender_org.io_scene_gltf2.blender.imp.image import BlenderImage
    tex = gltf.data.textures[tex_index]
    if tex.source is None:
        return None
    BlenderImage.create(gltf, tex.source)
    name = gltf.data.images[tex.source].blender_image_name
    return bpy.data.images.get(name) if name else None


def _source(nt, socket):
    """The output socket feeding `socket`, or None (then its default value holds)."""
    for link in nt.links:
        if link.to_socket == socket:
            return link.from_socket
    return None


def wire(gltf, pymat, mat):
    """Sets `mat`'s surface to the lightmap's emission when the glTF
    material carries MOZ_lightmap; returns whether it did."""
    ext = (pymat.extensions or {}).get(EXTENSION)
    if not ext or "index" not in ext:
        return False
    img = _image(gltf, ext["index"])
    if img is None:
        gltf.log.warning(f"{EXTENSION}: material {mat.name!r}: texture {ext['index']} has no image")
        return False
    img.colorspace_settings.is_data = True  # linear values, not sRGB
    intensity = float(ext.get("intensity", 1.0))
    coord = int(ext.get("texCoord", 1))
    nt = mat.node_tree
    bsdf = next((n for n in nt.nodes if n.type == "BSDF_PRINCIPLED"), None)
    out = next((n for n in nt.nodes if n.type == "OUTPUT_MATERIAL"), None)
    if out is None:
        out = nt.nodes.new("ShaderNodeOutputMaterial")

    uv = nt.nodes.new("ShaderNodeUVMap")
    uv.uv_map = "UVMap" if coord == 0 else "UVMap.%03d" % coord
    uv.label = f"{EXTENSION} uv"
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = img
    tex.interpolation = "Linear"
    tex.extension = "EXTEND"
    tex.label = f"{EXTENSION} (E / intensity)"
    nt.links.new(uv.outputs["UV"], tex.inputs["Vector"])

    # texel × intensity / π × base colour
    scale = nt.nodes.new("ShaderNodeVectorMath")
    scale.operation = "SCALE"
    scale.inputs["Scale"].default_value = intensity / math.pi
    nt.links.new(tex.outputs["Color"], scale.inputs[0])
    mul = nt.nodes.new("ShaderNodeVectorMath")
    mul.operation = "MULTIPLY"
    nt.links.new(scale.outputs["Vector"], mul.inputs[0])
    base_in = bsdf.inputs["Base Color"] if bsdf else None
    src = _source(nt, base_in) if base_in is not None else None
    if src is not None:
        nt.links.new(src, mul.inputs[1])
    else:
        c = base_in.default_value[:3] if base_in is not None else (1.0, 1.0, 1.0)
        mul.inputs[1].default_value = c
    lm = nt.nodes.new("ShaderNodeEmission")
    lm.label = "baked lighting"
    lm.inputs["Strength"].default_value = 1.0
    nt.links.new(mul.outputs["Vector"], lm.inputs["Color"])
    surface = lm.outputs["Emission"]

    # the material's own emission (glTF emissive × strength), kept
    if bsdf is not None:
        ec, es = bsdf.inputs["Emission Color"], bsdf.inputs["Emission Strength"]
        ec_src, es_src = _source(nt, ec), _source(nt, es)
        emits = ec_src is not None or es_src is not None
        emits = emits or (es.default_value > 0 and max(ec.default_value[:3]) > 0)
        if emits:
            own = nt.nodes.new("ShaderNodeEmission")
            own.label = "own emission"
            if ec_src is not None:
                nt.links.new(ec_src, own.inputs["Color"])
            else:
                own.inputs["Color"].default_value = ec.default_value
            if es_src is not None:
                nt.links.new(es_src, own.inputs["Strength"])
            else:
                own.inputs["Strength"].default_value = es.default_value
            add = nt.nodes.new("ShaderNodeAddShader")
            nt.links.new(surface, add.inputs[0])
            nt.links.new(own.outputs["Emission"], add.inputs[1])
            surface = add.outputs["Shader"]
    for link in list(nt.links):
        if link.to_socket == out.inputs["Surface"]:
            nt.links.remove(link)
    nt.links.new(surface, out.inputs["Surface"])
    mat["kalos_lightmap_intensity"] = intensity
    x = -900
    for n in (uv, tex, scale, mul, lm):
        n.location = (x, -500)
        x += 200
    return True


class glTF2ImportUserExtension:
    """The importer's hook: called after each material is made."""

    def __init__(self):
        self.wired = []

    def gather_import_material_after_hook(self, pymat, vertex_color, mat, gltf):
        if wire(gltf, pymat, mat):
            self.wired.append(mat.name)


def enable():
    """Registers this module as an enabled add-on (the importer looks for
    `glTF2ImportUserExtension` in enabled add-ons' modules); for scripts
    that import it from sys.path instead of installing it."""
    name = __name__
    addons = bpy.context.preferences.addons
    if addons.get(name) is None:
        addons.new().module = name


def register():
    pass


def unregister():
    pass


def _report():
    for o in bpy.data.objects:
        if o.type == "MESH":
            me = o.data
            print(f"mesh {o.name}: {len(me.polygons)} faces, uv maps {[u.name for u in me.uv_layers]}, "
                  f"materials {[m.name for m in me.materials if m]}")
        else:
            print(f"{o.type.lower()} {o.name}")
    for m in bpy.data.materials:
        if m.node_tree is None:
            continue
        kinds = sorted({n.type for n in m.node_tree.nodes})
        out = next((n for n in m.node_tree.nodes if n.type == "OUTPUT_MATERIAL"), None)
        surf = [l.from_node.type for l in m.node_tree.links if out and l.to_node == out]
        print(f"material {m.name}: surface from {surf}, nodes {kinds}"
              + (f", lightmap intensity {m['kalos_lightmap_intensity']:.4g}" if "kalos_lightmap_intensity" in m else ""))
    for i in bpy.data.images:
        if i.type == "IMAGE":
            print(f"image {i.name!r}: {i.size[0]}×{i.size[1]}, float {i.is_float}, depth {i.depth}, "
                  f"colour space {i.colorspace_settings.name}, users {i.users}")


def _pixels(path):
    import numpy as np

    img = bpy.data.images.load(path)
    img.colorspace_settings.is_data = True
    w, h = img.size
    px = np.empty(w * h * img.channels, dtype=np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, -1)[:, :, :3]


def _compare(path, ref_path, background):
    """Channel means of the render and the reference, over all pixels and
    over the pixels where the reference is not the background."""
    import numpy as np

    x, r = _pixels(path), _pixels(ref_path)
    if x.shape != r.shape:
        sys.exit(f"{path} is {x.shape[1]}×{x.shape[0]}, {ref_path} {r.shape[1]}×{r.shape[0]}")
    fg = np.any(np.abs(r - background) > 1e-4, axis=2) | np.any(np.abs(x - background) > 1e-4, axis=2)
    for what, m in (("all pixels", np.ones(fg.shape, bool)), (f"{fg.sum()} foreground pixels", fg)):
        mx, mr = x[m].mean(0), r[m].mean(0)
        print(f"channel means over {what}: blender {np.round(mx, 4)}, reference {np.round(mr, 4)}, "
              f"ratio {np.round(mx / mr, 4)}")


def _main(argv):
    import argparse

    ap = argparse.ArgumentParser(description="Import a kalos lightmapped .glb with its lightmap wired in")
    ap.add_argument("glb")
    ap.add_argument("--plain", action="store_true", help="import without this extension (to compare)")
    ap.add_argument("--render", help="render the scene camera with emission only to this .exr")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--background", type=float, default=0.0, help="the world's radiance (grey)")
    ap.add_argument("--compare", help="a reference .exr (e.g. `kalos render` of the scene): print channel means")
    ap.add_argument("--blend", help="save the scene as this .blend")
    args = ap.parse_args(argv)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if not args.plain:
        enable()
    bpy.ops.import_scene.gltf(filepath=os.path.abspath(args.glb))
    _report()
    if args.render:
        sc = bpy.context.scene
        cams = [o for o in bpy.data.objects if o.type == "CAMERA"]
        if not cams:
            sys.exit(f"{args.glb}: no camera")
        sc.camera = cams[0]
        sc.render.engine = "CYCLES"
        sc.cycles.device = "CPU"
        sc.render.threads_mode = "FIXED"
        sc.render.threads = args.threads
        sc.cycles.samples = args.samples
        sc.cycles.use_adaptive_sampling = False
        sc.cycles.use_denoising = False
        sc.cycles.max_bounces = 0  # emission seen by the camera only
        sc.render.resolution_x = sc.render.resolution_y = args.res
        sc.render.resolution_percentage = 100
        sc.render.film_transparent = False
        sc.view_settings.view_transform = "Standard"
        sc.world = sc.world or bpy.data.worlds.new("world")
        if sc.world.node_tree is None:
            sc.world.use_nodes = True
        if sc.world.node_tree is not None:
            for n in sc.world.node_tree.nodes:
                if n.type == "BACKGROUND":
                    n.inputs["Color"].default_value = (1, 1, 1, 1)
                    n.inputs["Strength"].default_value = args.background
        sc.render.image_settings.file_format = "OPEN_EXR"
        sc.render.image_settings.color_depth = "32"
        sc.render.filepath = os.path.abspath(args.render)
        bpy.ops.render.render(write_still=True)
        png = os.path.splitext(os.path.abspath(args.render))[0] + ".png"
        sc.render.image_settings.file_format = "PNG"
        sc.render.image_settings.color_depth = "8"
        bpy.data.images["Render Result"].save_render(png)
        print(f"rendered {args.render} and {png}")
        if args.compare:
            _compare(os.path.abspath(args.render), os.path.abspath(args.compare), args.background)
    if args.blend:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(args.blend))


if __name__ == "__main__":
    _main(sys.argv[1:])
