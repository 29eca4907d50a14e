//! Compressed vertex data (`compress = "quantize" | "meshopt" |
//! "meshopt-v1"`): integer positions, normals, morph deltas and texture
//! coordinates by KHR_mesh_quantization, then optionally meshoptimizer's
//! vertex and index codecs by EXT_meshopt_compression or
//! KHR_meshopt_compression; and the reader that turns such a file back into
//! the plain f32 glTF that `verify` and `inspect` read.
//!
//! **The grid.** Positions are u16 on a grid that is the same for every
//! chunk of a level and aligned to the world, so that two chunks round a
//! shared vertex alike and their borders stay identical:
//! - horizontally, the step is the sample spacing / 2^k(L), with k(L) the
//!   largest that fits the level's widest footprint in 65 535 steps, and at
//!   most 8 (`MAX_SHIFT`): every DEM sample is exactly on the grid, and
//!   only the cut points (where a dividing line crosses a parent edge, the
//!   one kind of vertex off the sample grid) are placed on it by the mesher.
//!   Finer than 1/256 of a cell (chunks under 128 cells wide) bought nothing
//!   but a sample's x and z one more bit above the byte boundary: capped,
//!   Fuji's `meshopt-v1` positions take 2.50 bytes per vertex instead of
//!   2.61 (7 would make them 2.89: the grid no longer ends on a byte);
//! - vertically, one step for the whole tileset: a power of two ≤
//!   `max_error_m / 16`, doubled while the tallest chunk (the whole relief
//!   plus skirts) would need more than 65 535 steps; a DEM whose relief needs
//!   a step above `max_error_m / 4` is refused. Heights round to the nearest
//!   multiple of the step, the same in every chunk and level, so a vertex a
//!   child shares with its parent keeps morph delta 0.
//!
//! The node carries the dequantisation, as KHR_mesh_quantization intends:
//! `translation` (the footprint's north-west corner, and the lowest height
//! multiple) and `scale` = the step per axis. This changes the output
//! contract for these modes only (DESIGN.md's node has no scale): world =
//! translation + scale · POSITION.
//!
//! **The δ budget.** Rounding the corners' heights moves the surface at a
//! point by at most the most any corner moves, so each triangle (and each
//! interval of a border or dividing line) is meshed to δ(L) less that
//! ([`crate::mesh::decimate::Targets::rounding`], at most step/2) and the
//! written, dequantized chunk is still within δ(L) of every sample. A DEM
//! sample of whole metres rounds by nothing at a step of 1/8 m, so
//! triangles of samples keep all of δ there: meshing every level to
//! δ(L) − step/2, as this did before, cost California at 1 m 4.8 % more
//! surface vertices than `none`. Cut points, the one kind of vertex
//! off the sample grid, are placed on the level's grid by the mesher itself
//! ([`crate::mesh::decimate::ChunkSpec::cut_lattice`]): moved along their dividing line
//! to the nearest step, where the file holds them exactly, so the surface
//! the mesher measures is the one written. Crossings closer together than
//! a step land on one point as separate vertices, each with its own morph
//! target, and the pieces between them are flat; one whose move would turn
//! a piece over tries the other neighbouring step, and failing that stays
//! exact and rounds only here. Rounding every
//! cut point only here, after meshing, tilted steep triangles past δ
//! (Provence at 1 m: 8.058 m in a chunk of δ 8 m; California at 1 m: 151
//! chunks, up to 10 m at δ 1 m, where fans of parent edges cross a line
//! closer together than a step and rounding folded the pieces between
//! them). [`Quantization::cut_error`] still measures each chunk as it will
//! be written, and the pipeline meshes it again with a wider margin next to
//! cut points where that misses δ. `verify` re-measures the dequantized
//! files against δ with no allowance.
//!
//! **Morph targets** are the parent's height rounded to the same grid minus
//! the vertex's rounded height, in whole steps (scaled by the node like
//! POSITION): i8 where every delta of the chunk fits, which is every leaf
//! and most levels, else i16, or f32 holding the same whole numbers where a
//! delta exceeds 32 767 steps. Normals are i8 normalized (as the OCTAHEDRAL
//! filter decodes them, see below), texture coordinates u16 normalized, the
//! normal map's tangent i8 normalized.
//!
//! **Layout.** A chunk's vertex data lies in three bufferViews, each holding
//! the surface then the skirt ([`write_quantized`]): the vertex attributes
//! interleaved, the normals, the triangles. Every bufferView costs the JSON
//! about 200 bytes and every meshopt stream a header and a 32-byte tail,
//! which at a few thousand vertices per chunk is a byte per vertex; the
//! document also leaves out defaults (`byteOffset` 0, primitive mode 4).
//!
//! **meshopt** encodes every vertex stream (codec version 0, the one
//! EXT_meshopt_compression allows; normals through the 8-bit OCTAHEDRAL
//! filter, whose decoded values `quantize` writes too) and the index stream
//! (triangle codec, whose corner rotation `quantize` writes too), so it
//! decodes to exactly the bytes `quantize` writes. EXT_meshopt_compression
//! is *required* and the fallback buffer holds no data (`fallback: true`):
//! the point of the mode is size, and an uncompressed fallback would make the
//! file larger than `quantize`; a reader without the decoder should use
//! `quantize` or `none` output. Its files stay byte for byte what they were
//! before `meshopt-v1` existed, for cesium-native and other readers that
//! know only the EXT extension.
//!
//! **meshopt-v1** is `meshopt` for readers that know KHR_meshopt_compression
//! (its Khronos successor; CesiumJS from 1.143), and differs in five ways:
//! - the vertex streams go through meshoptimizer's vertex codec version 1
//!   (which the KHR extension allows and EXT does not) at level 3, its
//!   tightest (0.05–0.07 bytes per vertex below level 2; the encoder's
//!   extra second or two on California is inside the write stage's
//!   run-to-run spread); the index stream through the same triangle codec;
//! - normals keep 8 octahedral bits but each is the lattice point whose
//!   *decoded* normal is nearest the exact one ([`NormalEncoding::Nearest`])
//!   instead of meshoptimizer's per-coordinate rounding: worst angle 0.71°
//!   instead of 1.14° on Fuji (0.73° against 1.21° over the whole sphere)
//!   for 0.003 bytes per vertex. 8 bits are the fewest that stay within 1°:
//!   measured on Fuji at 1 m (501 869 normals; worst angle, then bytes per
//!   surface vertex of the normal stream and of all geometry,
//!   `examples/geometry_bytes.rs`), 8 bits 0.71°, 1.75, 8.28; 7 bits
//!   1.45°, 1.59, 8.11; 6 bits 2.58°, 1.32, 7.83 (rounded instead: 1.14°,
//!   2.15°, 3.79°). `normal_bits` trades that shading for size in any mode;
//! - the JSON leaves out what only labels or restates a default: the node,
//!   mesh and material names (the chunk record has the key) and the
//!   material's roughness 1 (see [`meshopt_pack`] for a cut that was tried
//!   and dropped);
//! - surface and skirt share one vertex set and its accessors: the skirt's
//!   top vertices are the surface's own (the same position, normal and
//!   morph delta), so the set is the surface's vertices then the skirt's
//!   bottoms, and each primitive's vertices are those its triangles use
//!   (what [`decompress`] cuts out for each). A bottom-only skirt saves
//!   0.19 bytes per surface vertex on Fuji at 1 m and 0.31 on California
//!   (the tops' data and three accessors' JSON, less the dearer skirt
//!   indices: a top is now an earlier vertex, not the next one). Readers
//!   that cache accessors (three.js, CesiumJS) hold the set once. It is
//!   `meshopt-v1` only: Blender and MeshLab, which read `quantize`, cannot
//!   read a meshopt file anyway;
//! - a chunk over 255 cells wide (the top levels) writes POSITION as f32
//!   step counts in a view of its own, through the EXPONENTIAL filter with
//!   mantissas in 1/256-cell units (`exp_position_column`): its u16 step
//!   of 1/128 cell or coarser put the sample index's low bits in each x and
//!   z low byte. Fuji at 1 m: 8.01 → 7.88 bytes per surface vertex.
//!
//! Its normals differ from `quantize`'s, so its surface decodes to what
//! `quantize` writes with `normal_bits = 8` (and the `strip` order), the
//! same nearest-point normals and, in wide chunks, the same positions as
//! f32 instead of u16, and its skirt to the same triangles with fewer
//! vertices: that pair is what the tests compare, after [`decompress`].

use std::collections::BTreeMap;

use serde_json::{Value, json};

use crate::chunk::Chunk;
use crate::heightfield::Heightfield;
use crate::mesh::MeshVertex;
use crate::mesh::decimate::Grid;
use crate::morph::points_near_triangle;
use crate::output::gltf::{PrimData, index_bytes, index_values};
use crate::quadtree::ChunkTree;

/// The largest u16.
const U16_STEPS: f64 = 65_535.0;

/// The finest horizontal step, 2^-MAX_SHIFT cells (see the module comment).
const MAX_SHIFT: u32 = 8;

/// Why vertex data cannot be quantized.
#[derive(Debug, thiserror::Error)]
pub enum QuantizeError {
    /// The relief is too tall for u16 heights at a step small against δ.
    #[error(
        "compress: the DEM's relief of {relief_m} m (plus skirts) needs a height step of {step_m} m to fit \
         16 bits, more than max_error_m / 4 = {quarter_m} m; raise max_error_m or use --compress none"
    )]
    Relief {
        /// Highest minus lowest valid height, metres.
        relief_m: f64,
        /// The step it would need, metres.
        step_m: f64,
        /// `max_error_m / 4`.
        quarter_m: f64,
    },
    /// A chunk is wider than 65 535 cells: its samples cannot all be on a u16 grid.
    #[error("compress: level {level} has chunks {cells} cells wide, more than a u16 position can count")]
    TooWide {
        /// Level.
        level: u32,
        /// Widest footprint, cells.
        cells: u32,
    },
    /// A chunk's vertices do not fit the planned grid (a terrachunk bug).
    #[error("compress: chunk {chunk}: a {axis} coordinate falls outside 0..=65535 steps (please report it)")]
    Range {
        /// `L/x/y`.
        chunk: String,
        /// x, y or z.
        axis: &'static str,
    },
}

/// The quantization grid of one build (see the module comment).
#[derive(Clone, Debug, PartialEq)]
pub struct Quantization {
    /// Height step, metres: a power of two, the same for every level.
    pub step_y_m: f64,
    /// Per level `L`: the horizontal step is `spacing_m / 2^shift[L]`.
    pub shift: Vec<u32>,
    /// Sample spacing `[s_x, s_z]`, metres.
    pub spacing_m: [f64; 2],
}

impl Quantization {
    /// Plans the grid for `tree` over `hf` with leaf accuracy `max_error_m`.
    pub fn plan(hf: &Heightfield, tree: &ChunkTree, max_error_m: f64) -> Result<Self, QuantizeError> {
        let (lo, hi) = hf
            .heights
            .iter()
            .filter(|h| !h.is_nan())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &h| (a.min(f64::from(h)), b.max(f64::from(h))));
        let relief_m = if hi >= lo { hi - lo } else { 0.0 };
        // Skirts hang at most δ(L−1) + δ(L−2) ≤ 2·δ(0) below the lowest sample.
        let range = relief_m + 2.0 * tree.delta_m[0];
        let mut step = 2f64.powi((max_error_m / 16.0).log2().floor() as i32);
        while range / step > U16_STEPS - 2.0 {
            step *= 2.0;
        }
        if step > max_error_m / 4.0 {
            return Err(QuantizeError::Relief { relief_m, step_m: step, quarter_m: max_error_m / 4.0 });
        }
        let mut shift = Vec::with_capacity(tree.xs.len());
        for level in 0..=tree.depth() {
            let cells = tree.widest_cells(level).into_iter().max().unwrap_or(1).max(1);
            if f64::from(cells) > U16_STEPS {
                return Err(QuantizeError::TooWide { level, cells });
            }
            shift.push((U16_STEPS / f64::from(cells)).log2().floor().min(f64::from(MAX_SHIFT)) as u32);
        }
        Ok(Quantization { step_y_m: step, shift, spacing_m: hf.spacing_m })
    }

    /// The largest |surface − sample| over the samples under `chunk`'s
    /// triangles that have a cut-point corner the file moves sideways, with
    /// every corner where the written file puts it: heights on the grid
    /// (which the mesher's targets leave room for) and a cut point, off the
    /// sample grid and left off the quantize grid by the mesher, moved
    /// along its dividing line to the nearest step. Half a step (1/512 of a cell in a 250-cell
    /// chunk) on a steep triangle can tilt it by more than the mesher's
    /// margin next to cut points (Provence at 1 m, Verdon gorge: 8.058 m in
    /// a chunk of δ 8 m), which is what this finds. Triangles without a cut
    /// corner only move vertically, within what their targets left room for.
    ///
    /// Exact where it is over `within` (the error the caller accepts);
    /// otherwise some value no larger than `within`, so the two compare
    /// alike either way. Only the samples over `within` among the cut-point
    /// triangles' are looked for under their neighbours (usually none):
    /// a neighbour can only lower a sample's error.
    pub fn cut_error(&self, chunk: &Chunk, grid: &Grid, within: f64) -> Result<f64, QuantizeError> {
        let frame = self.frame(chunk)?;
        let whole = |c: f64| c == c.round();
        let surface = &chunk.surface;
        let written: Vec<MeshVertex> = surface
            .positions
            .iter()
            .map(|p| {
                // Grid coordinates as the file gives them, exactly (the step
                // is a power of two of a cell): through metres they would
                // carry rounding that a steep sliver turns into 10⁻⁹ m.
                let q = frame.position(p);
                let h = frame.translation[1] + frame.scale[1] * f64::from(q[1]);
                let [x, z] = [0, 2].map(|a| frame.corner[a / 2] + f64::from(q[a]) / frame.k);
                MeshVertex { x, z, h, ph: h }
            })
            .collect();
        // A cut point (off the sample grid) the file moves sideways: one the
        // mesher left off the quantize grid. One it placed on that grid
        // (nearly all) moves only vertically, like a sample, within what
        // its triangles' targets left room for.
        let cut: Vec<bool> = chunk
            .surface_grid
            .iter()
            .zip(&written)
            .map(|(&(x, z), w)| (!whole(x) || !whole(z)) && (w.x != x || w.z != z))
            .collect();
        // Each sample's error is its best fit among the written triangles
        // over it, as `verify` takes it: where a cut point moves across a
        // sliver, triangles overlap, and the sliver's steep plane must not
        // count against a sample its neighbour fits. The samples are those
        // under a cut-point triangle; the triangles that can be over them
        // after the move are those sharing a corner with one.
        let triangles: Vec<[usize; 3]> =
            surface.indices.chunks_exact(3).map(|t| [t[0] as usize, t[1] as usize, t[2] as usize]).collect();
        let is_cut = |t: &[usize; 3]| t.iter().any(|&i| cut[i]);
        let mut near = vec![false; written.len()];
        for t in triangles.iter().filter(|t| is_cut(t)) {
            for &i in t {
                near[i] = true;
            }
        }
        // Usually every sample is within `within` under every cut-point
        // triangle over it: one pass says so and stores nothing.
        let (mut over, mut low) = (false, 0.0f64);
        for t in triangles.iter().filter(|t| is_cut(t)) {
            near_samples(grid, &t.map(|i| written[i]), |_, e| match e > within {
                true => over = true,
                false => low = low.max(e),
            });
        }
        if !over {
            return Ok(low);
        }
        // Otherwise the cut-point triangles' samples, each with its best fit
        // among them (sorted by sample, one entry each); those still over
        // `within` are then improved by the triangles next to them.
        let mut best: Vec<(usize, f64)> = Vec::new();
        for t in triangles.iter().filter(|t| is_cut(t)) {
            near_samples(grid, &t.map(|i| written[i]), |k, e| best.push((k, e)));
        }
        best.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        best.dedup_by_key(|b| b.0);
        let low = best.iter().map(|b| b.1).filter(|&e| e <= within).fold(0.0, f64::max);
        best.retain(|b| b.1 > within);
        for t in triangles.iter().filter(|t| !is_cut(t) && t.iter().any(|&i| near[i])) {
            near_samples(grid, &t.map(|i| written[i]), |k, e| {
                if let Ok(at) = best.binary_search_by_key(&k, |b| b.0) {
                    best[at].1 = best[at].1.min(e);
                }
            });
        }
        Ok(best.iter().map(|b| b.1).fold(low, f64::max))
    }

    /// The box `(min, max)` of a chunk's exact positions widened by half
    /// a step of `level` on each axis: its positions as written round to
    /// the grid by up to that, so this box holds them.
    pub fn written_bounds(&self, (min, max): ([f64; 3], [f64; 3]), level: u32) -> ([f64; 3], [f64; 3]) {
        let k = f64::from(1u32 << self.shift[level as usize]);
        let half = [self.spacing_m[0] / k / 2.0, self.step_y_m / 2.0, self.spacing_m[1] / k / 2.0];
        ([0, 1, 2].map(|a| min[a] - half[a]), [0, 1, 2].map(|a| max[a] + half[a]))
    }

    /// The grid of one chunk: where its integers start and their step.
    pub fn frame(&self, chunk: &Chunk) -> Result<Frame, QuantizeError> {
        let k = f64::from(1u32 << self.shift[chunk.key.level as usize]);
        let ((x0, _), (z0, _)) = chunk.footprint;
        let lowest = chunk
            .surface
            .positions
            .iter()
            .chain(&chunk.skirt.positions)
            .map(|p| (p[1] / self.step_y_m).round())
            .fold(f64::INFINITY, f64::min);
        let lowest = if lowest.is_finite() { lowest } else { 0.0 };
        let frame = Frame {
            translation: [f64::from(x0) * self.spacing_m[0], lowest * self.step_y_m, f64::from(z0) * self.spacing_m[1]],
            scale: [self.spacing_m[0] / k, self.step_y_m, self.spacing_m[1] / k],
            corner: [f64::from(x0), f64::from(z0)],
            lowest,
            k,
            spacing_m: self.spacing_m,
        };
        let key = chunk.key;
        for p in chunk.surface.positions.iter().chain(&chunk.skirt.positions) {
            let q = frame.steps(p);
            if let Some(a) = (0..3).find(|&a| !(0.0..=U16_STEPS).contains(&q[a])) {
                return Err(QuantizeError::Range {
                    chunk: format!("{}/{}/{}", key.level, key.x, key.y),
                    axis: ["x", "y", "z"][a],
                });
            }
        }
        Ok(frame)
    }
}

/// One chunk's quantization: world = `translation` + `scale` · integer.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// Node translation, metres.
    pub translation: [f64; 3],
    /// Node scale: the step per axis, metres.
    pub scale: [f64; 3],
    /// The footprint's north-west corner, samples `[x0, z0]`.
    corner: [f64; 2],
    /// The translation's height in steps.
    lowest: f64,
    /// Horizontal steps per sample spacing, 2^shift.
    k: f64,
    /// Sample spacing, metres.
    spacing_m: [f64; 2],
}

impl Frame {
    /// A world position in whole steps from the translation (as f64). x and
    /// z go through grid coordinates, so samples land on whole steps exactly.
    fn steps(&self, p: &[f64; 3]) -> [f64; 3] {
        let [x, z] = self.horizontal_steps(p);
        [x.round(), (p[1] / self.scale[1]).round() - self.lowest, z.round()]
    }

    /// `p`'s x and z in horizontal steps from the corner, before rounding:
    /// whole numbers where `p` is on the grid.
    fn horizontal_steps(&self, p: &[f64; 3]) -> [f64; 2] {
        [0, 1].map(|c| (p[2 * c] / self.spacing_m[c] - self.corner[c]) * self.k)
    }

    /// World position `p` where the file puts it: moved sideways to the
    /// nearest step where it is off the grid (a cut point the mesher left
    /// off it), else `p` itself. A texture coordinate is made from this, so
    /// that it maps the point the file draws.
    pub fn on_grid(&self, p: &[f64; 3]) -> [f64; 3] {
        let mut q = *p;
        for (c, steps) in self.horizontal_steps(p).into_iter().enumerate() {
            if steps != steps.round() {
                q[2 * c] = (self.corner[c] + steps.round() / self.k) * self.spacing_m[c];
            }
        }
        q
    }

    /// A world position as u16 steps (checked in [`Quantization::frame`]).
    pub fn position(&self, p: &[f64; 3]) -> [u16; 3] {
        self.steps(p).map(|v| v as u16)
    }

    /// The morph delta, in height steps, that takes a vertex at height `y`
    /// to `target_y` (both rounded to the grid first).
    pub fn delta_steps(&self, y: f64, target_y: f64) -> i64 {
        ((target_y / self.scale[1]).round() - (y / self.scale[1]).round()) as i64
    }
}

// ------------------------------------------------------------------ writing

/// The meshoptimizer extension the quantized streams are compressed for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Meshopt {
    /// EXT_meshopt_compression (`compress = "meshopt"`): vertex codec
    /// version 0, the only one it allows.
    Ext,
    /// KHR_meshopt_compression (`compress = "meshopt-v1"`): vertex codec
    /// version 1.
    Khr,
}

/// The extensions [`decompress`] reads compressed bufferViews of.
const MESHOPT_EXTENSIONS: [&str; 2] = ["EXT_meshopt_compression", "KHR_meshopt_compression"];

impl Meshopt {
    /// The extension's name, as `extensionsUsed` and the bufferViews spell it.
    pub fn extension(self) -> &'static str {
        match self {
            Meshopt::Ext => MESHOPT_EXTENSIONS[0],
            Meshopt::Khr => MESHOPT_EXTENSIONS[1],
        }
    }

    /// meshoptimizer's vertex codec version.
    fn vertex_version(self) -> i32 {
        match self {
            Meshopt::Ext => 0,
            Meshopt::Khr => 1,
        }
    }

    /// meshoptimizer's vertex encoder level (0..=3). Version 0 is written at
    /// level 2 as it always was; version 1 at 3, its tightest: 0.047 bytes
    /// per surface vertex below level 2 on California at 1 m, for 1.5
    /// thread-seconds more encoding (6.6 against 5.1; version 0 takes 3.0)
    /// in a write stage of about 66 (README, "Compression").
    fn vertex_level(self) -> i32 {
        match self {
            Meshopt::Ext => 2,
            Meshopt::Khr => 3,
        }
    }
}

/// How quantized normals are chosen for meshoptimizer's OCTAHEDRAL filter,
/// which stores two octahedral coordinates of `bits` bits in i8 components
/// and decodes them to an i8 normalized unit vector. Worst angles measured
/// on Fuji at 1 m (501 869 surface and skirt normals, README):
///
/// | bits | `Rounded` | `Nearest` |
/// |---|---|---|
/// | 8 | 1.14° | 0.71° |
/// | 7 | 2.15° | 1.45° |
/// | 6 | 3.79° | 2.58° |
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NormalEncoding {
    /// 8 bits, each coordinate rounded as meshoptimizer's encoder rounds it:
    /// what `quantize` and `meshopt` have always written.
    Rounded,
    /// `bits` bits (2..=8), each normal the one of the four lattice points
    /// around its octahedral coordinates whose *decoded* normal is nearest
    /// it: rounding each coordinate on its own is not the nearest point on
    /// the sphere, and the decoder's own rounding to i8 adds to it.
    Nearest(u32),
}

/// Unit normals through meshoptimizer's OCTAHEDRAL filter as `encoding`
/// says: what the filter's input holds (the two coordinates and the third
/// component holding 1.0 in that many bits; the fourth is 0) and what the
/// decoder makes of it, the i8 normalized normal a reader gets.
pub fn octahedral(normals: &[[f32; 3]], encoding: NormalEncoding) -> (Vec<[i8; 4]>, Vec<[i8; 4]>) {
    let bits = match encoding {
        NormalEncoding::Rounded => {
            let unit: Vec<[f32; 4]> = normals.iter().map(|n| [n[0], n[1], n[2], 0.0]).collect();
            let oct: Vec<[i8; 4]> = meshopt::encode_filter_oct(&unit, 8);
            let mut decoded = oct.clone();
            meshopt::decode_filter_oct(&mut decoded);
            return (oct, decoded);
        }
        NormalEncoding::Nearest(bits) => bits,
    };
    let one = (1i32 << (bits - 1)) - 1;
    let s = f64::from(one);
    // The four lattice points around each normal's octahedral coordinates
    // (meshoptimizer's mapping: z the hemisphere axis), as filter input.
    let mut candidates: [Vec<[i8; 4]>; 4] = std::array::from_fn(|_| Vec::with_capacity(normals.len()));
    for n in normals {
        let [x, y, z] = n.map(f64::from);
        let l1 = x.abs() + y.abs() + z.abs();
        let (x, y) = if l1 > 0.0 { (x / l1, y / l1) } else { (0.0, 0.0) };
        let (u, v) = if z >= 0.0 { (x, y) } else { ((1.0 - y.abs()) * x.signum(), (1.0 - x.abs()) * y.signum()) };
        let (fu, fv) = ((u * s).floor(), (v * s).floor());
        for (c, (du, dv)) in candidates.iter_mut().zip([(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]) {
            c.push([(fu + du).clamp(-s, s) as i8, (fv + dv).clamp(-s, s) as i8, one as i8, 0]);
        }
    }
    let decoded: Vec<Vec<[i8; 4]>> = candidates
        .iter()
        .map(|c| {
            let mut d = c.clone();
            meshopt::decode_filter_oct(&mut d);
            d
        })
        .collect();
    let mut oct = Vec::with_capacity(normals.len());
    let mut out = Vec::with_capacity(normals.len());
    for (i, n) in normals.iter().enumerate() {
        let best = (0..4)
            .max_by(|&a, &b| cosine(n, &decoded[a][i]).total_cmp(&cosine(n, &decoded[b][i])).then(b.cmp(&a)))
            .expect("four candidates");
        oct.push(candidates[best][i]);
        out.push(decoded[best][i]);
    }
    (oct, out)
}

/// The cosine of the angle between `n` and an i8 normalized vector.
pub fn cosine(n: &[f32; 3], d: &[i8; 4]) -> f64 {
    let d = [0, 1, 2].map(|k| f64::from(d[k]));
    let dot: f64 = (0..3).map(|k| d[k] * f64::from(n[k])).sum();
    let len = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    dot / (len(d) * len(n.map(f64::from))).max(f64::MIN_POSITIVE)
}

/// The binary chunk and the JSON arrays that describe it, as a .glb is
/// built; `streams` lists the bufferViews `meshopt` compresses.
#[derive(Default)]
pub struct Sink {
    /// The binary chunk so far.
    pub bin: Vec<u8>,
    /// `bufferViews`.
    pub views: Vec<Value>,
    /// `accessors`.
    pub accessors: Vec<Value>,
    /// Vertex and index streams, for [`meshopt_pack`].
    pub streams: Vec<Stream>,
}

/// A bufferView of vertex or index data.
pub struct Stream {
    view: usize,
    count: usize,
    stride: usize,
    /// Index data (u16 or u32 triangles) rather than vertex attributes.
    triangles: bool,
    /// Vertices the indices refer to (index streams only).
    vertices: usize,
    /// What `meshopt` encodes instead, and the filter (OCTAHEDRAL or
    /// EXPONENTIAL) that decodes it into the bytes written.
    filtered: Option<(&'static str, Vec<u8>)>,
}

fn align4(bin: &mut Vec<u8>) {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
}

/// Appends a bufferView of `bytes` (a `stride` for vertex data, none for
/// indices) and returns its index. A zero `byteOffset` is left out, as it
/// is the default.
fn push_view(sink: &mut Sink, bytes: &[u8], stride: Option<usize>) -> usize {
    align4(&mut sink.bin);
    let mut view = json!({"buffer": 0, "byteLength": bytes.len()});
    if !sink.bin.is_empty() {
        view["byteOffset"] = sink.bin.len().into();
    }
    match stride {
        Some(stride) => {
            view["byteStride"] = stride.into();
            view["target"] = 34962.into();
        }
        None => view["target"] = 34963.into(),
    }
    sink.bin.extend_from_slice(bytes);
    sink.views.push(view);
    sink.views.len() - 1
}

/// Per-component minimum and maximum, for POSITION accessors.
fn bounds<const N: usize>(values: impl Iterator<Item = [f64; N]>) -> (Vec<f64>, Vec<f64>) {
    let (mut lo, mut hi) = (vec![f64::INFINITY; N], vec![f64::NEG_INFINITY; N]);
    for v in values {
        for a in 0..N {
            lo[a] = lo[a].min(v[a]);
            hi[a] = hi[a].max(v[a]);
        }
    }
    (lo, hi)
}

/// A unit vector's component as i8 normalized.
fn snorm8(v: f32) -> i8 {
    (v.clamp(-1.0, 1.0) * 127.0).round() as i8
}

/// A texture coordinate as u16 normalized.
fn unorm16(c: f32) -> u16 {
    (f64::from(c).clamp(0.0, 1.0) * U16_STEPS).round() as u16
}

/// One vertex attribute of every primitive: `size` bytes per vertex (a
/// multiple of 4, as KHR_mesh_quantization aligns vertex elements), and
/// per primitive its bytes and its accessor (type and bounds; the view,
/// offset and count are filled in where it is laid out).
struct Column {
    size: usize,
    parts: Vec<(Vec<u8>, Value)>,
}

impl Column {
    /// `size` bytes per element from `f`, the same accessor for every primitive.
    fn each<T>(size: usize, data: &[&[T]], accessor: &Value, f: impl Fn(&T) -> Vec<u8>) -> Column {
        Column { size, parts: data.iter().map(|d| (d.iter().flat_map(&f).collect(), accessor.clone())).collect() }
    }
}

/// Lays `columns` out interleaved in one view, primitive after primitive,
/// and returns each primitive's accessors in column order. `filtered` is
/// what meshopt encodes instead, with the filter that decodes it.
fn push_columns(
    sink: &mut Sink,
    columns: &[Column],
    counts: &[usize],
    filtered: Option<(&'static str, Vec<u8>)>,
) -> Vec<Vec<usize>> {
    let stride: usize = columns.iter().map(|c| c.size).sum();
    let total: usize = counts.iter().sum();
    let mut bytes = Vec::with_capacity(stride * total);
    for (p, &n) in counts.iter().enumerate() {
        for v in 0..n {
            for c in columns {
                bytes.extend_from_slice(&c.parts[p].0[v * c.size..(v + 1) * c.size]);
            }
        }
    }
    let view = push_view(sink, &bytes, Some(stride));
    sink.streams.push(Stream { view, count: total, stride, triangles: false, vertices: total, filtered });
    let mut first = 0;
    let mut out = Vec::with_capacity(counts.len());
    for (p, &n) in counts.iter().enumerate() {
        let mut offset = first * stride;
        let mut accessors = Vec::with_capacity(columns.len());
        for c in columns {
            let mut accessor = c.parts[p].1.clone();
            accessor["bufferView"] = view.into();
            accessor["count"] = n.into();
            if offset > 0 {
                accessor["byteOffset"] = offset.into();
            }
            sink.accessors.push(accessor);
            accessors.push(sink.accessors.len() - 1);
            offset += c.size;
        }
        out.push(accessors);
        first += n;
    }
    out
}

/// A primitive's positions in u16 steps, with their per-axis bounds.
fn position_steps(frame: &Frame, p: &PrimData) -> (Vec<[u16; 3]>, Vec<f64>, Vec<f64>) {
    let q: Vec<[u16; 3]> = p.part.positions.iter().map(|v| frame.position(v)).collect();
    let (min, max) = bounds(q.iter().map(|v| v.map(f64::from)));
    (q, min, max)
}

/// POSITION: u16 steps, 8 bytes per vertex, with the primitive's bounds.
fn position_column(frame: &Frame, prims: &[PrimData]) -> Column {
    let parts = prims
        .iter()
        .map(|p| {
            let (q, min, max) = position_steps(frame, p);
            let (min, max): (Vec<u64>, Vec<u64>) =
                (min.iter().map(|&v| v as u64).collect(), max.iter().map(|&v| v as u64).collect());
            let bytes = q.iter().flat_map(|v| [v[0], v[1], v[2], 0].into_iter().flat_map(u16::to_le_bytes)).collect();
            (bytes, json!({"componentType": 5123, "type": "VEC3", "min": min, "max": max}))
        })
        .collect();
    Column { size: 8, parts }
}

/// POSITION for a chunk whose horizontal step is coarser than 1/256 of a
/// cell (one over 255 cells wide), through meshoptimizer's EXPONENTIAL
/// filter: the same step counts as f32 (12 bytes per vertex, decoded), each
/// encoded as a 24-bit mantissa in 1/256-cell units and an exponent that
/// scales it back. In u16 steps of 1/128 cell or coarser, a sample's x and
/// z low bytes carry the index's low bits, which the vertex codec pays for
/// (Fuji at 1 m, levels 0 and 1: 3.10 and 2.97 bytes per vertex for
/// positions alone, 2.56 and 2.46 this way; 2.30 at the 64-cell leaves);
/// in 1/256-cell units a sample's low byte is 0, as in a narrow chunk's.
/// Heights keep their steps (exponent 0). See [`exp_word`] for the range.
fn exp_position_column(frame: &Frame, prims: &[PrimData]) -> (Column, Vec<u8>) {
    let shift = frame.k.log2().round() as u32;
    let exp = |v: u16| exp_word(v, shift);
    let mut filtered = Vec::new();
    let parts = prims
        .iter()
        .map(|p| {
            // Whole step counts: the same JSON as f64 or f32.
            let (q, min, max) = position_steps(frame, p);
            let bytes = q.iter().flat_map(|v| v.map(f32::from).into_iter().flat_map(f32::to_le_bytes)).collect();
            for v in &q {
                let e = [exp(v[0]), exp_word(v[1], 8), exp(v[2])];
                filtered.extend(e.into_iter().flat_map(u32::to_le_bytes));
            }
            (bytes, json!({"componentType": 5126, "type": "VEC3", "min": min, "max": max}))
        })
        .collect();
    (Column { size: 12, parts }, filtered)
}

/// `steps` (a u16 count of 2^-`shift` cells) as one EXPONENTIAL-filter
/// word that decodes to exactly `steps`: the mantissa in 1/256-cell units
/// (`steps` · 2^(8 − shift)), the exponent undoing that. The mantissa is a
/// signed 24-bit number, so it is shifted by at most 7: only a chunk of
/// 32 768 cells or more (step 1 cell) keeps a low bit in its low byte.
fn exp_word(steps: u16, shift: u32) -> u32 {
    let up = 8u32.saturating_sub(shift).min(7);
    let mantissa = u32::from(steps) << up;
    ((-(up as i32) as i8 as u8 as u32) << 24) | mantissa
}

/// The morph target's POSITION: whole height steps in the narrowest type
/// that holds every primitive's (they share one view): i8 (4 bytes per
/// vertex), i16 (8) or f32 holding the same whole numbers (12). A leaf's
/// samples are within δ(L−1) = 2·max_error_m of its parent's surface, 32
/// steps of max_error_m/16 (Fuji's leaves: ±31), and i8 holds its deltas
/// without the i16 high byte that flips with every sign: meshoptimizer packs
/// them about a quarter tighter.
fn delta_column(frame: &Frame, prims: &[PrimData]) -> Column {
    let steps: Vec<Vec<i64>> = prims
        .iter()
        .map(|p| {
            p.part.positions.iter().zip(&p.part.morph_dy).map(|(q, dy)| frame.delta_steps(q[1], q[1] + dy)).collect()
        })
        .collect();
    let range = |d: &[i64]| (d.iter().copied().min().unwrap_or(0), d.iter().copied().max().unwrap_or(0));
    let (lo, hi) = range(&steps.concat());
    let (size, ctype) = if lo >= i64::from(i8::MIN) && hi <= i64::from(i8::MAX) {
        (4, 5120)
    } else if lo >= -32767 && hi <= 32767 {
        (8, 5122)
    } else {
        (12, 5126)
    };
    let parts = steps
        .iter()
        .map(|d| {
            let (lo, hi) = range(d);
            let bytes: Vec<u8> = match size {
                4 => d.iter().flat_map(|&v| [0, v as i8 as u8, 0, 0]).collect(),
                8 => d.iter().flat_map(|&v| [0, v as i16, 0, 0].into_iter().flat_map(i16::to_le_bytes)).collect(),
                _ => d.iter().flat_map(|&v| [0.0, v as f32, 0.0].into_iter().flat_map(f32::to_le_bytes)).collect(),
            };
            let accessor = if ctype == 5126 {
                let (lo, hi) = (lo as f32, hi as f32);
                json!({"componentType": ctype, "type": "VEC3", "min": [0.0, lo, 0.0], "max": [0.0, hi, 0.0]})
            } else {
                json!({"componentType": ctype, "type": "VEC3", "min": [0, lo, 0], "max": [0, hi, 0]})
            };
            (bytes, accessor)
        })
        .collect();
    Column { size, parts }
}

/// Writes the quantized vertex data (KHR_mesh_quantization) of the vertex
/// sets `prims` and the primitives `triangles` (each a set and its
/// triangles; one set per primitive, except `meshopt-v1`'s surface and
/// skirt, which share one) in three bufferViews, each holding every set in
/// turn, their accessors starting where their set does:
/// - the vertices, interleaved: POSITION (u16 steps, 8 bytes), the morph
///   delta (see `delta_column`), then TEXCOORD_0 (u16 normalized),
///   TANGENT (i8 normalized) and TEXCOORD_1 where the texture has them;
/// - NORMAL, i8 normalized, 4 bytes, in a view of its own because
///   meshopt's OCTAHEDRAL filter applies to a whole view: `meshopt` stores
///   the two octahedral coordinates (which its vertex codec packs tighter
///   than three components), `quantize` what the filter decodes them to, so
///   both read alike;
/// - the triangles, u16 (u32 for a set of more than 65 535 vertices). meshoptimizer's index codec keeps the triangles'
///   order but may rotate each one's corners; both modes write the
///   rotation it decodes to, so that `meshopt` decodes to exactly what
///   `quantize` writes. Where the skirt's indices start again at 0 the
///   codec restarts its vertex counter, so one stream costs no more than two.
///
/// Three views instead of one per stream and primitive shorten the JSON and
/// save each meshopt stream's header and tail. With `meshopt-v1`, a chunk
/// over 255 cells wide has a fourth, first: POSITION alone, through the
/// EXPONENTIAL filter (see `exp_position_column`). Returns each primitive's
/// `attributes`, index accessor and morph target accessor (its set's).
pub fn write_quantized(
    sink: &mut Sink,
    frame: &Frame,
    prims: &[PrimData],
    triangles: &[(usize, &[u32])],
    normals: NormalEncoding,
    codec: Option<Meshopt>,
) -> Vec<(Value, usize, usize)> {
    let counts: Vec<usize> = prims.iter().map(|p| p.part.positions.len()).collect();
    // meshopt-v1, a chunk over 255 cells wide: POSITION in a view of its
    // own, through the EXPONENTIAL filter (see `exp_position_column`).
    let exp_positions = (codec == Some(Meshopt::Khr) && frame.k < 256.0).then(|| {
        let (column, filtered) = exp_position_column(frame, prims);
        push_columns(sink, &[column], &counts, Some(("EXPONENTIAL", filtered)))
    });
    let mut columns = vec![delta_column(frame, prims)];
    let mut names = vec![""];
    if exp_positions.is_none() {
        columns.insert(0, position_column(frame, prims));
        names.insert(0, "POSITION");
    }
    let uv_accessor = json!({"componentType": 5123, "normalized": true, "type": "VEC2"});
    let uv_bytes = |t: &[f32; 2]| t.map(unorm16).into_iter().flat_map(u16::to_le_bytes).collect();
    let uvs: Option<Vec<&[[f32; 2]]>> = prims.iter().map(|p| p.uv.as_deref()).collect();
    if let Some(uv) = uvs {
        columns.push(Column::each(4, &uv, &uv_accessor, uv_bytes));
        names.push("TEXCOORD_0");
    }
    let tangents: Option<Vec<&[[f32; 4]]>> = prims.iter().map(|p| p.tangents.as_deref()).collect();
    if let Some(t) = tangents {
        let accessor = json!({"componentType": 5120, "normalized": true, "type": "VEC4"});
        columns.push(Column::each(4, &t, &accessor, |t| t.map(|c| snorm8(c) as u8).to_vec()));
        names.push("TANGENT");
    }
    let uv1: Option<Vec<&[[f32; 2]]>> = prims.iter().map(|p| p.uv1.as_deref()).collect();
    if let Some(uv) = uv1 {
        columns.push(Column::each(4, &uv, &uv_accessor, uv_bytes));
        names.push("TEXCOORD_1");
    }
    let vertex = push_columns(sink, &columns, &counts, None);

    // Normals through the octahedral filter, and what it decodes to.
    let unit: Vec<[f32; 3]> = prims.iter().flat_map(|p| p.normals.iter().copied()).collect();
    let (oct, decoded) = octahedral(&unit, normals);
    let mut first = 0;
    let mut parts = Vec::with_capacity(prims.len());
    for &n in &counts {
        let bytes = decoded[first..first + n].iter().flat_map(|v| v.map(|c| c as u8)).collect();
        parts.push((bytes, json!({"componentType": 5120, "normalized": true, "type": "VEC3"})));
        first += n;
    }
    let filtered = oct.iter().flat_map(|v| v.map(|c| c as u8)).collect();
    let normal = push_columns(sink, &[Column { size: 4, parts }], &counts, Some(("OCTAHEDRAL", filtered)));

    // Triangles, as the index codec rotates them.
    let all: Vec<u32> = triangles.iter().flat_map(|(_, t)| t.iter().copied()).collect();
    let vertices = counts.iter().copied().max().unwrap_or(0);
    let encoded = meshopt::encode_index_buffer(&all, vertices).expect("a triangle list");
    let rotated: Vec<u32> = meshopt::decode_index_buffer(&encoded, all.len()).expect("just encoded");
    // u16, or u32 for a set denser than u16 indices hold.
    let (bytes, component) = index_bytes(&rotated);
    let stride = if component == 5125 { 4 } else { 2 };
    let view = push_view(sink, &bytes, None);
    sink.streams.push(Stream { view, count: all.len(), stride, triangles: true, vertices, filtered: None });
    let mut first = 0;
    let mut out = Vec::with_capacity(triangles.len());
    for &(p, t) in triangles {
        let n = t.len();
        let mut accessor = json!({"bufferView": view, "componentType": component, "count": n, "type": "SCALAR"});
        if first > 0 {
            accessor["byteOffset"] = (stride * first).into();
        }
        sink.accessors.push(accessor);
        first += n;
        let mut attributes = json!({"NORMAL": normal[p][0]});
        if let Some(positions) = &exp_positions {
            attributes["POSITION"] = positions[p][0].into();
        }
        for (name, &a) in names.iter().zip(&vertex[p]) {
            if !name.is_empty() {
                attributes[*name] = a.into();
            }
        }
        let delta = names.iter().position(|n| n.is_empty()).expect("the morph delta column");
        out.push((attributes, sink.accessors.len() - 1, vertex[p][delta]));
    }
    out
}

/// Compresses every stream with meshoptimizer (`codec`'s extension): the
/// compressed bytes become the new binary chunk (buffer 0) and the views
/// keep their uncompressed layout in a fallback buffer 1 that holds no
/// data. Returns buffer 1's byte length.
///
/// The views could all start at 0 in buffer 1 (it needs only to be as long
/// as the longest), 40 bytes of JSON less per chunk, but MeshLab (tinygltf)
/// reads a buffer without `uri` as the GLB's binary chunk: it refuses the
/// file only while buffer 1 is longer than that chunk, and with the shorter
/// buffer it read compressed bytes as indices and crashed.
pub fn meshopt_pack(sink: &mut Sink, codec: Meshopt) -> usize {
    let mut packed = Vec::new();
    for s in &sink.streams {
        let view = &mut sink.views[s.view];
        let (offset, length) =
            (view["byteOffset"].as_u64().unwrap_or(0) as usize, view["byteLength"].as_u64().unwrap_or(0) as usize);
        let raw = s.filtered.as_ref().map_or(&sink.bin[offset..offset + length], |(_, f)| f.as_slice());
        let encoded = if s.triangles {
            meshopt::encode_index_buffer(&index_values(raw, s.stride), s.vertices).expect("a triangle list")
        } else {
            encode_vertices(raw, s.stride, codec)
        };
        align4(&mut packed);
        view["buffer"] = 1.into();
        let mut ext = json!({
            "buffer": 0, "byteLength": encoded.len(), "byteStride": s.stride,
            "count": s.count, "mode": if s.triangles { "TRIANGLES" } else { "ATTRIBUTES" },
        });
        if !packed.is_empty() {
            ext["byteOffset"] = packed.len().into();
        }
        if let Some((filter, _)) = &s.filtered {
            ext["filter"] = (*filter).into();
        }
        view["extensions"] = json!({ codec.extension(): ext });
        packed.extend_from_slice(&encoded);
    }
    align4(&mut packed);
    std::mem::replace(&mut sink.bin, packed).len()
}

/// The vertex strides the writer makes and the reader takes: multiples of 4
/// up to 32 bytes (POSITION 8, a morph delta up to 12, three 4-byte
/// texture attributes).
const MAX_STRIDE: usize = 32;

/// meshoptimizer's vertex codec in the version and at the level `codec` uses.
fn encode_vertices(raw: &[u8], stride: usize, codec: Meshopt) -> Vec<u8> {
    encode_vertex_stream(raw, stride, codec.vertex_level(), codec.vertex_version())
        .unwrap_or_else(|e| unreachable!("the writer's vertex strides are multiples of 4 up to {MAX_STRIDE}: {e}"))
}

/// meshoptimizer's vertex codec, `version` 0 or 1 at `level` 0..=3, over
/// elements of `stride` bytes (a multiple of 4 up to 32).
pub fn encode_vertex_stream(raw: &[u8], stride: usize, level: i32, version: i32) -> Result<Vec<u8>, String> {
    fn enc<const N: usize>(raw: &[u8], level: i32, version: i32) -> Result<Vec<u8>, String> {
        let v: Vec<Element<N>> = raw.chunks_exact(N).map(|c| Element(c.try_into().expect("N bytes"))).collect();
        meshopt::encode_vertex_buffer_level(&v, level, Some(version)).map_err(|e| format!("{e:?}"))
    }
    match stride {
        4 => enc::<4>(raw, level, version),
        8 => enc::<8>(raw, level, version),
        12 => enc::<12>(raw, level, version),
        16 => enc::<16>(raw, level, version),
        20 => enc::<20>(raw, level, version),
        24 => enc::<24>(raw, level, version),
        28 => enc::<28>(raw, level, version),
        MAX_STRIDE => enc::<MAX_STRIDE>(raw, level, version),
        _ => Err(format!("stride {stride} is not a multiple of 4 up to {MAX_STRIDE}")),
    }
}

/// One element: `[u8; N]` has no `Default` for every `N`.
#[derive(Clone, Copy)]
#[repr(transparent)]
struct Element<const N: usize>([u8; N]);

impl<const N: usize> Default for Element<N> {
    fn default() -> Self {
        Element([0; N])
    }
}

/// meshoptimizer's vertex decoder for `count` elements of `stride` bytes.
fn decode_vertices(data: &[u8], count: usize, stride: usize) -> Result<Vec<u8>, String> {
    fn dec<const N: usize>(data: &[u8], count: usize) -> Result<Vec<u8>, String> {
        let v = meshopt::decode_vertex_buffer::<Element<N>>(data, count).map_err(|e| format!("{e:?}"))?;
        Ok(v.iter().flat_map(|e| e.0).collect())
    }
    match stride {
        4 => dec::<4>(data, count),
        8 => dec::<8>(data, count),
        12 => dec::<12>(data, count),
        16 => dec::<16>(data, count),
        20 => dec::<20>(data, count),
        24 => dec::<24>(data, count),
        28 => dec::<28>(data, count),
        MAX_STRIDE => dec::<MAX_STRIDE>(data, count),
        _ => Err(format!("stride {stride} is not a multiple of 4 up to {MAX_STRIDE}")),
    }
}

/// How many times its own size a meshopt stream can decode to, with room
/// to spare: a vertex stream of zeros, the densest there is, decodes to
/// 1 023 times its size with codec version 1 (each byte lane of a
/// 256-vertex block costs two control bits), an index stream takes at least
/// a byte per triangle.
const MAX_EXPANSION: usize = 2048;

/// A meshopt-compressed buffer view's bytes, decoded by the codec its
/// `mode` names but not yet by its `filter`: `ext` is the view's
/// `EXT_meshopt_compression` or `KHR_meshopt_compression` object (`count`,
/// `byteStride`, `mode`), `data` its compressed bytes. Indices come out as
/// little-endian u16 or u32, as the stride says.
pub fn decode_stream(ext: &Value, data: &[u8]) -> Result<Vec<u8>, String> {
    let num = |x: &Value| x.as_u64().map_or(0, |n| n as usize);
    let (count, stride) = (num(&ext["count"]), num(&ext["byteStride"]));
    // The decoder allocates what the file claims before it reads a byte: a
    // claim no stream of this size can hold is refused first.
    if count.checked_mul(stride).is_none_or(|n| n > MAX_EXPANSION.saturating_mul(data.len()).saturating_add(65_536)) {
        return Err(format!("{count} elements of {stride} bytes cannot come from {} compressed bytes", data.len()));
    }
    let bad = |e: meshopt::Error| format!("meshopt cannot decode it: {e:?}");
    // meshoptimizer asserts this (an abort, not an error).
    if ext["mode"] == "TRIANGLES" && !count.is_multiple_of(3) {
        return Err(format!("{count} indices are not whole triangles"));
    }
    match (ext["mode"].as_str(), stride) {
        (Some("ATTRIBUTES"), _) => {
            decode_vertices(data, count, stride).map_err(|e| format!("meshopt cannot decode it: {e}"))
        }
        (Some("TRIANGLES"), 2) => Ok(meshopt::decode_index_buffer::<u16>(data, count)
            .map_err(bad)?
            .into_iter()
            .flat_map(u16::to_le_bytes)
            .collect()),
        (Some("TRIANGLES"), 4) => Ok(meshopt::decode_index_buffer::<u32>(data, count)
            .map_err(bad)?
            .into_iter()
            .flat_map(u32::to_le_bytes)
            .collect()),
        (mode, stride) => Err(format!("meshopt mode {mode:?} with stride {stride}")),
    }
}

// ------------------------------------------------------------------ reading

/// A compressed chunk as plain glTF, and the grid it was quantized to.
pub struct Decoded {
    /// The same chunk as a .glb with f32 vertex data, u32 indices and no
    /// node scale (folded into POSITION and the morph targets), which any
    /// glTF reader (the `gltf` crate included) opens.
    pub glb: Vec<u8>,
    /// The node scale: the quantization step per axis, metres.
    pub step_m: [f64; 3],
}

/// Decodes a `quantize`, `meshopt` or `meshopt-v1` .glb into plain glTF;
/// `None` for a file that uses none of their extensions.
pub fn decompress(bytes: &[u8]) -> Result<Option<Decoded>, String> {
    let glb = gltf::Glb::from_slice(bytes).map_err(|e| format!("not a GLB: {e}"))?;
    let mut json: Value = serde_json::from_slice(&glb.json).map_err(|e| format!("bad JSON: {e}"))?;
    let used: Vec<&str> = json["extensionsUsed"].as_array().into_iter().flatten().filter_map(Value::as_str).collect();
    if !used.iter().any(|e| *e == "KHR_mesh_quantization" || MESHOPT_EXTENSIONS.contains(e)) {
        return Ok(None);
    }
    let bin: &[u8] = glb.bin.as_deref().unwrap_or(&[]);
    let scale = match json["nodes"][0]["scale"].as_array() {
        Some(s) if s.len() == 3 => [0, 1, 2].map(|a| s[a].as_f64().unwrap_or(f64::NAN)),
        _ => [1.0; 3],
    };
    if !scale.iter().all(|s| s.is_finite()) {
        return Err("node scale is not three numbers".into());
    }
    // Which accessors are positions (scaled by the node) and which indices.
    let mut positions = std::collections::BTreeSet::new();
    let mut indices = std::collections::BTreeSet::new();
    for prim in
        json["meshes"].as_array().into_iter().flatten().flat_map(|m| m["primitives"].as_array().into_iter().flatten())
    {
        positions.extend(prim["attributes"]["POSITION"].as_u64());
        for t in prim["targets"].as_array().into_iter().flatten() {
            positions.extend(t["POSITION"].as_u64());
        }
        indices.extend(prim["indices"].as_u64());
    }
    let mut out = Sink::default();
    let mut cache: Vec<Option<Vec<u8>>> = vec![None; json["bufferViews"].as_array().map_or(0, Vec::len)];
    let accessors: Vec<Value> = json["accessors"].as_array().cloned().unwrap_or_default();
    for prim in primitives(&json) {
        let attributes = prim["attributes"].as_object().into_iter().flat_map(|o| o.values());
        let targets =
            prim["targets"].as_array().into_iter().flatten().flat_map(|t| t.as_object()).flat_map(|o| o.values());
        for a in attributes.chain(targets).chain(prim.get("indices")) {
            if a.as_u64().is_none_or(|a| a as usize >= accessors.len()) {
                return Err(format!("a primitive refers to accessor {a}, of {}", accessors.len()));
            }
        }
    }
    let mut plain: Vec<(Vec<f64>, usize)> = Vec::with_capacity(accessors.len());
    // The file's accessor each of `plain` comes from (itself, or the one a
    // primitive's own copy was cut from).
    let mut source: Vec<usize> = (0..accessors.len()).collect();
    for (a, acc) in accessors.iter().enumerate() {
        let (mut values, n) = read_accessor(&json, acc, bin, &mut cache).map_err(|e| format!("accessor {a}: {e}"))?;
        if positions.contains(&(a as u64)) && n == 3 {
            for (i, v) in values.iter_mut().enumerate() {
                *v *= scale[i % 3];
            }
        }
        plain.push((values, n));
    }
    // A primitive's vertices are those its triangles use: where primitives
    // share a vertex set (meshopt-v1's skirt tops are surface vertices),
    // each gets its own accessors holding only those, in vertex order.
    let mut users: BTreeMap<u64, usize> = BTreeMap::new();
    for prim in primitives(&json) {
        for a in prim["attributes"].as_object().into_iter().flat_map(|o| o.values().filter_map(Value::as_u64)) {
            *users.entry(a).or_default() += 1;
        }
    }
    let mut primitive_accessors = Vec::new();
    for prim in primitives(&json) {
        let own = prim["attributes"].as_object().into_iter().flat_map(|o| o.values().filter_map(Value::as_u64));
        if !own.clone().any(|a| users[&a] > 1) {
            primitive_accessors.push(None);
            continue;
        }
        let i = prim["indices"].as_u64().ok_or("a primitive sharing vertices has no indices")? as usize;
        let idx = plain.get(i).ok_or_else(|| format!("accessor {i} does not exist"))?.0.clone();
        let targets = prim["targets"].as_array().into_iter().flatten().flat_map(|t| t["POSITION"].as_u64());
        let count = own
            .clone()
            .chain(targets.clone())
            .map(|a| plain.get(a as usize).map_or(0, |(v, n)| v.len() / n))
            .min()
            .unwrap_or(0);
        let mut remap = vec![None; count];
        for &v in &idx {
            *remap.get_mut(v as usize).ok_or("an index past the vertices")? = Some(0.0);
        }
        let mut next = 0.0;
        let kept: Vec<usize> = (0..count).filter(|&v| remap[v].is_some()).collect();
        for &v in &kept {
            remap[v] = Some(next);
            next += 1.0;
        }
        let mut map = BTreeMap::new();
        for a in own.chain(targets) {
            let (values, n) = plain.get(a as usize).ok_or_else(|| format!("accessor {a} does not exist"))?;
            let vals = kept.iter().flat_map(|&v| values[v * n..(v + 1) * n].iter().copied()).collect();
            map.insert(a, plain.len());
            plain.push((vals, *n));
            source.push(a as usize);
        }
        map.insert(i as u64, plain.len());
        plain.push((idx.iter().map(|&v| remap[v as usize].expect("marked above")).collect(), 1));
        source.push(i);
        primitive_accessors.push(Some(map));
    }
    for (a, (values, n)) in plain.iter().enumerate() {
        let acc = &accessors[source[a]];
        align4(&mut out.bin);
        let offset = out.bin.len();
        let count = values.len() / n.max(&1);
        if indices.contains(&(source[a] as u64)) {
            for v in values {
                out.bin.extend_from_slice(&(*v as u32).to_le_bytes());
            }
            out.views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": values.len() * 4, "target": 34963}));
            out.accessors.push(
                json!({"bufferView": out.views.len() - 1, "componentType": 5125, "count": count, "type": "SCALAR"}),
            );
            continue;
        }
        let scaled = positions.contains(&(source[a] as u64)) && *n == 3;
        let f: Vec<f32> = values.iter().map(|&v| v as f32).collect();
        for v in &f {
            out.bin.extend_from_slice(&v.to_le_bytes());
        }
        out.views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": f.len() * 4, "target": 34962}));
        let mut accessor =
            json!({"bufferView": out.views.len() - 1, "componentType": 5126, "count": count, "type": acc["type"]});
        if scaled {
            let (lo, hi) = bounds(f.chunks_exact(3).map(|c| [0, 1, 2].map(|k| f64::from(c[k]))));
            accessor["min"] = lo.iter().map(|&v| v as f32).collect::<Vec<_>>().into();
            accessor["max"] = hi.iter().map(|&v| v as f32).collect::<Vec<_>>().into();
        }
        out.accessors.push(accessor);
    }
    for (p, map) in primitive_accessors.iter().enumerate() {
        let Some(map) = map else { continue };
        let prim = primitive_mut(&mut json, p);
        for slot in prim["attributes"].as_object_mut().into_iter().flat_map(|o| o.values_mut()) {
            *slot = map[&slot.as_u64().expect("read above")].into();
        }
        for t in prim["targets"].as_array_mut().into_iter().flatten().filter_map(Value::as_object_mut) {
            if let Some(slot) = t.get_mut("POSITION") {
                *slot = map[&slot.as_u64().expect("checked above")].into();
            }
        }
        prim["indices"] = map[&prim["indices"].as_u64().expect("read above")].into();
    }
    let images = json["images"].as_array().cloned().unwrap_or_default();
    for (i, img) in images.iter().enumerate() {
        if let Some(v) = img["bufferView"].as_u64() {
            let bytes = view_bytes(&json, v as usize, bin, &mut cache)?.to_vec();
            align4(&mut out.bin);
            out.views.push(json!({"buffer": 0, "byteOffset": out.bin.len(), "byteLength": bytes.len()}));
            out.bin.extend_from_slice(&bytes);
            json["images"][i]["bufferView"] = (out.views.len() - 1).into();
        }
    }
    let root = json.as_object_mut().expect("a glTF document is an object");
    root.remove("extensionsUsed");
    root.remove("extensionsRequired");
    if let Some(node) = json.get_mut("nodes").and_then(|n| n.get_mut(0)).and_then(Value::as_object_mut) {
        node.remove("scale");
    }
    json["accessors"] = out.accessors.into();
    json["bufferViews"] = out.views.into();
    json["buffers"] = json!([{"byteLength": out.bin.len()}]);
    let text = serde_json::to_vec(&json).expect("JSON of plain values");
    Ok(Some(Decoded { glb: super::gltf::glb(&text, &out.bin), step_m: scale }))
}

/// Every primitive of every mesh, in order.
fn primitives(json: &Value) -> impl Iterator<Item = &Value> {
    json["meshes"].as_array().into_iter().flatten().flat_map(|m| m["primitives"].as_array().into_iter().flatten())
}

/// The `p`-th primitive of [`primitives`], to rewrite.
fn primitive_mut(json: &mut Value, p: usize) -> &mut Value {
    json["meshes"]
        .as_array_mut()
        .into_iter()
        .flatten()
        .flat_map(|m| m["primitives"].as_array_mut().into_iter().flatten())
        .nth(p)
        .expect("counted by primitives()")
}

/// The bytes of bufferView `v`, decoded if meshopt compressed them.
fn view_bytes<'c>(json: &Value, v: usize, bin: &[u8], cache: &'c mut [Option<Vec<u8>>]) -> Result<&'c [u8], String> {
    if v >= cache.len() {
        return Err(format!("bufferView {v} does not exist"));
    }
    if cache[v].is_none() {
        let view = &json["bufferViews"][v];
        let num = |x: &Value| x.as_u64().map(|n| n as usize);
        let slice = |off: usize, len: usize| {
            off.checked_add(len)
                .and_then(|end| bin.get(off..end))
                .ok_or_else(|| format!("bufferView {v} lies outside the binary chunk"))
        };
        let bytes = match MESHOPT_EXTENSIONS.iter().find_map(|e| view["extensions"].get(e)) {
            Some(m) => {
                if num(&m["buffer"]) != Some(0) {
                    return Err(format!("bufferView {v}: compressed data outside the binary chunk"));
                }
                let filter = m["filter"].as_str().unwrap_or("NONE");
                if !["NONE", "OCTAHEDRAL", "EXPONENTIAL"].contains(&filter) {
                    return Err(format!("bufferView {v}: meshopt filter {filter} is not supported"));
                }
                let stride = num(&m["byteStride"]).unwrap_or(0);
                let data = slice(num(&m["byteOffset"]).unwrap_or(0), num(&m["byteLength"]).unwrap_or(0))?;
                let decoded = decode_stream(m, data).map_err(|e| format!("bufferView {v}: {e}"))?;
                match (filter, stride) {
                    ("OCTAHEDRAL", 4) => {
                        let mut oct: Vec<[i8; 4]> =
                            decoded.chunks_exact(4).map(|c| [0, 1, 2, 3].map(|k| c[k] as i8)).collect();
                        meshopt::decode_filter_oct(&mut oct);
                        oct.iter().flat_map(|v| v.map(|c| c as u8)).collect()
                    }
                    ("OCTAHEDRAL", _) => return Err(format!("bufferView {v}: OCTAHEDRAL filter with stride {stride}")),
                    ("EXPONENTIAL", _) if stride.is_multiple_of(4) => {
                        let mut words: Vec<[u32; 1]> =
                            decoded.chunks_exact(4).map(|c| [u32::from_le_bytes([c[0], c[1], c[2], c[3]])]).collect();
                        meshopt::decode_filter_exp(&mut words);
                        words.iter().flat_map(|w| w[0].to_le_bytes()).collect()
                    }
                    ("EXPONENTIAL", _) => {
                        return Err(format!("bufferView {v}: EXPONENTIAL filter with stride {stride}"));
                    }
                    _ => decoded,
                }
            }
            None if num(&view["buffer"]) == Some(0) => {
                slice(num(&view["byteOffset"]).unwrap_or(0), num(&view["byteLength"]).unwrap_or(0))?.to_vec()
            }
            None => return Err(format!("bufferView {v} refers to a buffer without data")),
        };
        cache[v] = Some(bytes);
    }
    Ok(cache[v].as_deref().expect("filled above"))
}

/// An accessor's values as f64 (normalized integers mapped to [−1, 1] or
/// [0, 1]), and the number of components per element.
fn read_accessor(
    json: &Value,
    acc: &Value,
    bin: &[u8],
    cache: &mut [Option<Vec<u8>>],
) -> Result<(Vec<f64>, usize), String> {
    let (n, size) = super::gltf::accessor_layout(acc)?;
    // Matrices hold nothing terrachunk writes (and a MAT2 of byte
    // components, four to the layout table, pads its columns).
    if acc["type"].as_str().is_some_and(|t| t.starts_with("MAT")) {
        return Err(format!("type {}", acc["type"]));
    }
    let ctype = acc["componentType"].as_u64().unwrap_or(0);
    let count = acc["count"].as_u64().ok_or("no count")? as usize;
    let normalized = acc["normalized"].as_bool().unwrap_or(false);
    let v = acc["bufferView"].as_u64().ok_or("no bufferView")? as usize;
    let stride = json["bufferViews"][v]["byteStride"].as_u64().map_or(n * size, |s| s as usize);
    if stride < n * size {
        return Err(format!("byteStride {stride} is shorter than its {}-byte elements", n * size));
    }
    let offset = acc["byteOffset"].as_u64().unwrap_or(0) as usize;
    let data = view_bytes(json, v, bin, cache)?;
    let end = (count.max(1) - 1)
        .checked_mul(stride)
        .and_then(|e| e.checked_add(offset))
        .and_then(|e| e.checked_add(n * size));
    if count > 0 && end.is_none_or(|e| e > data.len()) {
        return Err("reaches past its bufferView".into());
    }
    let mut out = Vec::with_capacity(count * n);
    for i in 0..count {
        for c in 0..n {
            let b = &data[offset + i * stride + c * size..];
            let x = match ctype {
                5120 => f64::from(b[0] as i8),
                5121 => f64::from(b[0]),
                5122 => f64::from(i16::from_le_bytes([b[0], b[1]])),
                5123 => f64::from(u16::from_le_bytes([b[0], b[1]])),
                5125 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                _ => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            };
            out.push(match (normalized, ctype) {
                (true, 5120) => (x / 127.0).max(-1.0),
                (true, 5121) => x / 255.0,
                (true, 5122) => (x / 32767.0).max(-1.0),
                (true, 5123) => x / 65535.0,
                _ => x,
            });
        }
    }
    Ok((out, n))
}

/// How close to a triangle, in cells, a sample counts as under it, as
/// `verify` takes it. Strictly inside only, California at 1 m (cut points
/// on the grid) had 152 chunks meshed again and 151 reported over δ, where
/// `verify` found every level within δ; with this tolerance, 1 and none.
const UNDER_CELLS: f64 = 1e-4;

/// Visits each valid sample within [`UNDER_CELLS`] of triangle `tri` (grid
/// coordinates, within its bounding box) with its index in the grid and
/// |plane − sample|.
fn near_samples(grid: &Grid, tri: &[MeshVertex; 3], mut visit: impl FnMut(usize, f64)) {
    let [a, b, d] = tri;
    let rows = (a.z.min(b.z).min(d.z).ceil().max(0.0), a.z.max(b.z).max(d.z).floor().min((grid.height - 1) as f64));
    let cols = (a.x.min(b.x).min(d.x).ceil().max(0.0), a.x.max(b.x).max(d.x).floor().min((grid.width - 1) as f64));
    points_near_triangle(tri, rows, cols, UNDER_CELLS, |i, j, h| {
        let k = i * grid.width + j;
        let sample = grid.heights[k];
        if !sample.is_nan() {
            visit(k, (h - f64::from(sample)).abs());
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The vertex codec's two ends agree at every stride the writer uses
    /// and in both versions, and a view the reader cannot decode says why.
    /// Matrix accessors are refused, as before the layout table was shared:
    /// to that table a MAT2 has four components, like a VEC4.
    #[test]
    fn a_matrix_accessor_is_refused() {
        let json = serde_json::json!({"bufferViews": [{"buffer": 0, "byteLength": 16}]});
        let bin = [0u8; 16];
        let acc = |ty: &str| serde_json::json!({"bufferView": 0, "componentType": 5126, "count": 1, "type": ty});
        let read = |ty: &str| read_accessor(&json, &acc(ty), &bin, &mut [None]);
        assert_eq!(read("VEC4").unwrap(), (vec![0.0; 4], 4));
        let e = read("MAT2").unwrap_err();
        assert!(e.contains("MAT2"), "{e}");
    }

    #[test]
    fn a_vertex_stream_decodes_to_what_was_encoded() {
        for stride in (4..=MAX_STRIDE).step_by(4) {
            let raw: Vec<u8> = (0..stride * 37).map(|k| (k * 7 % 251) as u8).collect();
            for version in [0, 1] {
                let data = encode_vertex_stream(&raw, stride, 3, version).expect("a stride the writer uses");
                let ext = json!({"count": 37, "byteStride": stride, "mode": "ATTRIBUTES"});
                assert_eq!(decode_stream(&ext, &data).expect("decodes"), raw, "stride {stride}, version {version}");
            }
        }
        assert!(encode_vertex_stream(&[0; 6], 6, 3, 1).unwrap_err().contains("stride 6"));
        let odd = json!({"count": 3, "byteStride": 1, "mode": "TRIANGLES"});
        assert_eq!(decode_stream(&odd, &[]).unwrap_err(), "meshopt mode Some(\"TRIANGLES\") with stride 1");
    }

    /// `cut_error` with an acceptable error: exact wherever the chunk is
    /// over it, at most it where the chunk is within it, so the caller's
    /// comparison comes out as it would on the exact value. Measured on the
    /// children and grandchildren of a steep, rough grid whose cut points
    /// were left where the lines cross (as before the mesher placed them on
    /// the quantize grid), so the file moves every one sideways; meshed as
    /// the pipeline does, with them on the grid, the same chunks have
    /// nothing to move and are within δ as written.
    #[test]
    fn cut_error_is_exact_over_what_the_caller_accepts() {
        use crate::heightfield::Heightfield;
        use crate::mesh::decimate::{ChunkSpec, DividingLines, build_chunk};
        use crate::quadtree::ChunkKey;
        let (w, h) = (257usize, 257usize);
        let heights: Vec<f32> = (0..w * h)
            .map(|k| {
                let (x, z) = ((k % w) as f64, (k / w) as f64);
                let hash = ((k as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40) as f64 / f64::from(1u32 << 24);
                (900.0 * (x / 7.0).sin() * (z / 11.0).cos() + 4.0 * x + 20.0 * hash) as f32
            })
            .collect();
        let hf = Heightfield {
            width: w,
            height: h,
            heights,
            spacing_m: [30.0, 30.0],
            georef: Default::default(),
            source: "test".into(),
        };
        let tree = ChunkTree::plan(w, h, 2.0, 64, 0);
        let q = Quantization::plan(&hf, &tree, 2.0).unwrap();
        let grid = Grid::new(w, h, &hf.heights, None);
        let root_key = ChunkKey { level: 0, x: 0, y: 0 };
        let (mut measured, mut moved, mut over) = (0, 0, 0);
        for on_grid in [false, true] {
            let mesh = |key: ChunkKey, parent: Option<&crate::mesh::ChunkMesh>| {
                let level = key.level as usize;
                let spec = ChunkSpec {
                    key,
                    footprint: tree.footprint(key),
                    delta_m: tree.delta_m[level],
                    parent,
                    keep_parent_edges: true,
                    max_vertices: crate::config::MAX_CHUNK_VERTICES as usize,
                    dividing_lines: if tree.splits(key.level) { DividingLines::Children } else { DividingLines::None },
                    split_insertion: false,
                    cancel: None,
                    cut_share: crate::mesh::decimate::CUT_SHARE,
                    cut_lattice: on_grid.then_some(q.shift[level]),
                    height_step: Some(q.step_y_m),
                    thin: false,
                };
                build_chunk(&grid, &spec).unwrap()
            };
            let root = mesh(root_key, None);
            for child in tree.children(root_key) {
                let m = mesh(child, Some(&root));
                let grandchildren: Vec<_> = tree.children(child).into_iter().map(|g| mesh(g, Some(&m))).collect();
                for m in std::iter::once(&m).chain(&grandchildren) {
                    let delta = m.delta_m;
                    let chunk = crate::pipeline::assemble(&grid, hf.spacing_m, m, delta);
                    let exact = q.cut_error(&chunk, &grid, -1.0).unwrap();
                    if on_grid {
                        assert!(exact <= delta, "{:?}: {exact} m as written, δ {delta}", m.key);
                        continue;
                    }
                    measured += 1;
                    moved += usize::from(exact > 0.0);
                    over += usize::from(exact > delta);
                    for within in [0.0, exact / 2.0, exact, 2.0 * exact, delta] {
                        let got = q.cut_error(&chunk, &grid, within).unwrap();
                        if exact > within {
                            assert_eq!(got, exact, "{:?} within {within}", m.key);
                        } else {
                            assert!(got <= within, "{:?}: {got} over {within}", m.key);
                        }
                    }
                }
            }
        }
        // Every chunk has cut points; in one of them no sample under their
        // triangles moves off its surface.
        assert_eq!(measured, 20);
        assert!(moved >= 18, "{moved} of {measured} chunks had samples under moved triangles");
        eprintln!("{over} of {measured} chunks with their cut points moved are over δ as written");
    }

    /// Every u16 step count at every horizontal step decodes, through
    /// meshoptimizer's own EXPONENTIAL decoder, to itself; a sample of a
    /// chunk up to 32 767 cells wide lands on a mantissa whose low byte is
    /// 0 (what makes the filter worth it); and the mantissa never reaches
    /// the sign bit (the widest chunks' 65 535 steps once would have).
    #[test]
    fn exponential_position_words_decode_exactly() {
        for shift in 0..=8u32 {
            let mut words: Vec<[u32; 1]> = (0..=u16::MAX).map(|v| [exp_word(v, shift)]).collect();
            assert!(words.iter().all(|w| w[0] & 0x0080_0000 == 0), "shift {shift}: a negative mantissa");
            if shift >= 1 {
                let per_cell = 1u32 << shift;
                assert!((0..=u16::MAX).step_by(per_cell as usize).all(|v| exp_word(v, shift) & 0xff == 0));
            }
            meshopt::decode_filter_exp(&mut words);
            for (v, w) in words.iter().enumerate() {
                assert_eq!(f32::from_bits(w[0]), v as f32, "shift {shift}, {v} steps");
            }
        }
    }
}
