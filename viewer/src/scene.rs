//! What the viewer reads from disk: `tileset.json` (the chunk tree, through
//! `terrachunk::lod`) and one `.glb` per chunk, decoded into the CPU-side
//! mesh the GPU cache uploads. Only the output contract of DESIGN.md is
//! assumed: chunk-local f32 positions plus an f64 node translation, y-up,
//! primitives tagged `extras.role` "surface"/"skirt", one "parent" morph
//! target with POSITION deltas, an optional baseColor texture and an
//! optional tangent-space `normalTexture` (`--normal-map` tilesets).
//!
//! Normals morph with the shape: each vertex also carries its parent
//! chunk's normal at its (x, z), interpolated inside the parent triangle it
//! lies in ([`set_parent_normals`]). A child's triangles refine its
//! parent's, so at morph weight 1 the interpolated normal equals the
//! parent's at every pixel, and a split changes no shading.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use terrachunk::lod::LodTree;
use terrachunk::output::gltf::{Imported, import};

/// A tileset opened for viewing.
pub struct Tileset {
    /// The tileset directory.
    pub dir: PathBuf,
    /// The chunk tree.
    pub tree: LodTree,
    /// Samples per row and rows of the source grid.
    pub grid: [u32; 2],
    /// `[s_x, s_z]`, metres.
    pub spacing_m: [f64; 2],
    /// The largest τ the textures were sized for (`extras.terrachunk.tau_max_px`).
    pub tau_max_px: Option<f64>,
    /// The generated hillshade's sun, `[azimuth° clockwise from north,
    /// elevation°]`, when the tileset has one.
    pub sun_deg: Option<[f64; 2]>,
    /// World box of the whole terrain (glTF frame), min and max.
    pub bounds: ([f64; 3], [f64; 3]),
}

impl Tileset {
    /// Reads `DIR/tileset.json`.
    pub fn open(dir: &Path) -> Result<Self> {
        let path = dir.join("tileset.json");
        // With its external tilesets in place, read as `verify` reads them.
        let json = terrachunk::verify::read_tileset(dir)?;
        let tree = LodTree::from_tileset_json(&json).with_context(|| path.display().to_string())?;
        let ex = &json["extras"]["terrachunk"];
        let grid =
            [ex["grid"]["width"].as_u64().unwrap_or(0) as u32, ex["grid"]["height"].as_u64().unwrap_or(0) as u32];
        let spacing_m = [ex["spacing_m"][0].as_f64().unwrap_or(1.0), ex["spacing_m"][1].as_f64().unwrap_or(1.0)];
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for &r in &tree.roots {
            for a in 0..3 {
                lo[a] = lo[a].min(tree.nodes[r].min[a]);
                hi[a] = hi[a].max(tree.nodes[r].max[a]);
            }
        }
        let tau_max_px = ex["tau_max_px"].as_f64().filter(|t| t.is_finite() && *t > 0.0);
        let hs = &ex["texture"]["hillshade"];
        let sun_deg = hs["sun_azimuth_deg"].as_f64().zip(hs["sun_elevation_deg"].as_f64()).map(|(a, e)| [a, e]);
        let mut folders = std::collections::HashSet::new();
        for n in &tree.nodes {
            content_path(dir, &n.uri).with_context(|| path.display().to_string())?;
            // Each folder on the way is a real one: no link out of the tileset.
            let mut at = dir.to_path_buf();
            for part in Path::new(&n.uri).parent().into_iter().flat_map(Path::components) {
                at.push(part);
                if folders.insert(at.clone()) {
                    let meta =
                        std::fs::symlink_metadata(&at).with_context(|| format!("{}: cannot read", at.display()))?;
                    if !meta.file_type().is_dir() {
                        bail!("{}: not a folder (a link?); the viewer reads only inside the tileset", at.display());
                    }
                }
            }
        }
        Ok(Tileset { dir: dir.to_path_buf(), tree, grid, spacing_m, tau_max_px, sun_deg, bounds: (lo, hi) })
    }

    /// Path of a node's .glb (checked to stay inside the tileset when opened).
    pub fn chunk_path(&self, node: usize) -> PathBuf {
        self.dir.join(&self.tree.nodes[node].uri)
    }
}

/// A content URI as a path inside `dir`: relative, plain names only (no
/// `..`, no root, no drive), so a tileset cannot point the viewer outside
/// itself.
fn content_path(dir: &Path, uri: &str) -> Result<PathBuf> {
    let rel = Path::new(uri);
    if uri.is_empty() || !rel.components().all(|c| matches!(c, std::path::Component::Normal(_))) {
        bail!("content uri {uri:?} is not a plain path inside the tileset");
    }
    Ok(dir.join(rel))
}

/// Reads a chunk file as `verify` reads one ([`terrachunk::verify::read_tile`]):
/// a regular file (not a link out of the tileset), of bounded size, and a
/// `.glb` exactly as long as its header says.
fn read_chunk_file(path: &Path) -> Result<Vec<u8>> {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name().and_then(|n| n.to_str())) else {
        bail!("{}: not a chunk file's path", path.display());
    };
    Ok(terrachunk::verify::read_tile(dir, name)?)
}

/// One vertex as the GPU sees it (68 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    /// Chunk-local position, metres.
    pub pos: [f32; 3],
    /// Unit normal.
    pub normal: [f32; 3],
    /// TEXCOORD_0 (0 without a texture).
    pub uv: [f32; 2],
    /// Morph delta toward the parent surface, metres (y only in the flat
    /// frame; a 3-vector in the curved one).
    pub morph: [f32; 3],
    /// 0 on the surface, 1 on a skirt.
    pub role: f32,
    /// The parent surface's normal at this vertex's (x, z), not normalised
    /// (linear inside each parent triangle, so the fragment's interpolation
    /// matches the parent's); the vertex's own normal for a root or skirt.
    pub parent_normal: [f32; 3],
    /// TEXCOORD_1 (the normal map's, when its size differs from the colour's).
    pub uv1: [f32; 2],
}

/// An RGBA8 image with its mip chain (level 0 first).
pub struct Mips {
    /// `(width, height, rgba bytes)` per level.
    pub levels: Vec<(u32, u32, Vec<u8>)>,
}

/// A decoded chunk, ready to upload.
pub struct ChunkMesh {
    /// Node translation (f64): world = translation + local position.
    pub translation: [f64; 3],
    /// Surface vertices, then skirt vertices.
    pub vertices: Vec<Vertex>,
    /// Triangle list: surface triangles in `..surface_indices`, skirts after.
    pub indices: Vec<u32>,
    /// Index count of the surface part.
    pub surface_indices: u32,
    /// Line list of the unique surface and skirt edges (wireframe).
    pub edges: Vec<u32>,
    /// Material base colour (multiplies the texture).
    pub base_colour: [f32; 4],
    /// The baseColor texture, if any.
    pub texture: Option<Mips>,
    /// The tangent-space normal map (T = +x, B = −z, N = +y), if any.
    pub normal_map: Option<Mips>,
    /// Whether the normal map reads TEXCOORD_1 (else TEXCOORD_0).
    pub normal_uv1: bool,
}

impl ChunkMesh {
    /// Bytes this chunk takes on the GPU (vertex, index and line buffers and
    /// the texture with its mips): what the memory budget counts.
    pub fn gpu_bytes(&self) -> u64 {
        let tex: usize = [&self.texture, &self.normal_map]
            .iter()
            .map(|t| t.as_ref().map_or(0, |m| m.levels.iter().map(|l| l.2.len()).sum::<usize>()))
            .sum();
        (self.vertices.len() * std::mem::size_of::<Vertex>() + (self.indices.len() + self.edges.len()) * 4 + tex) as u64
    }

    /// Surface triangles.
    pub fn surface_triangles(&self) -> u32 {
        self.surface_indices / 3
    }
}

/// Reads and decodes one chunk file.
pub fn load_chunk(path: &Path) -> Result<ChunkMesh> {
    let bytes = read_chunk_file(path)?;
    decode_chunk(&bytes).with_context(|| path.display().to_string())
}

/// Reads and decodes one chunk file and gives each surface vertex its
/// parent's normal, from the parent's file (`parent`; none for a root).
pub fn load_chunk_under(path: &Path, parent: Option<&Path>) -> Result<ChunkMesh> {
    let mut mesh = load_chunk(path)?;
    if let Some(p) = parent {
        let pm = load_chunk(p)?;
        set_parent_normals(&mut mesh, &pm);
    }
    Ok(mesh)
}

/// Sets each surface vertex's `parent_normal` to the parent surface's
/// normal interpolated at its (x, z): the parent's vertex normals, linear
/// inside the parent triangle the vertex lies in (the one it lies deepest
/// in, where it is on an edge). Where no parent triangle is found (a hole
/// in the parent) the vertex keeps its own normal.
pub fn set_parent_normals(child: &mut ChunkMesh, parent: &ChunkMesh) {
    let tris: Vec<[usize; 3]> = parent.indices[..parent.surface_indices as usize]
        .chunks_exact(3)
        .map(|t| [t[0] as usize, t[1] as usize, t[2] as usize])
        .collect();
    if tris.is_empty() {
        return;
    }
    // Parent vertices in the child's frame, f64: (x, z) and normal.
    let off = [0, 2].map(|a| parent.translation[a] - child.translation[a]);
    let xz: Vec<[f64; 2]> =
        parent.vertices.iter().map(|v| [f64::from(v.pos[0]) + off[0], f64::from(v.pos[2]) + off[1]]).collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for t in &tris {
        for &i in t {
            for a in 0..2 {
                lo[a] = lo[a].min(xz[i][a]);
                hi[a] = hi[a].max(xz[i][a]);
            }
        }
    }
    // A bucket grid of about one triangle per cell.
    let side = ((tris.len() as f64).sqrt().ceil() as usize).clamp(1, 256);
    let cell = [0, 1].map(|a| ((hi[a] - lo[a]) / side as f64).max(1e-9));
    let at = |p: [f64; 2], a: usize| (((p[a] - lo[a]) / cell[a]).floor().max(0.0) as usize).min(side - 1);
    let mut buckets = vec![Vec::<u32>::new(); side * side];
    for (k, t) in tris.iter().enumerate() {
        let (mut b0, mut b1) = ([usize::MAX; 2], [0usize; 2]);
        for &i in t {
            for a in 0..2 {
                b0[a] = b0[a].min(at(xz[i], a));
                b1[a] = b1[a].max(at(xz[i], a));
            }
        }
        for r in b0[1]..=b1[1] {
            for c in b0[0]..=b1[0] {
                buckets[r * side + c].push(k as u32);
            }
        }
    }
    for v in child.vertices.iter_mut().filter(|v| v.role == 0.0) {
        // Where its target lies on the parent (the curved frame's deltas
        // move it sideways too).
        let p = [f64::from(v.pos[0] + v.morph[0]), f64::from(v.pos[2] + v.morph[2])];
        let mut best: Option<(f64, [f64; 3], [usize; 3])> = None;
        for &k in &buckets[at(p, 1) * side + at(p, 0)] {
            let t = tris[k as usize];
            let (a, b, c) = (xz[t[0]], xz[t[1]], xz[t[2]]);
            let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
            if det.abs() < 1e-18 {
                continue;
            }
            let l1 = ((p[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (p[1] - a[1])) / det;
            let l2 = ((b[0] - a[0]) * (p[1] - a[1]) - (p[0] - a[0]) * (b[1] - a[1])) / det;
            let l = [1.0 - l1 - l2, l1, l2];
            let inside = l[0].min(l[1]).min(l[2]);
            if best.is_none_or(|b| inside > b.0) {
                best = Some((inside, l, t));
            }
        }
        // Within f32 rounding of a triangle (a relative 1e-5 of its size).
        if let Some((inside, l, t)) = best
            && inside > -1e-5
        {
            let n = [0, 1, 2].map(|a| (0..3).map(|k| l[k] * f64::from(parent.vertices[t[k]].normal[a])).sum::<f64>());
            v.parent_normal = n.map(|c| c as f32);
        }
    }
}

/// Decodes a chunk from .glb bytes. A `--compress quantize`, `meshopt` or
/// `meshopt-v1` chunk is first turned into plain f32 glTF by the library's
/// own decoder (`terrachunk::output::compress::decompress`: the node scale
/// folded into the positions and morph deltas, the meshopt streams
/// decoded), which the `gltf` crate reads.
pub fn decode_chunk(bytes: &[u8]) -> Result<ChunkMesh> {
    let plain = terrachunk::output::compress::decompress(bytes).map_err(anyhow::Error::msg)?;
    let bytes = plain.as_ref().map_or(bytes, |d| d.glb.as_slice());
    let Imported { doc, buffers, images, json } = import(bytes).map_err(anyhow::Error::msg)?;
    let Some(node) = doc.nodes().next() else { bail!("no node") };
    let Some(mesh) = node.mesh() else { bail!("the node has no mesh") };
    // f64 translation from the JSON itself: `gltf` hands it over as f32.
    let t = &json["nodes"][node.index()]["translation"];
    let translation = [0, 1, 2].map(|a| t[a].as_f64().unwrap_or(0.0));
    let mut out = ChunkMesh {
        translation,
        vertices: Vec::new(),
        indices: Vec::new(),
        surface_indices: 0,
        edges: Vec::new(),
        base_colour: [1.0; 4],
        texture: None,
        normal_map: None,
        normal_uv1: false,
    };
    let mut prims: Vec<(bool, gltf::Primitive)> = mesh
        .primitives()
        .map(|p| {
            let skirt = p.extras().as_ref().is_some_and(|e| e.get().contains("\"skirt\""));
            (skirt, p)
        })
        .collect();
    prims.sort_by_key(|p| p.0);
    for (skirt, prim) in prims {
        let reader = prim.reader(|b| Some(&buffers[b.index()]));
        let pos: Vec<[f32; 3]> = reader.read_positions().context("a primitive without POSITION")?.collect();
        let nrm: Vec<[f32; 3]> =
            reader.read_normals().map(|n| n.collect()).unwrap_or_else(|| vec![[0.0, 1.0, 0.0]; pos.len()]);
        let uv: Vec<[f32; 2]> =
            reader.read_tex_coords(0).map(|t| t.into_f32().collect()).unwrap_or_else(|| vec![[0.0; 2]; pos.len()]);
        let uv1: Vec<[f32; 2]> =
            reader.read_tex_coords(1).map(|t| t.into_f32().collect()).unwrap_or_else(|| uv.clone());
        let dy: Vec<[f32; 3]> = match reader.read_morph_targets().next() {
            Some((Some(d), _, _)) => d.collect(),
            _ => vec![[0.0; 3]; pos.len()],
        };
        let base = out.vertices.len() as u32;
        let role = if skirt { 1.0 } else { 0.0 };
        if nrm.len() != pos.len() || uv.len() != pos.len() || uv1.len() != pos.len() || dy.len() != pos.len() {
            bail!("a primitive's attributes differ in length from its {} positions", pos.len());
        }
        for (i, &p) in pos.iter().enumerate() {
            let normal = nrm[i];
            out.vertices.push(Vertex {
                pos: p,
                normal,
                uv: uv[i],
                morph: dy[i],
                role,
                parent_normal: normal,
                uv1: uv1[i],
            });
        }
        let idx: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..pos.len() as u32).collect(),
        };
        if let Some(&i) = idx.iter().find(|&&i| i as usize >= pos.len()) {
            bail!("index {i} past the primitive's {} vertices", pos.len());
        }
        let idx: Vec<u32> = idx.into_iter().map(|i| i + base).collect();
        out.indices.extend_from_slice(&idx);
        if !skirt {
            out.surface_indices = out.indices.len() as u32;
            let pbr = prim.material().pbr_metallic_roughness();
            out.base_colour = pbr.base_color_factor();
            if let Some(info) = pbr.base_color_texture() {
                let img = &images[info.texture().source().index()];
                out.texture = Some(mips(rgba(img)?));
            }
            if let Some(info) = prim.material().normal_texture() {
                let img = &images[info.texture().source().index()];
                out.normal_map = Some(mips(rgba(img)?));
                out.normal_uv1 = info.tex_coord() == 1;
            }
        }
    }
    out.edges = unique_edges(&out.indices);
    Ok(out)
}

fn rgba(img: &gltf::image::Data) -> Result<(u32, u32, Vec<u8>)> {
    use gltf::image::Format;
    let px = match img.format {
        Format::R8G8B8A8 => img.pixels.clone(),
        Format::R8G8B8 => img.pixels.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect(),
        Format::R8 => img.pixels.iter().flat_map(|&g| [g, g, g, 255]).collect(),
        Format::R8G8 => img.pixels.chunks_exact(2).flat_map(|p| [p[0], p[0], p[0], p[1]]).collect(),
        f => bail!("texture format {f:?} is not supported"),
    };
    Ok((img.width, img.height, px))
}

/// A 2×2 box-filtered mip chain down to 1×1 (the files ask for mipmapping).
fn mips(level0: (u32, u32, Vec<u8>)) -> Mips {
    let mut levels = vec![level0];
    loop {
        let (w, h, px) = levels.last().expect("level 0");
        if *w == 1 && *h == 1 {
            break;
        }
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        let mut out = vec![0u8; (nw * nh * 4) as usize];
        for y in 0..nh {
            for x in 0..nw {
                for c in 0..4 {
                    let mut s = 0u32;
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (sx, sy) = ((2 * x + dx).min(w - 1), (2 * y + dy).min(h - 1));
                        s += u32::from(px[((sy * w + sx) * 4 + c) as usize]);
                    }
                    out[((y * nw + x) * 4 + c) as usize] = ((s + 2) / 4) as u8;
                }
            }
        }
        levels.push((nw, nh, out));
    }
    Mips { levels }
}

/// Each triangle edge once, as a line list.
fn unique_edges(indices: &[u32]) -> Vec<u32> {
    let mut e: Vec<(u32, u32)> = indices
        .chunks_exact(3)
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    e.sort_unstable();
    e.dedup();
    e.into_iter().flat_map(|(a, b)| [a, b]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrachunk::config::{Compress, Config, Frame};
    use terrachunk::pipeline::{BuildOptions, build};
    use terrachunk::texture::TextureSource;

    /// The distinct world positions (f64 from the f64 translation and the
    /// f32 local position) of a chunk's surface triangles, sorted.
    fn surface_points(m: &ChunkMesh) -> Vec<[u64; 3]> {
        let mut v: Vec<[u64; 3]> = m.indices[..m.surface_indices as usize]
            .iter()
            .map(|&i| {
                let p = m.vertices[i as usize].pos;
                [0, 1, 2].map(|a| (m.translation[a] + f64::from(p[a])).to_bits())
            })
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    /// The viewer opens every `--compress` mode: quantized and meshopt
    /// chunks go through the library's decoder first (before, the `gltf`
    /// crate refused their required extensions and nothing was drawn).
    /// `quantize` and `meshopt-v1` mesh alike, so each chunk loads as the
    /// same surface from both (meshopt-v1's wide chunks hold EXPONENTIAL
    /// positions, its narrow ones u16), with its texture and its skirt.
    #[test]
    fn every_compress_mode_loads_and_meshopt_v1_as_the_same_surface_as_quantize() {
        let tmp = tempfile::tempdir().unwrap();
        let dem = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/mount_st_helens_30m.tif");
        let out = |compress: Compress| {
            let dir = tmp.path().join(format!("{compress:?}"));
            build(&BuildOptions {
                inputs: vec![dem.clone()],
                out: dir.clone(),
                force: false,
                config: Config { max_error_m: 2.0, compress, frame: Frame::Flat, ..Config::default() },
                texture: TextureSource::Generated,
                progress: false,
                geoid: None,
            })
            .unwrap();
            Tileset::open(&dir).unwrap()
        };
        let (plain, q, v1) = (out(Compress::None), out(Compress::Quantize), out(Compress::MeshoptV1));
        assert_eq!(q.tree.nodes.len(), v1.tree.nodes.len());
        for n in 0..q.tree.nodes.len() {
            let (a, b) = (load_chunk(&q.chunk_path(n)).unwrap(), load_chunk(&v1.chunk_path(n)).unwrap());
            let uri = &q.tree.nodes[n].uri;
            assert_eq!(a.surface_triangles(), b.surface_triangles(), "{uri}");
            assert!(a.surface_triangles() > 0 && a.indices.len() > a.surface_indices as usize, "{uri}: no skirt");
            assert!(surface_points(&a) == surface_points(&b), "{uri}: meshopt-v1 loads another surface");
            assert!(a.texture.is_some() && b.texture.is_some(), "{uri}");
        }
        // The f32 tileset's chunks too, and the quantized ones lie where
        // they do (the meshes differ: quantized output meshes each triangle
        // to δ less its corners' rounding).
        for n in 0..plain.tree.nodes.len() {
            let m = load_chunk(&plain.chunk_path(n)).unwrap();
            let Some(k) = q.tree.nodes.iter().position(|o| o.key == plain.tree.nodes[n].key) else { continue };
            let q = load_chunk(&q.chunk_path(k)).unwrap();
            let bounds = |m: &ChunkMesh| {
                let p = surface_points(m);
                [0, 1, 2].map(|a| {
                    let v = p.iter().map(|q| f64::from_bits(q[a]));
                    (v.clone().fold(f64::INFINITY, f64::min), v.fold(f64::NEG_INFINITY, f64::max))
                })
            };
            for (a, (lo, hi)) in bounds(&m).into_iter().zip(bounds(&q)).enumerate() {
                assert!((lo.0 - hi.0).abs() < 0.5 && (lo.1 - hi.1).abs() < 2.5, "axis {a}: {lo:?} against {hi:?}");
            }
        }
    }

    /// A curved tileset (Mount St Helens at 2 m, where a flat frame would
    /// miss the Earth by 5.7 m) loads with 3-vector morph deltas, and every
    /// surface vertex of every child, moved by its delta as the shader
    /// moves it at w = 1, lands on its parent's surface as loaded.
    #[test]
    fn a_curved_tileset_morphs_each_child_onto_its_parent() {
        let tmp = tempfile::tempdir().unwrap();
        let dem = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/mount_st_helens_30m.tif");
        let dir = tmp.path().join("out");
        build(&BuildOptions {
            inputs: vec![dem],
            out: dir.clone(),
            force: false,
            config: Config { max_error_m: 2.0, ..Config::default() },
            texture: TextureSource::None,
            progress: false,
            geoid: None,
        })
        .unwrap();
        let index: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("tileset.json")).unwrap()).unwrap();
        assert_eq!(index["extras"]["terrachunk"]["placement"]["frame"], "curved");
        let ts = Tileset::open(&dir).unwrap();
        let (mut sideways, mut checked) = (0.0f32, 0);
        // The first children of each level (a brute-force search per vertex).
        let mut seen = std::collections::BTreeMap::new();
        for (n, node) in ts.tree.nodes.iter().enumerate() {
            let Some(p) = node.parent else { continue };
            if *seen.entry(node.key.level).and_modify(|k| *k += 1).or_insert(1) > 2 {
                continue;
            }
            let (child, parent) = (load_chunk(&ts.chunk_path(n)).unwrap(), load_chunk(&ts.chunk_path(p)).unwrap());
            let world = |m: &ChunkMesh, i: u32, morph: bool| {
                let v = &m.vertices[i as usize];
                let d = if morph { v.morph } else { [0.0; 3] };
                [0, 1, 2].map(|a| m.translation[a] + f64::from(v.pos[a]) + f64::from(d[a]))
            };
            let tris: Vec<[[f64; 3]; 3]> = parent.indices[..parent.surface_indices as usize]
                .chunks_exact(3)
                .map(|t| [world(&parent, t[0], false), world(&parent, t[1], false), world(&parent, t[2], false)])
                .collect();
            let mut used: Vec<u32> = child.indices[..child.surface_indices as usize].to_vec();
            used.sort_unstable();
            used.dedup();
            for &i in &used {
                let v = &child.vertices[i as usize];
                sideways = sideways.max(v.morph[0].abs().max(v.morph[2].abs()));
                let q = world(&child, i, true);
                // The parent's triangle under the target in plan (within a
                // 10⁻⁴ of its size: a target on its border is a chord
                // point, which f32 may put a rounding outside), and its
                // plane's height there.
                let gap = tris
                    .iter()
                    .filter_map(|[a, b, c]| {
                        let det = (b[0] - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (b[2] - a[2]);
                        let l1 = ((q[0] - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (q[2] - a[2])) / det;
                        let l2 = ((b[0] - a[0]) * (q[2] - a[2]) - (q[0] - a[0]) * (b[2] - a[2])) / det;
                        let l0 = 1.0 - l1 - l2;
                        (l0.min(l1).min(l2) > -1e-4).then(|| (q[1] - (l0 * a[1] + l1 * b[1] + l2 * c[1])).abs())
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!(gap < 0.01, "{}: vertex {i}'s target is {gap} m off the parent's surface", node.uri);
                checked += 1;
            }
        }
        assert!(checked > 500, "{checked} vertices");
        // The deltas are not vertical: the parent's chords are not where
        // the flat frame's vertical lines would meet them.
        assert!(sideways > 1e-4, "largest sideways delta {sideways} m");
    }

    /// The Kattegat fixture built untextured at 0.5 m into `tmp/out`.
    fn kattegat_tileset(tmp: &Path) -> PathBuf {
        let dem = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/kattegat_crop_u8.png");
        let dir = tmp.join("out");
        build(&BuildOptions {
            inputs: vec![dem],
            out: dir.clone(),
            force: false,
            config: Config { max_error_m: 0.5, frame: Frame::Flat, ..Config::default() },
            texture: TextureSource::None,
            progress: false,
            geoid: None,
        })
        .unwrap();
        dir
    }

    /// A tileset whose index is split into external tilesets opens as the
    /// same tree as with one index file.
    #[test]
    fn external_tilesets_open_as_the_one_file_tree() {
        let tmp = tempfile::tempdir().unwrap();
        let one = kattegat_tileset(tmp.path());
        let split = tmp.path().join("split");
        let dem = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/kattegat_crop_u8.png");
        build(&BuildOptions {
            inputs: vec![dem],
            out: split.clone(),
            force: false,
            config: Config { max_error_m: 0.5, frame: Frame::Flat, index_tiles: 4, ..Config::default() },
            texture: TextureSource::None,
            progress: false,
            geoid: None,
        })
        .unwrap();
        let external = std::fs::read_dir(&split)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .find(|n| n.starts_with("tileset-"))
            .expect("the index was not split");
        let (a, b) = (Tileset::open(&one).unwrap(), Tileset::open(&split).unwrap());
        assert!(a.tree.nodes.len() > 4);
        assert_eq!(a.tree, b.tree);
        std::fs::remove_file(split.join(&external)).unwrap();
        let e = format!("{:#}", Tileset::open(&split).err().expect("opened without an external tileset"));
        assert!(e.contains(&external), "{e}");
    }

    /// A damaged chunk whose triangles index past its vertices is an error
    /// naming the file: its indices once went to the GPU as they were.
    #[test]
    fn a_chunk_indexing_past_its_vertices_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = kattegat_tileset(tmp.path());
        let path = dir.join("tiles/0/0/0.glb");
        assert!(load_chunk(&path).is_ok());
        // The surface's first index (u16, at the start of its bufferView) set past the vertices.
        let mut bytes = std::fs::read(&path).unwrap();
        let glb = gltf::Glb::from_slice(&bytes).unwrap();
        let json: serde_json::Value = serde_json::from_slice(&glb.json).unwrap();
        let acc = &json["accessors"][json["meshes"][0]["primitives"][0]["indices"].as_u64().unwrap() as usize];
        assert_eq!(acc["componentType"], 5123, "u16 indices");
        let view = &json["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
        let at = 20 + glb.json.len() + 8 + view["byteOffset"].as_u64().unwrap_or(0) as usize;
        bytes[at..at + 2].copy_from_slice(&60_000u16.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let Err(e) = load_chunk(&path) else { panic!("a chunk indexing past its vertices loaded") };
        let e = format!("{e:#}");
        assert!(e.contains("0.glb") && e.contains("index 60000 past"), "{e}");
    }

    /// The viewer reads chunks as `verify` does: a chunk longer than its GLB
    /// header says, or one that is a link, is an error naming it; a tileset
    /// whose level folder is a link out of it does not open.
    #[cfg(unix)]
    #[test]
    fn padded_linked_and_linked_folder_chunks_are_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = kattegat_tileset(tmp.path());
        let ts = Tileset::open(&dir).unwrap();
        let path = ts.chunk_path(0);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes.extend_from_slice(&[0; 64]);
        std::fs::write(&path, &bytes).unwrap();
        let e = format!("{:#}", load_chunk(&path).err().expect("a padded chunk loaded"));
        assert!(e.contains("0.glb") && e.contains("header"), "{e}");
        std::fs::remove_file(&path).unwrap();
        std::os::unix::fs::symlink("/dev/zero", &path).unwrap();
        let e = format!("{:#}", load_chunk(&path).err().expect("a linked chunk loaded"));
        assert!(e.contains("0.glb") && e.contains("link"), "{e}");
        let level = dir.join("tiles/1");
        std::fs::rename(&level, tmp.path().join("elsewhere")).unwrap();
        std::os::unix::fs::symlink(tmp.path().join("elsewhere"), &level).unwrap();
        let e = format!("{:#}", Tileset::open(&dir).err().expect("a tileset with a linked folder opened"));
        assert!(e.contains("tiles/1") && e.contains("link"), "{e}");
    }
}
