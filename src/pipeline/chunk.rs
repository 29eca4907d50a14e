//! The per-chunk path, read top to bottom: mesh → skirt → morph (what the
//! children need, [`Run::shape`]) → texture → encode (what is left to
//! write, [`Run::finish`]). The scheduler ([`super::schedule`]) decides
//! when each runs and retries a quantized chunk at other cut shares;
//! nothing here loops.

use std::sync::atomic::Ordering;
use std::time::Instant;

use super::BuildError;
use super::schedule::{BuiltChunk, LevelFigures, Meshed, Run, TileFigures, Timers, few_chunks};

use crate::chunk::{Chunk, Part};
use crate::geodesy::Globe;
use crate::mesh::decimate::{ChunkSpec, DividingLines, build_chunk};
use crate::mesh::grid::Grid;
use crate::mesh::skirt::{Hang, build_skirt};
use crate::mesh::{ChunkMesh, MeshVertex, ParentPoint, dem_normal};
use crate::output::gltf::encode_glb;
use crate::output::tileset::{TileRecord, tile_uri};
use crate::quadtree::ChunkKey;

impl Run<'_> {
    /// Meshes chunk `key` within its δ from its parent's mesh (`share` of δ
    /// next to cut points, for quantized output), then adds its skirts and
    /// morph targets: the mesh its children start from, and the chunk.
    pub(super) fn shape(
        &self,
        key: ChunkKey,
        parent: Option<&ChunkMesh>,
        share: f64,
    ) -> Result<(ChunkMesh, Chunk), BuildError> {
        let t = Instant::now();
        let mesh = self.mesh(key, parent, share)?;
        Timers::add(&self.timers.mesh, t);
        let t = Instant::now();
        // Skirts reach below any neighbour of level ≥ L − 1 in any morph state.
        let margin = self.tree.delta_m[(key.level as usize).saturating_sub(2)];
        let chunk = Chunk {
            delta_m: self.tree.delta_m[key.level as usize],
            ..assemble(self.grid, self.hf.spacing_m, &mesh, margin, self.globe, self.opts.config.normal_map)
        };
        Timers::add(&self.timers.skirt_morph, t);
        Ok((mesh, chunk))
    }

    /// The TIN of chunk `key`, refused if the mesher left a sample beyond δ.
    fn mesh(&self, key: ChunkKey, parent: Option<&ChunkMesh>, share: f64) -> Result<ChunkMesh, BuildError> {
        let (tree, level) = (self.tree, key.level);
        let few = few_chunks(tree, level);
        let spec = ChunkSpec {
            key,
            footprint: tree.footprint(key),
            delta_m: tree.delta_m[level as usize],
            parent,
            keep_parent_edges: true,
            max_vertices: self.opts.config.max_chunk_vertices as usize,
            dividing_lines: match (tree.splits(level), few && self.lone_parts) {
                (true, _) => DividingLines::Children,
                (false, true) => DividingLines::Parts,
                (false, false) => DividingLines::None,
            },
            split_insertion: few,
            cancel: Some(&self.failed),
            cut_share: share,
            cut_lattice: self.ctx.quantization.as_ref().map(|q| q.shift[level as usize]),
            // Quantized output: each triangle is meshed to δ less what
            // its corners' heights round by (output::compress).
            height_step: self.ctx.quantization.as_ref().map(|q| q.step_y_m),
            thin: self.opts.config.thin.level(!tree.splits(level)),
        };
        let mesh = match self.rtin {
            Some(r) => r.build_chunk(
                self.grid,
                self.tree,
                key,
                spec.max_vertices,
                spec.cancel,
                self.globe.map(|g| (g, self.hf.spacing_m)),
            )?,
            None => build_chunk(self.grid, &spec)?,
        };
        if mesh.max_error_m > spec.delta_m {
            return Err(BuildError::MissedDelta {
                level: key.level,
                x: key.x,
                y: key.y,
                error_m: mesh.max_error_m,
                delta_m: spec.delta_m,
            });
        }
        Ok(mesh)
    }

    /// Textures, encodes and writes a shaped chunk.
    pub(super) fn finish(&self, meshed: Meshed) -> Result<BuiltChunk, BuildError> {
        let Meshed { chunk, remeshed, over_delta_m, max_error_m, leaf } = meshed;
        let (key, delta) = (chunk.key, chunk.delta_m);
        let timers = &self.timers;
        let t = Instant::now();
        let texture = self.texturer.map(|tx| tx.tile(key)).transpose()?;
        Timers::add(&timers.texture, t);
        let t = Instant::now();
        let glb = encode_glb(&chunk, texture.as_ref(), &self.ctx)?;
        let path = self.tmp.join(tile_uri(key));
        std::fs::create_dir_all(path.parent().expect("tile path has a parent"))
            .and_then(|_| std::fs::write(&path, &glb))
            .map_err(|source| BuildError::Io { path: path.clone(), source })?;
        self.bytes.fetch_add(glb.len() as u64, Ordering::Relaxed);
        Timers::add(&timers.write, t);
        self.bar.inc(1);
        let (min, max) = self.ctx.quantization.map_or(bounds(&chunk), |q| q.written_bounds(bounds(&chunk), key.level));
        let figures = LevelFigures {
            triangles: chunk.surface.triangle_count(),
            skirt_triangles: chunk.skirt.triangle_count(),
            vertices: chunk.surface.positions.len(),
            bytes: glb.len() as u64,
            texture: texture.map(|t| TileFigures {
                texel_m: t.colour.texel_size_m(),
                texels: t.colour.texels,
                limit: t.colour.limit[0].max(t.colour.limit[1]),
                bytes: (t.colour.bytes.len() + t.normal.as_ref().map_or(0, |n| n.bytes.len())) as u64,
            }),
        };
        Ok(BuiltChunk {
            record: TileRecord { key, min, max, delta_m: delta },
            figures,
            max_error_m,
            remeshed,
            over_delta_m,
            leaf,
        })
    }
}

/// A chunk from its TIN: the written triangles' vertices as the surface
/// (world f64, DEM normals), each with its morph target (the parent
/// surface's height, as a y delta), and skirts hanging from its borders,
/// whose top vertices carry the surface's morph deltas; with a `globe`,
/// then moved into the curved frame ([`bend`]; with a `normal_map`, each
/// vertex's normal the ground's up and its tangent the grid's x axis, the
/// frame the map's normals are given in). Public for the `.glb`
/// micro-benchmark (`benches/stages.rs`).
pub fn assemble(
    grid: &Grid,
    spacing: [f64; 2],
    mesh: &ChunkMesh,
    margin_m: f64,
    globe: Option<&Globe>,
    normal_map: bool,
) -> Chunk {
    let (used, indices) = written(mesh);
    let ((x0, x1), (z0, z1)) = mesh.footprint;
    let side = (x1 - x0).max(z1 - z0);
    let targets: Vec<ParentPoint> = match globe {
        Some(_) => used.iter().map(|&(_, k)| mesh.parent_points[k]).collect(),
        None => Vec::new(),
    };
    let used: Vec<MeshVertex> = used.into_iter().map(|(v, _)| v).collect();
    let mut surface = Part {
        positions: used.iter().map(|v| [v.x * spacing[0], v.h, v.z * spacing[1]]).collect(),
        normals: used
            .iter()
            .enumerate()
            .map(|(k, v)| {
                // A coarse chunk's vertices span much of the grid, a few pages each.
                grid.relieve_every(side, k as u32);
                dem_normal(grid, spacing, v.x, v.z)
            })
            .collect(),
        morph_dy: Vec::new(),
        indices,
        ..Part::default()
    };
    let parent_h: Vec<f64> = used.iter().map(|v| v.ph).collect();
    surface.morph_dy = used.iter().zip(&parent_h).map(|(v, p)| p - v.h).collect();
    let grid_xz: Vec<(f64, f64)> = used.iter().map(|v| (v.x, v.z)).collect();
    let (skirt, hangs) = build_skirt(grid, mesh.footprint, &surface, &grid_xz, &parent_h, margin_m);
    let mut chunk = Chunk {
        key: mesh.key,
        footprint: mesh.footprint,
        delta_m: mesh.delta_m,
        max_error_m: mesh.max_error_m,
        surface,
        surface_grid: grid_xz,
        skirt,
    };
    if let Some(globe) = globe {
        bend(&mut chunk, &targets, &hangs, globe, spacing, normal_map);
    }
    chunk
}

/// Moves a chunk assembled in grid metres into the curved frame: every
/// vertex to the world position of its grid point and height, its normal
/// turned from the grid's axes to the local ones there, and its morph
/// delta to the parent's written surface (`targets`, per surface vertex:
/// `ChunkMesh::parent_points`, which the bintree carries down its edges).
/// Skirt tops (`hangs`: the surface vertex each skirt vertex hangs from, as
/// [`build_skirt`] gives them) take their surface vertex's place, normal
/// and delta, bottoms its normal and delta 0, as in the flat frame; a
/// bottom hangs along the normal.
fn bend(
    chunk: &mut Chunk,
    targets: &[ParentPoint],
    hangs: &[Hang],
    globe: &Globe,
    spacing: [f64; 2],
    normal_map: bool,
) {
    let surface = &mut chunk.surface;
    let mut deltas = Vec::with_capacity(surface.positions.len());
    for (k, &(j, i)) in chunk.surface_grid.iter().enumerate() {
        // A vertex the parent has too was placed once, for both.
        let target = targets[k];
        let p = if target.shared { target.at } else { globe.world(j, i, surface.positions[k][1]) };
        if normal_map {
            // The map's normals are given against the grid's up and x axis.
            surface.normals[k] = globe.turn_normal(j, i, [0.0, 1.0, 0.0]);
            surface.tangents.push(globe.turn_normal(j, i, [1.0, 0.0, 0.0]));
        } else {
            surface.normals[k] = globe.turn_normal(j, i, surface.normals[k]);
        }
        deltas.push([0, 1, 2].map(|a| target.at[a] - p[a]));
        surface.positions[k] = p;
    }
    surface.plan_m = chunk.surface_grid.iter().map(|&(j, i)| [j * spacing[0], i * spacing[1]]).collect();
    surface.morph_dy = deltas.iter().map(|d| d[1]).collect();
    surface.morph_dxz = deltas.iter().map(|d| [d[0], d[2]]).collect();
    let skirt = &mut chunk.skirt;
    skirt.plan_m.reserve(hangs.len());
    skirt.morph_dxz.reserve(hangs.len());
    for (k, &Hang { surface: s, top }) in hangs.iter().enumerate() {
        let s = s as usize;
        // The same grid point and normal as its surface vertex: the same
        // results, without working them out again.
        let (j, i) = chunk.surface_grid[s];
        skirt.positions[k] = if top { surface.positions[s] } else { globe.world(j, i, skirt.positions[k][1]) };
        skirt.normals[k] = surface.normals[s];
        if normal_map {
            skirt.tangents.push(surface.tangents[s]);
        }
        skirt.plan_m.push(surface.plan_m[s]);
        let d = if top { deltas[s] } else { [0.0; 3] };
        skirt.morph_dy[k] = d[1];
        skirt.morph_dxz.push([d[0], d[2]]);
    }
}

/// The vertices of `mesh`'s written triangles, in the order they are first
/// used (each with its index in `mesh.vertices`), and the triangles'
/// indices into them.
fn written(mesh: &ChunkMesh) -> (Vec<(MeshVertex, usize)>, Vec<u32>) {
    let mut remap = vec![u32::MAX; mesh.vertices.len()];
    let mut used = Vec::new();
    let mut indices = Vec::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if !mesh.kept[t] {
            continue;
        }
        for &v in tri {
            if remap[v as usize] == u32::MAX {
                remap[v as usize] = used.len() as u32;
                used.push((mesh.vertices[v as usize], v as usize));
            }
            indices.push(remap[v as usize]);
        }
    }
    (used, indices)
}

fn bounds(c: &Chunk) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in c.surface.positions.iter().chain(&c.skirt.positions) {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}
