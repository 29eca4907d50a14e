"""The reference the importer checks compare against: a small .glb reader
that shares no code with terrachunk or with any importer (JSON chunk +
binary chunk, accessors decoded with numpy), and the chunk facts the
output contract promises (DESIGN.md): world position = node translation +
POSITION, y-up metres, a "surface" and an optional "skirt" primitive, one
morph target "parent" of y-deltas that puts every vertex on the parent
chunk's surface.

Accessors are decoded for plain and quantized (KHR_mesh_quantization)
buffers; a buffer view compressed with EXT_ or KHR_meshopt_compression
cannot be decoded here, and `Chunk.decodable` says so (its counts still come
from the JSON, which meshopt leaves intact).
"""

import json
import struct

import numpy as np

COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
# Normalised integer → float, glTF 2.0 §3.11 (KHR_mesh_quantization uses it).
NORM = {np.int8: 127.0, np.uint8: 255.0, np.int16: 32767.0, np.uint16: 65535.0}


def read_glb(path):
    """(json dict, binary chunk bytes) of a .glb file."""
    data = open(path, "rb").read()
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != 0x46546C67 or version != 2 or length != len(data):
        raise ValueError(f"{path}: not a glTF 2.0 binary ({len(data)} bytes)")
    jlen, jtype = struct.unpack_from("<II", data, 12)
    assert jtype == 0x4E4F534A, "first chunk is JSON"
    doc = json.loads(data[20 : 20 + jlen])
    off = 20 + jlen
    binary = b""
    if off < len(data):
        blen, btype = struct.unpack_from("<II", data, off)
        assert btype == 0x004E4942, "second chunk is BIN"
        binary = data[off + 8 : off + 8 + blen]
    return doc, binary


class Chunk:
    """One chunk file as the contract describes it, decoded independently."""

    def __init__(self, path):
        self.path = str(path)
        self.doc, self.bin = read_glb(path)
        doc = self.doc
        self.extensions = sorted(doc.get("extensionsUsed", []))
        self.decodable = not any(
            ext in (bv.get("extensions") or {})
            for bv in doc.get("bufferViews", [])
            for ext in ("EXT_meshopt_compression", "KHR_meshopt_compression")
        )
        node = doc["nodes"][doc["scenes"][doc.get("scene", 0)]["nodes"][0]]
        self.node = node
        assert "matrix" not in node and "rotation" not in node, "contract: translation only"
        self.translation = np.array(node.get("translation", [0, 0, 0]), dtype=np.float64)
        self.scale = np.array(node.get("scale", [1, 1, 1]), dtype=np.float64)
        self.extras = (node.get("extras") or {}).get("terrachunk", {})
        mesh = doc["meshes"][node["mesh"]]
        self.mesh = mesh
        self.target_names = (mesh.get("extras") or {}).get("targetNames")
        self.weights = mesh.get("weights")
        self.parts = {}
        for prim in mesh["primitives"]:
            role = (prim.get("extras") or {}).get("role")
            pos = doc["accessors"][prim["attributes"]["POSITION"]]
            idx = doc["accessors"][prim["indices"]]
            part = {
                "vertices": pos["count"],
                "triangles": idx["count"] // 3,
                "mode": prim.get("mode", 4),
                "material": prim.get("material"),
                "acc_min": np.array(pos["min"], dtype=np.float64),
                "acc_max": np.array(pos["max"], dtype=np.float64),
            }
            if self.decodable:
                part["local"] = self.accessor(prim["attributes"]["POSITION"])
                part["indices"] = self.accessor(prim["indices"]).astype(np.int64).reshape(-1, 3)
                targets = prim.get("targets", [])
                part["delta"] = self.accessor(targets[0]["POSITION"]) if targets else None
                part["world"] = part["local"] * self.scale + self.translation
                # A morph delta lives in the mesh's space too: the node's scale applies.
                part["world_delta"] = part["delta"] * self.scale if part["delta"] is not None else None
            self.parts[role] = part
        self.texture = self._texture()

    def accessor(self, i):
        """Accessor `i` as a float64 (or int) numpy array, count × width."""
        acc = self.doc["accessors"][i]
        dtype = np.dtype(COMPONENT[acc["componentType"]]).newbyteorder("<")
        width = WIDTH[acc["type"]]
        count = acc["count"]
        if "bufferView" not in acc:
            out = np.zeros((count, width))
        else:
            bv = self.doc["bufferViews"][acc["bufferView"]]
            start = bv.get("byteOffset", 0) + acc.get("byteOffset", 0)
            stride = bv.get("byteStride") or dtype.itemsize * width
            raw = np.frombuffer(self.bin, dtype=np.uint8, count=stride * (count - 1) + dtype.itemsize * width, offset=start)
            rows = np.lib.stride_tricks.as_strided(raw, shape=(count, dtype.itemsize * width), strides=(stride, 1))
            out = np.ascontiguousarray(rows).view(dtype).reshape(count, width)
            if acc.get("normalized"):
                out = np.maximum(out.astype(np.float64) / NORM[COMPONENT[acc["componentType"]]], -1.0)
        if acc["type"] == "SCALAR":
            return out.reshape(count)
        return out.astype(np.float64) if out.dtype.kind == "f" or acc.get("normalized") else out

    def _texture(self):
        """(width, height) of the base colour image, or None when untextured."""
        prim = self.mesh["primitives"][0]
        if prim.get("material") is None:
            return None
        pbr = self.doc["materials"][prim["material"]].get("pbrMetallicRoughness", {})
        if "baseColorTexture" not in pbr:
            return None
        image = self.doc["images"][self.doc["textures"][pbr["baseColorTexture"]["index"]]["source"]]
        bv = self.doc["bufferViews"][image["bufferView"]]
        data = self.bin[bv.get("byteOffset", 0) : bv.get("byteOffset", 0) + bv["byteLength"]]
        return image_size(data, image.get("mimeType"))

    @property
    def vertices(self):
        return sum(p["vertices"] for p in self.parts.values())

    @property
    def triangles(self):
        return sum(p["triangles"] for p in self.parts.values())

    def world_bounds(self):
        """World (glTF frame) min and max corners over every primitive, from
        the accessors' min/max (the decoded positions when decodable)."""
        lo, hi = [], []
        for p in self.parts.values():
            if "world" in p:
                lo.append(p["world"].min(axis=0))
                hi.append(p["world"].max(axis=0))
            else:
                a = p["acc_min"] * self.scale + self.translation
                b = p["acc_max"] * self.scale + self.translation
                lo.append(np.minimum(a, b))
                hi.append(np.maximum(a, b))
        return np.min(lo, axis=0), np.max(hi, axis=0)


def image_size(data, mime):
    """(width, height) of a PNG or JPEG from its header bytes."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return struct.unpack(">II", data[16:24])
    if data[:2] == b"\xff\xd8":
        i = 2
        while i < len(data):
            marker, seglen = data[i + 1], struct.unpack(">H", data[i + 2 : i + 4])[0]
            if marker in (0xC0, 0xC1, 0xC2):
                h, w = struct.unpack(">HH", data[i + 5 : i + 9])
                return w, h
            i += 2 + seglen
    raise ValueError(f"unknown image type {mime}")


def to_z_up(p):
    """glTF (x, y, z) y-up → (x, −z, y) z-up: Blender's import axes and the
    3D Tiles frame alike."""
    p = np.asarray(p, dtype=np.float64)
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def parent_surface_error(points, parent, r=0.0):
    """For world points (x, y, z) of a child chunk, the vertical distance to
    the parent chunk's surface at (x, z): the parent's surface triangles
    containing (x, z) are searched and the smallest |y − interpolated height|
    over them is kept (a point on a shared edge or a near-vertical sliver may
    lie in several). With `r` > 0 (quantized positions: either file may have
    moved a vertex up to r horizontally), a triangle within r of (x, z)
    counts too, and its height may move by r times its slope. Returns an
    array of distances (inf where no parent triangle holds the point)."""
    surf = parent.parts["surface"]
    tri = surf["world"][surf["indices"]]  # T × 3 × 3
    ax, az = tri[:, 0, 0], tri[:, 0, 2]
    bx, bz = tri[:, 1, 0], tri[:, 1, 2]
    cx, cz = tri[:, 2, 0], tri[:, 2, 2]
    det = (bz - cz) * (ax - cx) + (cx - bx) * (az - cz)
    keep = np.abs(det) > 0
    safe = np.where(keep, det, 1.0)
    # Plane slope |∇h| of each triangle (height = l1·ha + l2·hb + l3·hc).
    ha, hb, hc = tri[:, 0, 1], tri[:, 1, 1], tri[:, 2, 1]
    gx = ((bz - cz) * (ha - hc) + (cz - az) * (hb - hc)) / safe
    gz = ((cx - bx) * (ha - hc) + (ax - cx) * (hb - hc)) / safe
    slope = np.hypot(gx, gz)
    lo = np.minimum(np.minimum(ax, bx), cx), np.minimum(np.minimum(az, bz), cz)
    hi = np.maximum(np.maximum(ax, bx), cx), np.maximum(np.maximum(az, bz), cz)
    out = np.full(len(points), np.inf)
    margin = 1e-3 + r
    for k, (x, y, z) in enumerate(points):
        cand = keep & (lo[0] - margin <= x) & (x <= hi[0] + margin) & (lo[1] - margin <= z) & (z <= hi[1] + margin)
        if not cand.any():
            continue
        d = det[cand]
        l1 = ((bz[cand] - cz[cand]) * (x - cx[cand]) + (cx[cand] - bx[cand]) * (z - cz[cand])) / d
        l2 = ((cz[cand] - az[cand]) * (x - cx[cand]) + (ax[cand] - cx[cand]) * (z - cz[cand])) / d
        l3 = 1.0 - l1 - l2
        inside = (l1 >= -1e-6) & (l2 >= -1e-6) & (l3 >= -1e-6)
        if r > 0:
            # Horizontal distance to each candidate triangle (0 inside).
            t = tri[cand]
            dist = np.where(inside, 0.0, np.inf)
            for i, j in ((0, 1), (1, 2), (2, 0)):
                px, pz = t[:, i, 0], t[:, i, 2]
                ex, ez = t[:, j, 0] - px, t[:, j, 2] - pz
                u = np.clip(((x - px) * ex + (z - pz) * ez) / np.maximum(ex * ex + ez * ez, 1e-300), 0.0, 1.0)
                dist = np.minimum(dist, np.hypot(x - px - u * ex, z - pz - u * ez))
            near = dist <= r
        else:
            near = inside
        if not near.any():
            continue
        t = tri[cand][near]
        h = l1[near] * t[:, 0, 1] + l2[near] * t[:, 1, 1] + l3[near] * t[:, 2, 1]
        out[k] = np.min(np.maximum(np.abs(h - y) - r * slope[cand][near], 0.0))
    return out


def quantum(chunk):
    """(horizontal, vertical) size of one POSITION step, metres: 0 for f32
    positions, the node scale for integer ones (KHR_mesh_quantization,
    unnormalised), scale / (2^bits − 1) for normalised ones."""
    acc = chunk.doc["accessors"][chunk.mesh["primitives"][0]["attributes"]["POSITION"]]
    ct = acc["componentType"]
    if ct == 5126:
        return 0.0, 0.0
    step = chunk.scale / (NORM[COMPONENT[ct]] if acc.get("normalized") else 1.0)
    return float(max(step[0], step[2])), float(step[1])


def load_tileset(tileset_dir):
    """tileset.json with each external tileset (a tile whose content is a
    .json beside it) read in place of the tile that refers to it."""

    def inline(t):
        uri = (t.get("content") or {}).get("uri", "")
        if uri.endswith(".json"):
            return inline(json.load(open(f"{tileset_dir}/{uri}"))["root"])
        if "children" in t:
            t["children"] = [inline(c) for c in t["children"]]
        return t

    ts = json.load(open(f"{tileset_dir}/tileset.json"))
    ts["root"] = inline(ts["root"])
    return ts


def pick_chunks(tileset_dir):
    """The chunks the checks import: the root, a skirted mid-level chunk and a
    leaf at the deepest level (each with its parent, for the morph check),
    as (label, key, parent key or None). Deterministic: the first in key
    order that fits."""
    ts = load_tileset(tileset_dir)
    tiles, parent = {}, {}

    def walk(t, up):
        k = None
        if "content" in t:
            e = t["extras"]["terrachunk"]
            k = (e["level"], e["x"], e["y"])
            tiles[k] = t
            parent[k] = up
        for c in t.get("children", []):
            walk(c, k if k is not None else up)

    walk(ts["root"], None)
    keys = sorted(tiles)
    deepest = max(k[0] for k in keys)
    root = keys[0]
    leaf = next(k for k in keys if k[0] == deepest)
    mid_level = max(1, deepest // 2) if deepest > 1 else deepest
    skirted = None
    for k in keys:
        if k[0] == mid_level and k != leaf:
            c = Chunk(chunk_path(tileset_dir, k))
            if "skirt" in c.parts:
                skirted = k
                break
    chosen = [("root", root), ("skirted", skirted), ("leaf", leaf)]
    return ts, [(label, k, parent[k]) for label, k in chosen if k is not None]


def check_picks(tileset_dir, check):
    """Runs `check(ts, label, key, parent, failures)` on every chunk
    `pick_chunks` chooses; an exception from the reader under test is a
    finding, not a crash. Returns (picks, failures)."""
    ts, picks = pick_chunks(tileset_dir)
    failures = []
    for label, key, parent in picks:
        try:
            check(ts, label, key, parent, failures)
        except Exception as e:
            failures.append(f"{label} {name(key)}: {type(e).__name__}: {e}")
    return picks, failures


def tile_box(ts, key):
    """(min, max) corners, z-up tileset frame, of the tile `key`'s
    boundingVolume.box in tileset.json (an axis-aligned box, as written)."""

    def find(t):
        e = (t.get("extras") or {}).get("terrachunk")
        if e and (e["level"], e["x"], e["y"]) == tuple(key):
            return t
        for c in t.get("children", []):
            f = find(c)
            if f is not None:
                return f
        return None

    b = np.array(find(ts["root"])["boundingVolume"]["box"], dtype=np.float64)
    half = np.abs(b[3:6]) + np.abs(b[6:9]) + np.abs(b[9:12])
    return b[:3] - half, b[:3] + half


def footprint_xz(ref):
    """The chunk's footprint from its node extras, glTF frame: (x0, x1), (z0, z1) metres."""
    fp, sp = ref.extras["footprint"], ref.extras["spacing_m"]
    return (fp["x0"] * sp[0], fp["x1"] * sp[0]), (fp["z0"] * sp[1], fp["z1"] * sp[1])


def chunk_path(tileset_dir, key):
    return f"{tileset_dir}/tiles/{key[0]}/{key[1]}/{key[2]}.glb"


def name(key):
    return "/".join(map(str, key))


def expect_u32_root(tileset_dir):
    """Exit status 0 when the root chunk's surface holds more than 65 535
    vertices and its triangles are u32 (the fixture the importers must open
    with u32 indices); prints what it found."""
    root = pick_chunks(tileset_dir)[1][0][1]
    c = Chunk(chunk_path(tileset_dir, root))
    prim = next(p for p in c.mesh["primitives"] if (p.get("extras") or {}).get("role") == "surface")
    ct = c.doc["accessors"][prim["indices"]]["componentType"]
    vertices = c.parts["surface"]["vertices"]
    print(f"glbref: root {name(root)}: {vertices} surface vertices, index componentType {ct}")
    return 0 if vertices > 65535 and ct == 5125 else 1


if __name__ == "__main__":
    import sys

    if len(sys.argv) == 3 and sys.argv[1] == "--expect-u32-root":
        sys.exit(expect_u32_root(sys.argv[2]))
    sys.exit("usage: glbref.py --expect-u32-root TILESET_DIR")
