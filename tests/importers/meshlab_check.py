"""MeshLab (pymeshlab) on terrachunk chunks (DESIGN.md promise 4).

    python meshlab_check.py TILESET_DIR

For the chunks glbref.pick_chunks chooses (root, a skirted mid-level chunk,
a leaf), loaded with MeshLab's glTF reader:
- vertex and face counts equal the file's (glbref's independent reader);
- the world bounding box (the node translation, which MeshLab keeps as the
  layer's matrix, applied; MeshLab stays y-up) equals the file's, within
  f32 rounding, and the faces are the file's triangles in the file's order;
- the texture arrives (wedge texture coordinates and an image of the
  tile's size);
- the surface alone (the skirt's faces, which follow it, deleted) is a
  2-manifold disc with one boundary, no unreferenced, duplicate or
  degenerate (zero-area) faces and no duplicate vertices, measured with
  MeshLab's own topological measures and cleaning filters; on a grid with
  nodata the disc may have holes and several components, which is reported
  but not failed.
Prints one line per chunk; exits 1 on any mismatch.
"""

import argparse
import importlib.metadata
import os
import sys

import numpy as np
import pymeshlab

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import glbref  # noqa: E402


def pos_tol(extent_m):
    """1 mm plus two f32 units at the chunk's size (see blender_check)."""
    return 1e-3 + 2.0 * np.spacing(np.float32(extent_m)).item()


def load(path):
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(path)
    return ms


def check_chunk(tileset, ts, label, key, has_nodata, failures):
    path = glbref.chunk_path(tileset, key)
    ref = glbref.Chunk(path)
    fail = lambda msg: failures.append(f"{label} {glbref.name(key)}: {msg}")  # noqa: E731
    ms = load(path)
    if ms.mesh_number() != 1:
        fail(f"MeshLab made {ms.mesh_number()} layers, expected 1")
    m = ms.current_mesh()
    nv, nf = m.vertex_number(), m.face_number()
    if (nv, nf) != (ref.vertices, ref.triangles):
        fail(f"MeshLab has {nv} vertices / {nf} faces, the file {ref.vertices} / {ref.triangles}")

    world = m.transformed_vertex_matrix()
    lo, hi = world.min(axis=0), world.max(axis=0)
    rlo, rhi = ref.world_bounds()
    tol = pos_tol(float(np.abs(rhi - rlo).max()))
    box_err = max(np.abs(lo - rlo).max(), np.abs(hi - rhi).max())
    if box_err > tol:
        fail(f"world box {lo.round(3)}..{hi.round(3)} differs from the file's {rlo.round(3)}..{rhi.round(3)}")

    # x/z extent = the footprint in the node extras (in the planar frame: a
    # curved one turns and bends it onto the Earth); inside tileset.json's box.
    (x0, x1), (z0, z1) = glbref.footprint_xz(ref)
    fp_err = max(abs(lo[0] - x0), abs(hi[0] - x1), abs(lo[2] - z0), abs(hi[2] - z1))
    curved = (ts["extras"]["terrachunk"].get("placement") or {}).get("frame") == "curved"
    if fp_err > tol and not curved:
        fail(f"x/z extent {lo[[0, 2]].round(3)}..{hi[[0, 2]].round(3)} is not the footprint {(x0, x1)}, {(z0, z1)}")
    blo, bhi = glbref.tile_box(ts, key)
    zlo, zhi = glbref.to_z_up(lo), glbref.to_z_up(hi)
    zlo, zhi = np.minimum(zlo, zhi), np.maximum(zlo, zhi)
    if (zlo < blo - tol).any() or (zhi > bhi + tol).any():
        fail(f"world box leaves the tileset.json box {blo.round(3)}..{bhi.round(3)} (z-up)")

    # The same triangles in the same order: corner positions face by face.
    face_err = float("nan")
    if ref.decodable and nf == ref.triangles:
        mine = world[m.face_matrix()]
        theirs = np.concatenate([p["world"][p["indices"]] for p in ref.parts.values()])
        face_err = np.abs(mine - theirs).max()
        if face_err > tol:
            fail(f"faces differ from the file's triangles by up to {face_err:.3g} m")

    tex = "untextured"
    if ref.texture is not None:
        textures = m.textures()
        if not m.has_wedge_tex_coord() or not textures:
            fail("texture coordinates or image missing")
            tex = "missing"
        else:
            img = next(iter(textures.values()))
            size = (img.width(), img.height())
            tex = f"{size[0]}x{size[1]}"
            if size != tuple(ref.texture):
                fail(f"texture is {size}, the tile {ref.texture}")

    # The surface alone: its faces come first in the file and in MeshLab.
    ns = ref.parts["surface"]["triangles"]
    if nf > ns:
        ms.compute_selection_by_condition_per_face(condselect=f"fi >= {ns}")
        ms.meshing_remove_selected_faces()
    ms.meshing_remove_unreferenced_vertices()
    s = ms.current_mesh()
    topo = ms.get_topological_measures()
    sv, sf = s.vertex_number(), s.face_number()
    if (sv, sf) != (ref.parts["surface"]["vertices"], ns):
        fail(f"surface alone is {sv} vertices / {sf} faces, the file's {ref.parts['surface']['vertices']} / {ns}")
    removed = {}
    for name, filt in [
        ("duplicate faces", "meshing_remove_duplicate_faces"),
        ("zero-area faces", "meshing_remove_null_faces"),
        ("duplicate vertices", "meshing_remove_duplicate_vertices"),
    ]:
        before = (ms.current_mesh().vertex_number(), ms.current_mesh().face_number())
        getattr(ms, filt)()
        after = (ms.current_mesh().vertex_number(), ms.current_mesh().face_number())
        removed[name] = (before[0] - after[0]) if "vertices" in name else (before[1] - after[1])
    manifold = topo["non_two_manifold_edges"] == 0 and topo["non_two_manifold_vertices"] == 0
    if not manifold:
        fail(
            f"surface not 2-manifold: {topo['non_two_manifold_edges']} edges, "
            f"{topo['non_two_manifold_vertices']} vertices"
        )
    if topo["unreferenced_vertices"]:
        fail(f"{topo['unreferenced_vertices']} unreferenced vertices")
    for what, n in removed.items():
        if n:
            fail(f"MeshLab removed {n} {what} from the surface")
    disc = topo["connected_components_number"] == 1 and topo["number_holes"] == 1 and topo["genus"] == 0
    if not disc and not has_nodata:
        fail(
            f"surface is not one disc: {topo['connected_components_number']} components, "
            f"{topo['number_holes']} boundaries, genus {topo['genus']}"
        )
    print(
        f"meshlab {label:7} {glbref.name(key):7} verts {nv:6} faces {nf:6} (file {ref.vertices}/{ref.triangles}) "
        f"box {lo.round(2).tolist()}..{hi.round(2).tolist()} box err {box_err:.1e} m face err {face_err:.1e} m  "
        f"texture {tex}  surface: {sf} faces, 2-manifold {manifold}, components "
        f"{topo['connected_components_number']}, boundaries {topo['number_holes']}, genus {topo['genus']}, "
        f"removed dup faces/zero-area/dup verts {removed['duplicate faces']}/{removed['zero-area faces']}/"
        f"{removed['duplicate vertices']}"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tileset")
    ap.add_argument("--has-nodata", action="store_true", help="the DEM has voids: holes are not failures")
    args = ap.parse_args()
    print(f"pymeshlab {importlib.metadata.version('pymeshlab')}")
    picks, failures = glbref.check_picks(
        args.tileset, lambda ts, label, key, _parent, failures: check_chunk(args.tileset, ts, label, key, args.has_nodata, failures)
    )
    for f in failures:
        print(f"meshlab FAIL {f}")
    print(f"meshlab: {len(picks)} chunks, {len(failures)} failures")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
