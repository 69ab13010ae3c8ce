"""Run by tests/test_blender.py in its own process (bpy is a whole Blender): import a
USD headless and print, per mesh object, its vertex count, UV layer (per face corner),
material slots and evaluated local vertex positions at a frame, as JSON on a line
starting with JSON."""

import json
import sys

import bpy

usd, frame = sys.argv[1], int(sys.argv[2])
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.usd_import(filepath=usd)
scene = bpy.context.scene
scene.frame_set(frame)
dg = bpy.context.evaluated_depsgraph_get()
out = {}
for obj in (o for o in scene.objects if o.type == "MESH"):
    ev = obj.evaluated_get(dg)
    mesh = ev.to_mesh()
    uv = mesh.uv_layers.active
    out[obj.name] = {
        "vertices": len(mesh.vertices),
        "faces": len(mesh.polygons),
        "points": [list(v.co) for v in mesh.vertices],
        "uv": [list(d.uv) for d in uv.data] if uv is not None else None,
        "loops": [lp.vertex_index for lp in mesh.loops],
        "materials": [s.material.name for s in obj.material_slots if s.material is not None],
    }
    ev.to_mesh_clear()
print("JSON" + json.dumps(out))
