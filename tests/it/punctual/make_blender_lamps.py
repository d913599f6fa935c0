"""Writes blender-lamps.gltf (+ .bin) with Blender's own glTF exporter:
a 100 W point lamp, a 200 W spot (60° wide, blend 0.25) and a sun of
strength 3 W/m² over a 4 m plane. Run once with the pip `bpy` package
(Blender 5.0.1): python make_blender_lamps.py OUTPUT_DIR"""
import math
import os
import sys

import bpy

out = sys.argv[-1]
bpy.ops.wm.read_factory_settings(use_empty=True)
sc = bpy.context.scene


def lamp(kind, name, loc, rot, energy, **kw):
    d = bpy.data.lights.new(name, kind)
    d.energy = energy
    for k, v in kw.items():
        setattr(d, k, v)
    o = bpy.data.objects.new(name, d)
    o.location = loc
    o.rotation_euler = rot
    sc.collection.objects.link(o)


lamp("POINT", "pt", (0, 0, 2), (0, 0, 0), 100.0, shadow_soft_size=0.0)
lamp("SPOT", "sp", (1, 0, 2), (0.3, 0, 0), 200.0,
     spot_size=math.radians(60), spot_blend=0.25, shadow_soft_size=0.0)
lamp("SUN", "sun", (0, 0, 5), (0.5, 0.2, 0), 3.0)
bpy.ops.mesh.primitive_plane_add(size=4)
bpy.ops.export_scene.gltf(filepath=os.path.join(out, "blender-lamps.gltf"),
                          export_format="GLTF_SEPARATE", export_lights=True)
