"""Run by tests/test_blender.py in its own process (bpy is a whole Blender): import a
USD headless and print every mesh's evaluated world-space vertex positions at the
given frames, as JSON on a line starting with JSON."""

import json
import sys

import bpy

usd, frames = sys.argv[1], [int(x) for x in sys.argv[2].split(",")]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.usd_import(filepath=usd)
scene = bpy.context.scene
out = {}
for t in frames:
    scene.frame_set(t)
    dg = bpy.context.evaluated_depsgraph_get()
    pts = []
    for obj in sorted((o for o in scene.objects if o.type == "MESH"), key=lambda o: o.name):
        ev = obj.evaluated_get(dg)
        mesh = ev.to_mesh()
        mw = ev.matrix_world
        pts += [list(mw @ v.co) for v in mesh.vertices]
        ev.to_mesh_clear()
    out[t] = pts
names = sorted(o.name for o in scene.objects if o.type == "MESH")
print("JSON" + json.dumps({"names": names, "points": out}))
