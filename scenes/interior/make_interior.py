#!/usr/bin/env python3
"""Builds the textured interior in Blender and exports it with Blender's own
glTF exporter: two rooms joined by an ajar door, lit by a sky panel outside
the first room's window.

    python make_interior.py [OUT_DIR]

It needs Blender as a Python module (pip `bpy`; written against 5.0.1) and
numpy (which bpy's wheel brings). It writes, into OUT_DIR (default: this
script's folder):

- `interior.glb`: what kalos reads today (the sky panel, an emissive mesh,
  is the only light; no lamp, no glass), for the lightmap acceptance
  measurement (benches/acceptance/interior_lightmap.py);
- `interior-lamp-glass.glb`: the same, plus a glass vase on the table
  (Principled BSDF transmission 1, IOR 1.52) and a point lamp under the
  second room's ceiling (KHR_lights_punctual), for glTF as exporters write
  it (lamps, glass).

Everything is made here: the geometry from boxes, the textures (parquet,
wood grain, a painting with fine detail) from numpy with a fixed seed. No
file is read. Blender's coordinates are z-up; the exporter writes glTF's
y-up (x, z, −y). Units are metres.
"""

import math
import os
import sys
import tempfile

import bpy
import numpy as np
from mathutils import Vector

OUT = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.abspath(__file__)))

# --- the plan (Blender coordinates, metres) ---------------------------------
# Room A: x in [0, 4]; room B: x in [4.15, 8.15]; both y in [0, 5],
# floor at z = 0, ceiling at z = 2.7; walls 0.15 thick.
T = 0.15
H = 2.7
XB0, XB1 = 4.0 + T, 8.0 + T  # room B's inner x range
WINDOW = dict(x=(1.2, 3.4), z=(0.85, 2.3))  # in room A's north wall (y = 5)
DOOR = dict(y=(2.2, 3.1), z=(0.0, 2.1))  # in the shared wall (x in [4, 4.15])
DOOR_ANGLE = 30.0  # degrees open, into room B, hinged at its y = 3.1 side
SKY_STRENGTH = 150.0  # the sky panel's emission (radiance, W/(m^2 sr))
PAINTING = dict(x=(5.0, 7.0), z=(0.8, 2.2))  # on room B's south wall (y = 0)
CAMERA = dict(pos=(6.4, 4.8, 1.6), target=(6.1, 0.0, 1.2), hfov=84.0, res=(768, 512))

rng = np.random.RandomState(20261126)


# --- textures ------------------------------------------------------------------

def value_noise(h, w, cells_y, cells_x, rs=rng):
    """Smooth noise in [0, 1]: a random grid, bicubic-smoothed (smoothstep)
    bilinear upsampling, tiling."""
    g = rs.rand(cells_y, cells_x)
    y = np.arange(h) * cells_y / h
    x = np.arange(w) * cells_x / w
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    fy, fx = y - y0, x - x0
    fy, fx = fy * fy * (3 - 2 * fy), fx * fx * (3 - 2 * fx)
    y1, x1 = (y0 + 1) % cells_y, (x0 + 1) % cells_x
    a = g[y0][:, x0] * (1 - fx) + g[y0][:, x1] * fx
    b = g[y1][:, x0] * (1 - fx) + g[y1][:, x1] * fx
    return a * (1 - fy)[:, None] + b * fy[:, None]


def fbm(h, w, base, octaves, rs=rng):
    out, amp, tot = np.zeros((h, w)), 1.0, 0.0
    for o in range(octaves):
        c = base * 2 ** o
        out += amp * value_noise(h, w, c, c, rs)
        tot += amp
        amp *= 0.5
    return out / tot


def wood(h, w, rs, light=(0.62, 0.42, 0.24), dark=(0.36, 0.21, 0.10), rings=38.0):
    """Wood grain along x (u): stretched rings with fine pores, sRGB in [0, 1]."""
    y = np.linspace(0, 1, h, endpoint=False)[:, None]
    warp = fbm(h, w, 4, 4, rs)
    t = (y + 0.08 * warp + 0.02 * fbm(h, w, 16, 2, rs)) * rings
    ring = 0.5 + 0.5 * np.sin(2 * math.pi * t)
    ring = ring ** 3
    pores = (rs.rand(h, w) < 0.015).astype(float)
    pores = np.maximum(pores, np.roll(pores, 1, axis=1))
    mix = np.clip(0.75 * ring + 0.25 * fbm(h, w, 32, 2, rs) - 0.35 * pores, 0, 1)
    light, dark = np.array(light), np.array(dark)
    return dark + (light - dark) * mix[..., None]


def parquet(n, rs):
    """Staggered planks (the image is 2 m square: 20 rows of 0.1 m by 0.5 m
    planks), each with its own tone and grain, dark joints."""
    img = np.zeros((n, n, 3))
    rows, plank_len = 20, 4  # planks per row across the image
    rh, pw = n // rows, n // plank_len
    grain = wood(n, n, rs, light=(0.66, 0.45, 0.25), dark=(0.42, 0.26, 0.13), rings=90.0)
    for r in range(rows):
        off = (r * pw // 2 + rs.randint(pw // 4)) % n if r % 2 else rs.randint(pw // 4)
        for k in range(plank_len + 1):
            x0 = (off + k * pw) % n
            tone = 0.8 + 0.35 * rs.rand()
            shift = rs.randint(n)
            cols = (np.arange(x0, x0 + pw) % n)
            img[r * rh:(r + 1) * rh, cols] = np.roll(grain, shift, axis=0)[r * rh:(r + 1) * rh][:, cols] * tone
            img[r * rh:(r + 1) * rh, x0 % n] *= 0.35  # end joint
        img[r * rh, :] *= 0.35  # long joint
    return np.clip(img, 0, 1)


def painting(h, w, rs):
    """An abstract painting with detail down to a texel: colour fields,
    hatching, rings and short strokes 1-6 texels wide."""
    y, x = np.mgrid[0:h, 0:w].astype(float)
    img = np.zeros((h, w, 3))
    # a sky-to-ground gradient with soft blotches
    sky = np.array([0.25, 0.45, 0.75]) + 0.25 * fbm(h, w, 6, 4, rs)[..., None]
    ground = np.array([0.55, 0.4, 0.12]) + 0.3 * fbm(h, w, 8, 4, rs)[..., None]
    horizon = 0.55 * h + 40 * np.sin(x / w * 5.0)
    img[:] = np.where((y < horizon)[..., None], sky, ground)
    # colour fields (Mondrian-like) with black borders 3 texels wide
    for _ in range(9):
        x0, y0 = rs.randint(w - 200), rs.randint(h - 160)
        bw, bh = rs.randint(60, 200), rs.randint(50, 160)
        c = np.array([[0.85, 0.1, 0.08], [0.95, 0.8, 0.1], [0.1, 0.15, 0.6], [0.9, 0.9, 0.85]][rs.randint(4)])
        img[y0:y0 + bh, x0:x0 + bw] = c
        img[y0:y0 + 3, x0:x0 + bw] = img[y0 + bh - 3:y0 + bh, x0:x0 + bw] = 0.02
        img[y0:y0 + bh, x0:x0 + 3] = img[y0:y0 + bh, x0 + bw - 3:x0 + bw] = 0.02
    # concentric rings, 2 texels wide every 9, around a sun
    cx, cy = 0.72 * w, 0.25 * h
    r = np.hypot(x - cx, y - cy)
    rings = (r < 170) & ((r % 9) < 2)
    img[rings] = [0.98, 0.85, 0.3]
    img[(r < 38)] = [1.0, 0.95, 0.7]
    # hatching in the lower left: diagonal lines 1 texel wide every 5
    hatch = (x < 0.4 * w) & (y > 0.62 * h) & (((x + y) % 5) < 1)
    img[hatch] *= 0.25
    # cross-hatching in a band on the right
    band = (x > 0.6 * w) & (y > 0.7 * h) & ((((x - y) % 7) < 1.5) | (((x + y) % 7) < 1.5))
    img[band] = [0.05, 0.05, 0.08]
    # radial lines from the sun
    ang = np.arctan2(y - cy, x - cx)
    rays = (r > 180) & (r < 330) & ((np.abs(((ang * 48 / math.pi) % 2) - 1) < 0.12))
    img[rays] = [0.95, 0.6, 0.15]
    # short strokes 1-6 texels wide, in many colours
    for _ in range(700):
        x0, y0 = rs.rand() * w, rs.rand() * h
        a = rs.rand() * math.pi
        length, width = 10 + 40 * rs.rand(), 1 + rs.randint(6)
        c = rs.rand(3) ** 1.5
        t = np.linspace(0, length, int(length) * 2)
        xs = np.clip((x0 + np.cos(a) * t).astype(int), 0, w - 1)
        ys = np.clip((y0 + np.sin(a) * t).astype(int), 0, h - 1)
        for d in range(width):
            img[np.clip(ys + d, 0, h - 1), xs] = c
    # fine noise, as a canvas texture
    img *= (0.9 + 0.2 * rs.rand(h, w))[..., None]
    return np.clip(img, 0, 1)


def make_image(name, rgb, fmt, folder):
    """A Blender image from sRGB values in [0, 1] (top row first), saved as
    PNG or JPEG and packed, so that the exporter embeds those bytes."""
    h, w, _ = rgb.shape
    img = bpy.data.images.new(name, width=w, height=h, alpha=False)
    px = np.ones((h, w, 4), dtype=np.float32)
    px[..., :3] = rgb[::-1]  # Blender's rows go bottom up
    img.pixels.foreach_set(px.ravel())
    ext = {"PNG": "png", "JPEG": "jpg"}[fmt]
    img.filepath_raw = os.path.join(folder, f"{name}.{ext}")
    img.file_format = fmt
    if fmt == "JPEG":
        bpy.context.scene.render.image_settings.quality = 90
    img.save()
    img.reload()
    img.pack()
    return img


# --- materials -----------------------------------------------------------------

def principled(name, color=(0.8, 0.8, 0.8), rough=0.5, metal=0.0, image=None, two_sided=True):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    m.use_backface_culling = not two_sided
    p = m.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (*color, 1.0)
    p.inputs["Roughness"].default_value = rough
    p.inputs["Metallic"].default_value = metal
    if image is not None:
        t = m.node_tree.nodes.new("ShaderNodeTexImage")
        t.image = image
        m.node_tree.links.new(t.outputs["Color"], p.inputs["Base Color"])
    return m


def emitter(name, color, strength):
    """An emissive, one-sided material with a black base colour."""
    m = principled(name, color=(0, 0, 0), rough=1.0, two_sided=False)
    p = m.node_tree.nodes["Principled BSDF"]
    p.inputs["Emission Color"].default_value = (*color, 1.0)
    p.inputs["Emission Strength"].default_value = strength
    return m


def glass(name):
    m = principled(name, color=(1, 1, 1), rough=0.0)
    p = m.node_tree.nodes["Principled BSDF"]
    p.inputs["Transmission Weight"].default_value = 1.0
    # crown glass; at 1.5 (glTF's default) the exporter leaves out
    # KHR_materials_ior
    p.inputs["IOR"].default_value = 1.52
    return m


# --- geometry ------------------------------------------------------------------

# box corner i = x bit + 2 y bit + 4 z bit; faces wound outward
FACES = [((0, 4, 6, 2), 0), ((1, 3, 7, 5), 0), ((0, 1, 5, 4), 1), ((2, 6, 7, 3), 1),
         ((0, 2, 3, 1), 2), ((4, 5, 7, 6), 2)]
# the two world axes a face's uv follows, by its normal axis
UV_AXES = {0: (1, 2), 1: (0, 2), 2: (0, 1)}


def mesh_object(name, boxes, materials, location=(0, 0, 0), rotation_z=0.0):
    """One object made of boxes. Each box: (lo, hi, material index, uv),
    where uv is a number s (world-planar uv, one repeat every s metres, the
    grain along x for floors and along a face's longer side otherwise) or a
    function (face normal axis, sign, corner) -> uv."""
    verts, faces, mat_idx, uvs = [], [], [], []
    for lo, hi, mi, uv in boxes:
        base = len(verts)
        corners = [Vector((hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1],
                           hi[2] if i & 4 else lo[2])) for i in range(8)]
        verts += corners
        for k, (f, axis) in enumerate(FACES):
            faces.append(tuple(base + i for i in f))
            mat_idx.append(mi)
            sign = 1 if k % 2 else -1
            if callable(uv):
                uvs.append([uv(axis, sign, corners[i]) for i in f])
            else:
                a, b = UV_AXES[axis]
                ext_a, ext_b = hi[a] - lo[a], hi[b] - lo[b]
                if axis != 2 and ext_b > ext_a:  # grain along the longer side
                    a, b = b, a
                uvs.append([(corners[i][a] / uv, corners[i][b] / uv) for i in f])
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in verts], [], faces)
    for m in materials:
        me.materials.append(m)
    layer = me.uv_layers.new(name="UVMap")
    for poly, mi, fuv in zip(me.polygons, mat_idx, uvs):
        poly.material_index = mi
        for li, u in zip(poly.loop_indices, fuv):
            layer.data[li].uv = u
    me.validate()
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    ob.rotation_euler = (0, 0, math.radians(rotation_z))
    bpy.context.scene.collection.objects.link(ob)
    return ob


def build(tex_dir):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.unit_settings.system = "METRIC"
    scene.render.resolution_x, scene.render.resolution_y = CAMERA["res"]

    rs = np.random.RandomState(7)
    img_parquet = make_image("parquet", parquet(1024, rs), "JPEG", tex_dir)
    img_wood = make_image("wood", wood(1024, 1024, rs), "JPEG", tex_dir)
    img_painting = make_image("painting", painting(768, 1024, rs), "PNG", tex_dir)

    paint = principled("wall_paint", color=(0.80, 0.78, 0.72), rough=0.9)
    ceiling = principled("ceiling_paint", color=(0.85, 0.85, 0.83), rough=0.95)
    floor = principled("parquet_polished", rough=0.12, image=img_parquet)
    woodm = principled("wood", rough=0.45, image=img_wood)
    brass = principled("brass", color=(0.9, 0.7, 0.35), rough=0.3, metal=1.0)
    canvas = principled("painting", rough=0.7, image=img_painting)
    sky = emitter("sky", (0.80, 0.88, 1.0), SKY_STRENGTH)

    x0, x1, y0, y1 = -T, XB1 + T, -T, 5.0 + T
    mesh_object("Floor", [((x0, y0, -0.1), (x1, y1, 0.0), 0, 2.0)], [floor])
    mesh_object("Ceiling", [((x0, y0, H), (x1, y1, H + 0.1), 0, 1.0)], [ceiling])

    wx, wz = WINDOW["x"], WINDOW["z"]
    dy, dz = DOOR["y"], DOOR["z"]
    walls = [
        ((x0, y0, 0), (x1, 0.0, H)),  # south
        ((XB1, 0.0, 0), (x1, 5.0, H)),  # east
        ((x0, 0.0, 0), (0.0, 5.0, H)),  # west
        # north, around room A's window
        ((x0, 5.0, 0), (wx[0], y1, H)), ((wx[1], 5.0, 0), (x1, y1, H)),
        ((wx[0], 5.0, 0), (wx[1], y1, wz[0])), ((wx[0], 5.0, wz[1]), (wx[1], y1, H)),
        # shared, around the door
        ((4.0, 0.0, 0), (XB0, dy[0], H)), ((4.0, dy[1], 0), (XB0, 5.0, H)),
        ((4.0, dy[0], dz[1]), (XB0, dy[1], H)),
    ]
    mesh_object("Walls", [(lo, hi, 0, 1.0) for lo, hi in walls], [paint])

    # the door: hinged at (XB0, 3.1), its leaf in local y in [-0.88, 0]
    w = dy[1] - dy[0] - 0.02
    knob_y = (-w + 0.06, -w + 0.10)
    mesh_object("Door", [
        ((0.0, -w, 0.0), (0.04, 0.0, dz[1] - 0.015), 0, 1.0),
        ((0.04, knob_y[0], 1.0), (0.10, knob_y[1], 1.05), 1, 1.0),
        ((-0.06, knob_y[0], 1.0), (0.0, knob_y[1], 1.05), 1, 1.0),
    ], [woodm, brass], location=(XB0, dy[1] - 0.01, 0.005), rotation_z=DOOR_ANGLE)

    # the table, in room B
    tx, ty, th = (5.0, 6.2), (1.4, 2.2), 0.75
    legs = [((x, y, 0.0), (x + 0.06, y + 0.06, th - 0.04), 0, 1.0)
            for x in (tx[0] + 0.05, tx[1] - 0.11) for y in (ty[0] + 0.05, ty[1] - 0.11)]
    mesh_object("Table", [((tx[0], ty[0], th - 0.04), (tx[1], ty[1], th), 0, 1.2)] + legs, [woodm])

    # the painting on room B's south wall, seen from +y: u runs along -x
    px, pz = PAINTING["x"], PAINTING["z"]

    def canvas_uv(axis, sign, c):
        if axis == 1 and sign > 0:
            return ((px[1] - c[0]) / (px[1] - px[0]), (c[2] - pz[0]) / (pz[1] - pz[0]))
        return (0.02, 0.02)

    f = 0.05
    mesh_object("Painting", [
        ((px[0], 0.0, pz[0]), (px[1], 0.03, pz[1]), 0, canvas_uv),
        ((px[0] - f, 0.0, pz[0] - f), (px[1] + f, 0.05, pz[0]), 1, 0.5),
        ((px[0] - f, 0.0, pz[1]), (px[1] + f, 0.05, pz[1] + f), 1, 0.5),
        ((px[0] - f, 0.0, pz[0]), (px[0], 0.05, pz[1]), 1, 0.5),
        ((px[1], 0.0, pz[0]), (px[1] + f, 0.05, pz[1]), 1, 0.5),
    ], [canvas, woodm])

    # the sky: an emissive panel just outside the window, a little larger
    # than it, facing it (-y); close to the window, so that most of its
    # light enters and a shading point that sees the sky sees much of it
    sx, sz = (wx[0] - 0.05, wx[1] + 0.05), (wz[0] - 0.05, wz[1] + 0.05)
    sy = y1 + 0.01
    me = bpy.data.meshes.new("Sky")
    me.from_pydata([(sx[0], sy, sz[0]), (sx[1], sy, sz[0]), (sx[1], sy, sz[1]),
                    (sx[0], sy, sz[1])], [], [(0, 1, 2, 3)])
    me.materials.append(sky)
    ob = bpy.data.objects.new("Sky", me)
    scene.collection.objects.link(ob)

    # the camera, in room B
    cam = bpy.data.cameras.new("Camera")
    cam.sensor_fit = "HORIZONTAL"
    cam.angle = math.radians(CAMERA["hfov"])
    cam.clip_start = 0.05
    co = bpy.data.objects.new("Camera", cam)
    co.location = CAMERA["pos"]
    d = Vector(CAMERA["target"]) - Vector(CAMERA["pos"])
    co.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()
    scene.collection.objects.link(co)
    scene.camera = co
    return scene


def add_lamp_and_glass():
    """The glass vase on the table and a point lamp under room B's ceiling."""
    bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=24, radius=0.12,
                                         location=(5.8, 1.8, 0.75 + 0.12))
    vase = bpy.context.active_object
    vase.name = vase.data.name = "GlassVase"
    vase.scale = (1.0, 1.0, 1.4)
    vase.location.z = 0.75 + 0.12 * 1.4
    bpy.ops.object.shade_smooth()
    vase.data.materials.append(glass("glass"))
    lamp = bpy.data.lights.new("Lamp", type="POINT")
    lamp.energy = 60.0  # watts, as Blender counts a point lamp's power
    lamp.color = (1.0, 0.85, 0.65)
    lamp.shadow_soft_size = 0.05
    lo = bpy.data.objects.new("Lamp", lamp)
    lo.location = (6.2, 2.8, 2.35)
    bpy.context.scene.collection.objects.link(lo)


def export(path, lights):
    bpy.ops.export_scene.gltf(
        filepath=path, export_format="GLB", export_cameras=True, export_lights=lights,
        export_yup=True, export_apply=True, export_image_format="AUTO",
        export_import_convert_lighting_mode="SPEC")
    print(f"wrote {path} ({os.path.getsize(path)} bytes)")


def main():
    os.makedirs(OUT, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="interior-tex-") as tex_dir:
        build(tex_dir)
        export(os.path.join(OUT, "interior.glb"), lights=False)
        add_lamp_and_glass()
        export(os.path.join(OUT, "interior-lamp-glass.glb"), lights=True)


if __name__ == "__main__":
    main()
