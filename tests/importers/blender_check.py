"""Blender's own glTF importer on terrachunk chunks (DESIGN.md promise 4).

    python blender_check.py TILESET_DIR [--render docs/blender_chunk.png]

For the root, a skirted mid-level chunk and a leaf (glbref.pick_chunks),
imported one at a time into an empty scene with `bpy.ops.import_scene.gltf`:
- vertex and face counts equal the file's (read by glbref, which shares no
  code with terrachunk or Blender);
- the world-space bounding box (node translation applied, Blender's y-up →
  z-up turn: glTF (x, y, z) → Blender (x, −z, y)) equals the chunk's box
  from the file, and its x/y extent equals the footprint in the node extras
  times the spacing, within f32 rounding;
- the morph target arrives as a shape key "parent" whose vertices (value 1)
  are base + delta of the file, and those points lie on the parent chunk's
  surface (its triangles interpolated) within f32 rounding; the root's
  shape key moves nothing;
- the texture is bound: the Principled BSDF's Base Color is linked from an
  Image Texture node whose image has the tile's size.
Prints one line per chunk; exits 1 on any mismatch.
"""

import argparse
import math
import os
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import glbref  # noqa: E402

# Positions are chunk-local f32 (the node translation is f64): a chunk
# x metres wide places a vertex to about x·2⁻²⁴, so tolerances grow with the
# chunk: 1 mm plus two f32 units at its size. The morph check adds the
# parent's rounding.
def pos_tol(extent_m):
    return 1e-3 + 2.0 * np.spacing(np.float32(extent_m)).item()


SURFACE_TOL_M = 5e-3


def empty_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def import_chunk(path):
    """Import one .glb; returns the mesh objects it created."""
    before = set(bpy.data.objects)
    result = bpy.ops.import_scene.gltf(filepath=path)
    if "FINISHED" not in result:
        raise RuntimeError(f"import of {path} returned {result}")
    return [o for o in bpy.data.objects if o not in before and o.type == "MESH"]


def world_coords(obj, shape_key=None):
    """World coordinates (N × 3) of the object's vertices, from the base mesh
    or from one shape key's data."""
    mesh = obj.data
    n = len(mesh.vertices)
    co = np.empty(n * 3)
    if shape_key is None:
        mesh.vertices.foreach_get("co", co)
    else:
        mesh.shape_keys.key_blocks[shape_key].data.foreach_get("co", co)
    co = co.reshape(n, 3)
    m = np.array(obj.matrix_world)
    return co @ m[:3, :3].T + m[:3, 3]


def base_colour_image(obj):
    """The image linked into the Principled BSDF's Base Color, or a reason."""
    if not obj.material_slots or obj.material_slots[0].material is None:
        return None, "no material"
    mat = obj.material_slots[0].material
    if mat.node_tree is None:
        return None, f"material {mat.name} has no node tree"
    bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None:
        return None, f"material {mat.name} has no Principled BSDF"
    links = bsdf.inputs["Base Color"].links
    if not links:
        return None, "Base Color is not linked"
    node = links[0].from_node
    if node.type != "TEX_IMAGE" or node.image is None:
        return None, f"Base Color comes from {node.type}, not an image texture"
    return node.image, None


def check_chunk(tileset, ts, label, key, parent_key, failures):
    path = glbref.chunk_path(tileset, key)
    ref = glbref.Chunk(path)
    empty_scene()
    objs = import_chunk(path)
    fail = lambda msg: failures.append(f"{label} {glbref.name(key)}: {msg}")  # noqa: E731
    if len(objs) != 1:
        fail(f"import made {len(objs)} mesh objects, expected 1")
        if not objs:
            return None
    obj = objs[0]
    mesh = obj.data
    nv, nf = len(mesh.vertices), len(mesh.polygons)
    if (nv, nf) != (ref.vertices, ref.triangles):
        fail(f"Blender has {nv} vertices / {nf} faces, the file {ref.vertices} / {ref.triangles}")
    if any(len(p.vertices) != 3 for p in mesh.polygons):
        fail("non-triangle faces after import")

    # World box, z-up: the file's box turned the way Blender turns it.
    world = world_coords(obj)
    lo, hi = world.min(axis=0), world.max(axis=0)
    rlo, rhi = ref.world_bounds()
    zlo, zhi = glbref.to_z_up(rlo), glbref.to_z_up(rhi)
    zlo, zhi = np.minimum(zlo, zhi), np.maximum(zlo, zhi)
    tol = pos_tol(float(np.abs(rhi - rlo).max()))
    box_err = max(np.abs(lo - zlo).max(), np.abs(hi - zhi).max())
    if box_err > tol:
        fail(f"world box {lo.round(3)}..{hi.round(3)} differs from the file's {zlo.round(3)}..{zhi.round(3)}")
    want_x, (z0, z1) = glbref.footprint_xz(ref)
    want_y = (-z1, -z0)  # rows run south = −y in Blender
    fp_err = max(abs(lo[0] - want_x[0]), abs(hi[0] - want_x[1]), abs(lo[1] - want_y[0]), abs(hi[1] - want_y[1]))
    # The curved frame puts each vertex where the Earth has it, turned by
    # the grid's convergence and bent by the Earth: no longer the footprint
    # in grid metres (the world box above is still the file's).
    curved = (ts["extras"]["terrachunk"].get("placement") or {}).get("frame") == "curved"
    if fp_err > tol and not curved:
        fail(f"x/y extent {lo[:2].round(3)}..{hi[:2].round(3)} is not the footprint {want_x}, {want_y}")

    # Inside the tile's box in tileset.json (also z-up).
    blo, bhi = glbref.tile_box(ts, key)
    if (lo < blo - tol).any() or (hi > bhi + tol).any():
        fail(f"world box {lo.round(3)}..{hi.round(3)} leaves the tileset.json box {blo.round(3)}..{bhi.round(3)}")

    # Shape key "parent": base + delta of the file, on the parent's surface.
    keys = mesh.shape_keys.key_blocks if mesh.shape_keys else []
    names = [k.name for k in keys]
    morph_err = surface_err = float("nan")
    if "parent" not in names:
        fail(f"no shape key 'parent' (shape keys: {names})")
    elif not ref.decodable:
        # EXT_/KHR_meshopt_compression: the reference cannot decode the deltas, so
        # only the key's presence is checked.
        print(f"blender {label} {glbref.name(key)}: {ref.extensions} not decodable here, shape key values unchecked")
    else:
        moved = world_coords(obj, "parent")
        # Blender's vertex order is the file's primitives in order, each in
        # its own order (no merging): rebuild the file's expectation alike.
        want = np.concatenate(
            [
                glbref.to_z_up(p["world"] + (p["world_delta"] if p["world_delta"] is not None else 0.0))
                for p in ref.parts.values()
            ]
        )
        if moved.shape == want.shape:
            morph_err = np.abs(moved - want).max()
            if morph_err > tol:
                fail(f"shape key 'parent' differs from base + delta by {morph_err:.4g} m")
        else:
            fail(f"shape key has {len(moved)} points, the file {len(want)}")
        if parent_key is None:
            base = world_coords(obj)
            if np.abs(moved - base).max() != 0.0:
                fail("the root's shape key moves vertices")
            surface_err = 0.0
        else:
            parent = glbref.Chunk(glbref.chunk_path(tileset, parent_key))
            ns = ref.parts["surface"]["vertices"]
            pts = moved[:ns]  # the surface primitive comes first
            gl = np.stack([pts[:, 0], pts[:, 2], -pts[:, 1]], axis=1)  # back to glTF axes
            # Quantized positions (KHR_mesh_quantization) may each have moved
            # half a step: horizontally (r) and vertically (added to the bound).
            (qh, qv), (ph, pv) = glbref.quantum(ref), glbref.quantum(parent)
            r, bound = (qh + ph) / 2, SURFACE_TOL_M + (qv + pv) / 2
            # Curved: a target on the parent's border edge is a chord point,
            # which f32 may put a rounding outside the parent's plan.
            if curved:
                r = max(r, tol)
            err = glbref.parent_surface_error(gl, parent, r)
            surface_err = err.max()
            if not np.isfinite(surface_err) or surface_err > bound:
                bad = int((err > bound).sum())
                fail(f"{bad} of {len(err)} shape-key points off the parent surface, worst {surface_err:.4g} m")
        if obj.data.shape_keys and obj.data.shape_keys.key_blocks["parent"].value != 0.0:
            fail("shape key 'parent' is not at value 0 (mesh.weights = [0])")

    # Texture bound to the material.
    tex = "untextured"
    if ref.texture is not None:
        image, why = base_colour_image(obj)
        if image is None:
            fail(f"texture not bound: {why}")
            tex = "unbound"
        else:
            size = tuple(image.size)
            tex = f"{size[0]}x{size[1]}"
            if size != tuple(ref.texture):
                fail(f"base colour image is {size}, the tile {ref.texture}")
    print(
        f"blender {label:7} {glbref.name(key):7} verts {nv:6} faces {nf:6} (file {ref.vertices}/{ref.triangles}) "
        f"box {lo.round(2).tolist()}..{hi.round(2).tolist()} box err {box_err:.1e} m  "
        f"shape key 'parent' err {morph_err:.1e} m, on parent surface within {surface_err:.1e} m  texture {tex}"
    )
    return obj


def render(tileset, key, out_png):
    """A small Cycles render of one chunk, textured, from the south-east."""
    empty_scene()
    objs = import_chunk(glbref.chunk_path(tileset, key))
    lo = np.min([world_coords(o).min(axis=0) for o in objs], axis=0)
    hi = np.max([world_coords(o).max(axis=0) for o in objs], axis=0)
    centre, size = (lo + hi) / 2, (hi - lo)
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("cam")
    cam_data.clip_end = 10 * float(size.max())
    cam = bpy.data.objects.new("cam", cam_data)
    scene.collection.objects.link(cam)
    span = float(max(size[0], size[1]))
    cam.location = (centre[0] + 1.0 * span, centre[1] - 1.1 * span, centre[2] + 1.0 * span)
    direction = centre - np.array(cam.location)
    cam.rotation_euler = (
        math.atan2(math.hypot(direction[0], direction[1]), -direction[2]),
        0.0,
        math.atan2(direction[1], direction[0]) - math.pi / 2,
    )
    scene.camera = cam
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (math.radians(40), 0, math.radians(-45))
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("w")
    world.color = (0.6, 0.7, 0.8)
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 8
    scene.render.resolution_x, scene.render.resolution_y = 480, 320
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = os.path.abspath(out_png)
    bpy.ops.render.render(write_still=True)
    print(f"blender render of {glbref.name(key)} → {out_png}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tileset")
    ap.add_argument("--render", help="write a small render of the root chunk here")
    args = ap.parse_args()
    print(f"blender {bpy.app.version_string}, glTF importer {glTF_version()}")
    picks, failures = glbref.check_picks(
        args.tileset, lambda ts, label, key, parent, failures: check_chunk(args.tileset, ts, label, key, parent, failures)
    )
    if args.render:
        try:
            render(args.tileset, picks[0][1], args.render)
        except Exception as e:
            failures.append(f"render: {type(e).__name__}: {e}")
    for f in failures:
        print(f"blender FAIL {f}")
    print(f"blender: {len(picks)} chunks, {len(failures)} failures")
    sys.exit(1 if failures else 0)


def glTF_version():
    import addon_utils

    for mod in addon_utils.modules():
        if mod.__name__.endswith("io_scene_gltf2"):
            return ".".join(map(str, mod.bl_info.get("version", ())))
    return "?"


if __name__ == "__main__":
    main()
