"""Blender's side of bench/bench_peer.py: Cell Fracture of one asset into N pieces, a convex hull each, one GLB.

    blender -b --factory-startup --python bench/peer_blender.py -- IN OUT.glb N [--seed S]

Runs inside Blender (its own Python: bpy, bmesh and what Blender ships, nothing
of this project). What a user of Blender does by hand, as a script:

1. import the asset (File > Import: the glTF importer for .glb, with its "Merge
   Vertices" option so the mesh is closed where the file splits vertices at UV
   seams, or the OBJ importer for .obj) and join its mesh objects into one;
2. give it a particle system of N particles emitted from its volume (the
   add-on's default point source, "Own Particles": points inside the solid);
3. Cell Fracture (the bundled add-on ``object_fracture_cell``,
   ``bpy.ops.object.add_fracture_cell_objects``) with ``source_limit`` N and the
   add-on's defaults otherwise, except ``use_debug_redraw`` (a debug option that
   redraws the window after every cell: there is no window here);
4. delete the original (the add-on keeps it), then add one convex hull per piece
   as a mesh named ``UCX_<piece>_00``: the way collision shapes get into a GLB
   from Blender (the rigid body's "Convex Hull" shape stays in the .blend: the
   glTF exporter writes no physics), and what Unreal's importers take as convex
   collision of ``<piece>`` (fracture writes the same with ``collision.glb=unreal``);
5. export everything as one GLB (File > Export > glTF 2.0, defaults).

Prints one line ``PEER_JSON {...}``: seconds of each step (startup = the
process's start to this script's first line, from /proc), the number of
pieces and of hull meshes. The bench measures the whole process from outside.
"""

import json
import os
import random
import sys
import time

T0 = time.perf_counter()


def _process_age() -> float:
    """Seconds since this process started (Linux /proc), or -1 where unknown."""
    try:
        with open("/proc/self/stat") as fh:
            start_ticks = int(fh.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as fh:
            uptime = float(fh.read().split()[0])
        return uptime - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return -1.0


STARTUP = _process_age()

import numpy  # noqa: E402

# Debian's numpy (1.24) has no np.bool any more; Blender 3.4's glTF importer still uses it.
if "bool" not in numpy.__dict__:
    numpy.bool = bool

import addon_utils  # noqa: E402
import bmesh  # noqa: E402
import bpy  # noqa: E402


def _args() -> tuple[str, str, int, int]:
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    seed = 0
    if "--seed" in argv:
        i = argv.index("--seed")
        seed = int(argv[i + 1])
        del argv[i:i + 2]
    if len(argv) != 3:
        raise SystemExit("usage: blender -b --factory-startup --python peer_blender.py -- IN OUT.glb N [--seed S]")
    return argv[0], argv[1], int(argv[2]), seed


def _import(path: str) -> bpy.types.Object:
    for obj in list(bpy.data.objects):  # the factory scene's cube, camera and light
        bpy.data.objects.remove(obj, do_unlink=True)
    if path.lower().endswith((".glb", ".gltf")):
        bpy.ops.import_scene.gltf(filepath=path, merge_vertices=True)
    elif path.lower().endswith(".obj"):
        bpy.ops.wm.obj_import(filepath=path)
    else:
        raise SystemExit(f"{path}: only .glb, .gltf and .obj here")
    meshes = [obj for obj in bpy.context.scene.objects if obj.type == "MESH"]
    if not meshes:
        raise SystemExit(f"{path}: no mesh")
    bpy.ops.object.select_all(action="DESELECT")
    for obj in meshes:
        obj.select_set(True)
    bpy.context.view_layer.objects.active = meshes[0]
    if len(meshes) > 1:
        bpy.ops.object.join()
    return bpy.context.view_layer.objects.active


def _particles(obj: bpy.types.Object, count: int, seed: int) -> None:
    modifier = obj.modifiers.new("fracture_sites", type="PARTICLE_SYSTEM")
    system = modifier.particle_system
    system.seed = seed
    settings = system.settings
    settings.count = count
    settings.emit_from = "VOLUME"
    settings.distribution = "RAND"
    settings.frame_start = settings.frame_end = 1
    settings.lifetime = 1000
    settings.physics_type = "NO"
    bpy.context.scene.frame_set(1)


def _fracture(obj: bpy.types.Object, count: int) -> list:
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    before = set(bpy.context.scene.objects)
    bpy.ops.object.add_fracture_cell_objects(source={"PARTICLE_OWN"}, source_limit=count, use_debug_redraw=False)
    pieces = [o for o in bpy.context.scene.objects if o not in before and o.type == "MESH"]
    bpy.data.objects.remove(obj, do_unlink=True)  # the add-on keeps the original: a user deletes it
    return pieces


def _hulls(pieces: list) -> int:
    collection = bpy.context.scene.collection
    made = 0
    for piece in pieces:
        if len(piece.data.vertices) < 4:
            continue
        bm = bmesh.new()  # the piece's corners alone: the hull's faces are then the only faces
        for vertex in piece.data.vertices:
            bm.verts.new(vertex.co)
        result = bmesh.ops.convex_hull(bm, input=bm.verts)
        # As Mesh > Convex Hull does by default: drop the corners inside the hull.
        drop = {g for g in result["geom_interior"] + result["geom_unused"] if isinstance(g, bmesh.types.BMVert)}
        bmesh.ops.delete(bm, geom=list(drop), context="VERTS")
        mesh = bpy.data.meshes.new(f"UCX_{piece.name}_00")
        bm.to_mesh(mesh)
        bm.free()
        hull = bpy.data.objects.new(mesh.name, mesh)
        hull.matrix_world = piece.matrix_world.copy()
        collection.objects.link(hull)
        made += 1
    return made


def main() -> None:
    source, out, count, seed = _args()
    random.seed(seed)  # the add-on shuffles points and jitters cell corners with Python's random
    addon_utils.enable("object_fracture_cell", default_set=True)
    seconds = {"startup": STARTUP, "setup": time.perf_counter() - T0}
    t = time.perf_counter()
    obj = _import(os.path.abspath(source))
    seconds["import"] = time.perf_counter() - t
    t = time.perf_counter()
    _particles(obj, count, seed)
    pieces = _fracture(obj, count)
    seconds["fracture"] = time.perf_counter() - t
    t = time.perf_counter()
    hulls = _hulls(pieces)
    seconds["hulls"] = time.perf_counter() - t
    t = time.perf_counter()
    bpy.ops.export_scene.gltf(filepath=os.path.abspath(out), export_format="GLB")
    seconds["export"] = time.perf_counter() - t
    print("PEER_JSON " + json.dumps({"seconds": seconds, "pieces": len(pieces), "hulls": hulls,
                                     "blender": bpy.app.version_string}), flush=True)


main()
