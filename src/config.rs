//! Settings: `pipeline.toml` and the command line, merged into one validated
//! [`Config`]. Unknown keys are rejected, so a typo never goes unnoticed.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The meshoptimizer extension the quantized streams are compressed for
/// (`output::compress` holds the codecs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Meshopt {
    /// EXT_meshopt_compression (`compress = "meshopt"`): vertex codec
    /// version 0, the only one it allows.
    Ext,
    /// KHR_meshopt_compression (`compress = "meshopt-v1"`): vertex codec
    /// version 1.
    Khr,
}

/// How quantized normals are chosen for meshoptimizer's OCTAHEDRAL filter,
/// which stores two octahedral coordinates of `bits` bits in i8 components
/// and decodes them to an i8 normalized unit vector (worst angles per
/// encoding and bit count: docs/compression.md).
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

/// Every pipeline setting, with its unit. Defaults match `pipeline.toml`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// δ of the deepest level: the largest vertical error, in metres, of the
    /// finest chunks against any valid DEM sample. Range: > 0. Default 1.
    pub max_error_m: f64,
    /// Largest screen-space error, in pixels, the runtime may use; textures
    /// are sized from it (T_g ≤ δ/τ_max). Range: > 0. Default 2.
    pub tau_max_px: f64,
    /// Worker threads; 0 = one per core. Range: 0..=[`MAX_THREADS`]. Default 0.
    pub threads: usize,
    /// The most memory a build may hold, as a size (`"2GB"`, `"256MB"`,
    /// `"1.5GiB"`; `"none"`: no limit). Whole-grid arrays larger than an
    /// eighth of it live in mapped scratch files beside the output
    /// ([`crate::store`]); the tileset is the same bytes. Default `"2GB"`.
    pub memory_limit: String,
    /// Multiplier applied to every height (e.g. 0.3048 for feet). Range:
    /// finite, ≠ 0. Default 1.
    pub vertical_scale: f64,
    /// Override the ground spacing, metres `[s_x, s_z]`. Range:
    /// [`SPACING_M`] on each axis (the grid's extent is checked too, once
    /// its size is known: `pipeline::MAX_EXTENT_M`). Default: the file's own
    /// (1 m for files without a georeference).
    pub spacing_m: Option<[f64; 2]>,
    /// Widest a deepest-level chunk may be, in grid cells. Range: 2..=4096.
    /// Up to [`dense_leaf_cells`]`(max_chunk_vertices)` always works (250
    /// at the default: a 251² chunk at full density, plus the cut points
    /// on its borders, still fits; 1 018 at 1 048 575); a wider leaf that needs more than
    /// `max_chunk_vertices` to meet `max_error_m` stops the build with an
    /// error that says so. Default: unset, chosen from the data (the
    /// shallowest tree whose chunks hold at most 8 000 vertices on average).
    pub leaf_cells: Option<u32>,
    /// Widest a top-level chunk may be, in grid cells. Range: 2..=65536.
    /// Set, the grid is cut into as many top-level chunks as that takes (a
    /// forest of trees under the tileset's root), so the tree has fewer
    /// levels above the leaves: each level binds every level below it to
    /// its edges, and fewer of them leave the leaves fewer triangles and the
    /// tileset fewer bytes (California's 4097² crop at 5 m: 1.239 → 1.0×
    /// pydelatin's leaf triangles with 512, docs/settings.md, "Top-level chunks"), at
    /// the cost of a far view that draws all the top-level chunks at their
    /// δ. Default: unset, one top-level chunk (two or more only where the
    /// grid is at least 1.5 times as wide as tall, or tall as wide).
    pub root_cells: Option<u32>,
    /// Most surface vertices one chunk may hold. A coarse chunk that would
    /// need more to meet its δ (rough ground against a small error) makes
    /// the build add refine levels: levels at the bottom that keep the
    /// leaves' footprint and halve δ, so that every δ above doubles and the
    /// top chunks get sparse. A chunk of more than 65 535 vertices has u32
    /// indices, the others u16. Range: 65 535..=16 777 215. Default
    /// [`MAX_CHUNK_VERTICES`] (docs/settings.md).
    pub max_chunk_vertices: u32,
    /// Which levels the mesher thins after its greedy insertion (step 5:
    /// free vertices the finished TIN no longer needs are collapsed onto a
    /// neighbour where every sample stays within δ). Default `leaves` (the
    /// deepest level: the finest surface, nearly as fast as none); `all`
    /// also thins every coarser level (fewer triangles and bytes over all
    /// levels, about a third more meshing time); `none` (docs/settings.md, "Thinning").
    pub thin: Thin,
    /// How each chunk's triangles are ordered for the GPU's post-transform
    /// vertex cache (meshoptimizer). Default: unset, which means `strip`
    /// with `compress = "meshopt"` and `fast` otherwise
    /// ([`Config::triangle_order`]).
    pub vertex_cache: Option<VertexCache>,
    /// Build every chunk down to the deepest level, even below one that
    /// already meets `max_error_m` (flat ground). For measuring what the
    /// error-bounded tree saves (`terrachunk bench --savings`); the output is
    /// as valid, only larger. Default false.
    pub complete_tree: bool,
    /// Most tiles one index file holds. A tree with more has its subtrees
    /// under one level written as external tilesets beside `tileset.json`
    /// (3D Tiles 1.1; `tileset-L-x-y.json`), so that a client reads the
    /// index a piece at a time. Range: 1..=16 777 216. Default
    /// [`INDEX_TILES`].
    pub index_tiles: usize,
    /// Widest a chunk's texture may be, in texels per side. Where a chunk
    /// would need more to keep T_g ≤ δ/τ_max, the cap wins and the build
    /// says so (the bound then does not hold for that level). Range:
    /// 2..=16384. Default 512.
    pub max_texture_px: u32,
    /// How texture tiles are stored in the .glb: `png` (exact) or `jpeg`
    /// (smaller, lossy). Default `png`.
    pub texture_format: TextureFormat,
    /// JPEG quality, 1..=100 (used with `texture_format = "jpeg"`). Default 85.
    pub jpeg_quality: u8,
    /// Resolution of the generated colour map (no `--texture` image), in
    /// texels per DEM sample spacing: 1 = one texel per sample, 2 = twice as
    /// fine. Range: 0.125..=8. Default 1.
    pub hillshade_multiple: f64,
    /// Direction the sun shines from for the generated hillshade, degrees
    /// clockwise from north. Range: 0..360. Default 315 (north-west).
    pub sun_azimuth_deg: f64,
    /// Sun height above the horizon for the generated hillshade, degrees.
    /// Range: > 0 and ≤ 90. Default 45.
    pub sun_elevation_deg: f64,
    /// Also write a tangent-space normal map from the full-resolution DEM
    /// into every chunk (`normalTexture`). Default false.
    pub normal_map: bool,
    /// How vertex data is stored in the .glb (see `output::compress`):
    /// `none` (f32, opens everywhere), `quantize` (KHR_mesh_quantization:
    /// integer positions on a world-aligned grid whose rounding is taken out
    /// of every level's δ), `meshopt` (quantize, then
    /// EXT_meshopt_compression) or `meshopt-v1` (quantize, then
    /// KHR_meshopt_compression with the version 1 vertex codec). Default
    /// `none`.
    pub compress: Compress,
    /// Bits per octahedral coordinate of quantized normals (meshoptimizer's
    /// OCTAHEDRAL filter in i8 components), each normal stored as the
    /// lattice point whose decoded normal is nearest it: fewer bits pack
    /// tighter and shade coarser (worst 0.71° at 8 bits, 1.45° at 7, 2.58° at
    /// 6 on Fuji). Range: 2..=8. Default: unset, which means
    /// [`NORMAL_BITS_V1`] with `compress = "meshopt-v1"` and, for `quantize`
    /// and `meshopt`, 8 bits rounded as meshoptimizer's encoder rounds them,
    /// as earlier versions wrote them (worst 1.14°)
    /// ([`Config::normal_encoding`]). Unused with `compress = "none"`.
    pub normal_bits: Option<u32>,
    /// Which mesher makes each chunk's surface: `rtin` (the right-triangle
    /// bintree, `mesh::rtin`: right-isosceles triangles only, chunks on
    /// squares of 2^k cells, no slivers) or `tin` (greedy insertion,
    /// `mesh::decimate`: fewer triangles, slivers on flat ground). Default
    /// `rtin`.
    pub mesher: Mesher,
    /// The frame a georeferenced grid's chunks are written in: `flat`
    /// (grid metres on the tangent plane at the grid centre), `curved`
    /// (every vertex at its WGS 84 position, `geodesy::Globe`; needs
    /// `mesher = "rtin"` and `compress = "none"`), or `auto`: curved where
    /// the flat frame would draw a sample farther than a quarter of
    /// `max_error_m` from its place on the ellipsoid and those settings
    /// allow it, else flat. Default `auto`.
    pub frame: Frame,
}

/// The frame of a placed tileset's chunks ([`Config::frame`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Frame {
    /// Curved where the flat frame's error is over a quarter of the leaf δ.
    #[default]
    Auto,
    /// Grid metres on the tangent plane at the centre.
    Flat,
    /// Every vertex at its WGS 84 position.
    Curved,
}

/// The share of `max_error_m` the flat frame's distance from the ellipsoid
/// may reach before `frame = "auto"` writes the curved frame.
pub const FLAT_FRAME_SHARE: f64 = 0.25;

/// Which mesher makes the chunks ([`Config::mesher`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Mesher {
    /// Right-triangle bintree with true errors (`mesh::rtin`).
    #[default]
    Rtin,
    /// Greedy insertion TIN, nested in the parent's (`mesh::decimate`).
    Tin,
}

/// The default [`Config::index_tiles`]: an index file of 16 384 tiles is
/// about 6 MB of JSON.
pub const INDEX_TILES: usize = 16_384;

/// The default [`Config::max_chunk_vertices`]: 65 535, what u16 indices
/// hold, so every chunk stays small enough to cull and page finely. A dense
/// top chunk of rough ground at a small error then makes refine levels,
/// which keep the top of the tree coarse for its footprint. Allowing
/// 2^20 − 1 drops them: California
/// at 1 m in 7 levels and 10 922 chunks instead of 9 and 27 270, 11 % fewer
/// surface vertices and 15 % fewer bytes, but every δ above the leaves
/// then sat on a footprint four times wider, and the viewer's cut along
/// `docs/flythrough_california.json` drew 3.6 times the triangles (1.56 M
/// against 428 k) and 3.3 times the file bytes per frame (docs/settings.md). Larger limits stay a setting.
pub const MAX_CHUNK_VERTICES: u32 = 65_535;

/// The most worker threads a build may ask for: more than any machine's
/// cores, and few enough that their stacks fit an ordinary address space.
pub const MAX_THREADS: usize = 1024;

/// The range of `spacing_m`, metres: from a millimetre (finer than any
/// terrain survey) to 100 km (coarser than any global DEM), so that chunk
/// extents stay where f32 chunk-local positions carry them and geometric
/// errors and transforms stay finite.
pub const SPACING_M: std::ops::RangeInclusive<f64> = 1e-3..=1e5;

/// The widest leaf, in cells, that holds every sample of its footprint and
/// the cut points on its four borders (up to about 10 per border cell, 2.5
/// on each) within `max_vertices`: 250 for the default 65 535, 1 018 for
/// 1 048 575.
pub fn dense_leaf_cells(max_vertices: u32) -> u32 {
    let fits = |c: u64| (c + 1) * (c + 1) + 10 * c <= u64::from(max_vertices);
    let mut c = (f64::from(max_vertices).sqrt() as u64).saturating_sub(1);
    while c > 0 && !fits(c) {
        c -= 1;
    }
    while fits(c + 1) {
        c += 1;
    }
    c as u32
}

/// The octahedral bits of `meshopt-v1` normals: the fewest whose decoded
/// normals stay within 1° of the exact ones (0.71° worst on Fuji, 1.45° at
/// 7 bits; docs/compression.md).
pub const NORMAL_BITS_V1: u32 = 8;

/// How a chunk's vertex data is stored. Measured figures are in
/// docs/compression.md.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Compress {
    /// f32 positions, normals, morph deltas and texture coordinates: the
    /// portable output every glTF reader opens.
    #[default]
    None,
    /// KHR_mesh_quantization (required): u16 positions on a world-aligned
    /// grid, the node's `scale` holding the step; i8 normals; i8 (or i16)
    /// morph deltas; u16 normalized texture coordinates.
    Quantize,
    /// `Quantize`, then every vertex and index stream through
    /// meshoptimizer's codecs (EXT_meshopt_compression, required; vertex
    /// codec version 0), for every meshopt reader.
    Meshopt,
    /// `Quantize`, then every vertex and index stream through
    /// meshoptimizer's codecs (KHR_meshopt_compression, required; vertex
    /// codec version 1), normals the nearest [`NORMAL_BITS_V1`]-bit
    /// octahedral lattice points, and a leaner JSON: the smallest output,
    /// for readers that know KHR_meshopt_compression (CesiumJS from 1.143).
    #[serde(rename = "meshopt-v1")]
    #[value(name = "meshopt-v1")]
    MeshoptV1,
}

impl Compress {
    /// Whether vertex data is quantized (every mode but `none`).
    pub fn quantizes(self) -> bool {
        self != Compress::None
    }

    /// The meshoptimizer extension the quantized streams are packed for.
    pub fn meshopt(self) -> Option<Meshopt> {
        match self {
            Compress::None | Compress::Quantize => None,
            Compress::Meshopt => Some(Meshopt::Ext),
            Compress::MeshoptV1 => Some(Meshopt::Khr),
        }
    }
}

/// Which levels the mesher thins after greedy insertion
/// ([`Config::thin`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Thin {
    /// No level.
    None,
    /// The deepest level.
    #[default]
    Leaves,
    /// Every level.
    All,
}

impl Thin {
    /// Whether a level is thinned (`deepest`: it has no children).
    pub fn level(self, deepest: bool) -> bool {
        match self {
            Thin::None => false,
            Thin::Leaves => deepest,
            Thin::All => true,
        }
    }
}

/// Triangle order for the vertex cache. Measured on 1 m SRTM chunks (average
/// transformed vertices per triangle, 16-entry FIFO; 0.5 is ideal, the
/// mesher's own order gives 2.0): `Fast` 0.94, `Best` 0.68, while `Best`
/// costs about a fifth of the whole build. On Fuji at 1 m: `Fast` 0.80,
/// `Best` 0.63, `Strip` 0.66, `Strip` and `Best` taking the same time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum VertexCache {
    /// meshoptimizer's `optimizeVertexCacheFifo` for a 16-entry cache.
    #[default]
    Fast,
    /// meshoptimizer's table-driven `optimizeVertexCache`.
    Best,
    /// meshoptimizer's `optimizeVertexCacheStrip`: runs of triangles that
    /// each share an edge with the one before, the order its index and
    /// vertex codecs (`compress = "meshopt"`) pack tightest.
    Strip,
}

/// How texture tiles are encoded.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, serde::Serialize, schemars::JsonSchema, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum TextureFormat {
    /// Lossless: neighbouring tiles' border texels are equal exactly.
    #[default]
    Png,
    /// Lossy, with `jpeg_quality`: smaller files; borders equal within the
    /// compression error.
    Jpeg,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            max_error_m: 1.0,
            tau_max_px: 2.0,
            threads: 0,
            memory_limit: "2GB".into(),
            vertical_scale: 1.0,
            spacing_m: None,
            leaf_cells: None,
            root_cells: None,
            max_chunk_vertices: MAX_CHUNK_VERTICES,
            thin: Thin::Leaves,
            vertex_cache: None,
            complete_tree: false,
            index_tiles: INDEX_TILES,
            max_texture_px: 512,
            texture_format: TextureFormat::Png,
            jpeg_quality: 85,
            hillshade_multiple: 1.0,
            sun_azimuth_deg: 315.0,
            sun_elevation_deg: 45.0,
            normal_map: false,
            compress: Compress::None,
            normal_bits: None,
            mesher: Mesher::Rtin,
            frame: Frame::Auto,
        }
    }
}

/// The smallest `memory_limit`: below it the process itself does not fit.
pub const MIN_MEMORY_LIMIT: u64 = 16_000_000;

/// A setting that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The config file could not be read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The config file is not valid TOML or has an unknown key.
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What the parser said (names the key).
        message: String,
    },
    /// A value is out of range.
    #[error("{key} = {value}: {why}")]
    Invalid {
        /// The setting.
        key: &'static str,
        /// Its value.
        value: String,
        /// The allowed range.
        why: &'static str,
    },
}

impl Config {
    /// The triangle order in effect: `vertex_cache`, or when it is unset
    /// `Strip` for `meshopt` and `meshopt-v1` output (1.2 bytes per surface
    /// vertex smaller than `Fast` on Fuji, 1.9 on California at 1 m, where
    /// the build takes a quarter longer) and `Fast` otherwise.
    pub fn triangle_order(&self) -> VertexCache {
        self.vertex_cache.unwrap_or(match self.compress {
            Compress::Meshopt | Compress::MeshoptV1 => VertexCache::Strip,
            Compress::None | Compress::Quantize => VertexCache::Fast,
        })
    }

    /// How quantized normals are chosen: the nearest of `normal_bits`, or
    /// when it is unset of [`NORMAL_BITS_V1`] for `meshopt-v1`, and
    /// meshoptimizer's own 8-bit rounding for `quantize` and `meshopt`
    /// (whose files stay as earlier versions wrote them).
    pub fn normal_encoding(&self) -> NormalEncoding {
        match (self.normal_bits, self.compress) {
            (Some(bits), _) => NormalEncoding::Nearest(bits),
            (None, Compress::MeshoptV1) => NormalEncoding::Nearest(NORMAL_BITS_V1),
            (None, Compress::None | Compress::Quantize | Compress::Meshopt) => NormalEncoding::Rounded,
        }
    }

    /// Reads a `pipeline.toml`.
    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io { path: path.into(), source })?;
        toml::from_str(&text).map_err(|e| ConfigError::Parse { path: path.into(), message: e.message().to_string() })
    }

    /// `memory_limit` in bytes (`None`: no limit); at least 16 MB.
    pub fn memory_limit_bytes(&self) -> Result<Option<u64>, &'static str> {
        if self.memory_limit.trim().eq_ignore_ascii_case("none") {
            return Ok(None);
        }
        match crate::store::parse_bytes(&self.memory_limit) {
            Ok(b) if b >= MIN_MEMORY_LIMIT => Ok(Some(b)),
            Ok(_) => Err("must be at least 16MB (or \"none\")"),
            Err(_) => Err("must be a size such as \"2GB\", \"256MB\" or \"1.5GiB\", or \"none\""),
        }
    }

    /// Checks every value's range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |key, value: String, why| Err(ConfigError::Invalid { key, value, why });
        if !(self.max_error_m > 0.0 && self.max_error_m.is_finite()) {
            return bad("max_error_m", self.max_error_m.to_string(), "must be a finite number of metres > 0");
        }
        if !(self.tau_max_px > 0.0 && self.tau_max_px.is_finite()) {
            return bad("tau_max_px", self.tau_max_px.to_string(), "must be a finite number of pixels > 0");
        }
        if !(self.vertical_scale.is_finite() && self.vertical_scale != 0.0) {
            return bad("vertical_scale", self.vertical_scale.to_string(), "must be finite and not 0");
        }
        if let Err(why) = self.memory_limit_bytes() {
            return Err(ConfigError::Invalid { key: "memory_limit", value: self.memory_limit.clone(), why });
        }
        if self.threads > MAX_THREADS {
            return bad("threads", self.threads.to_string(), "must be within 0..=1024 (0: one per core)");
        }
        if let Some(s) = self.spacing_m
            && !s.iter().all(|v| SPACING_M.contains(v))
        {
            return bad("spacing_m", format!("{s:?}"), "must be within 0.001..=100000 metres on each axis");
        }
        if let Some(c) = self.leaf_cells
            && !(2..=4096).contains(&c)
        {
            return bad("leaf_cells", c.to_string(), "must be within 2..=4096 cells");
        }
        if let Some(c) = self.root_cells
            && !(2..=65_536).contains(&c)
        {
            return bad("root_cells", c.to_string(), "must be within 2..=65536 cells");
        }
        if !(65_535..=16_777_215).contains(&self.max_chunk_vertices) {
            return bad(
                "max_chunk_vertices",
                self.max_chunk_vertices.to_string(),
                "must be within 65535..=16777215 vertices",
            );
        }
        if !(1..=16_777_216).contains(&self.index_tiles) {
            return bad("index_tiles", self.index_tiles.to_string(), "must be within 1..=16777216 tiles");
        }
        if !(2..=16384).contains(&self.max_texture_px) {
            return bad("max_texture_px", self.max_texture_px.to_string(), "must be within 2..=16384 texels");
        }
        if !(1..=100).contains(&self.jpeg_quality) {
            return bad("jpeg_quality", self.jpeg_quality.to_string(), "must be within 1..=100");
        }
        if !(0.125..=8.0).contains(&self.hillshade_multiple) {
            return bad("hillshade_multiple", self.hillshade_multiple.to_string(), "must be within 0.125..=8");
        }
        if !(0.0..360.0).contains(&self.sun_azimuth_deg) {
            return bad("sun_azimuth_deg", self.sun_azimuth_deg.to_string(), "must be within 0..360 degrees");
        }
        if !(self.sun_elevation_deg > 0.0 && self.sun_elevation_deg <= 90.0) {
            return bad("sun_elevation_deg", self.sun_elevation_deg.to_string(), "must be > 0 and <= 90 degrees");
        }
        if let Some(b) = self.normal_bits
            && !(2..=8).contains(&b)
        {
            return bad("normal_bits", b.to_string(), "must be within 2..=8 bits");
        }
        if self.frame == Frame::Curved && (self.mesher != Mesher::Rtin || self.compress != Compress::None) {
            return bad(
                "frame",
                "curved".into(),
                "needs mesher = \"rtin\" and compress = \"none\" (the tin mesher's cut points and quantized \
                 positions live on the flat grid)",
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The widest leaf that always fits is the one the u16 limit had (250
    /// cells), and every width up to it holds its samples and border cut
    /// points within the limit while the next does not.
    #[test]
    fn dense_leaves_hold_their_samples_and_cut_points_within_the_limit() {
        assert_eq!(dense_leaf_cells(65_535), 250);
        assert_eq!(dense_leaf_cells(MAX_CHUNK_VERTICES), 250);
        assert_eq!(dense_leaf_cells(1_048_575), 1018);
        for limit in [65_535, 100_000, 1_048_575, 16_777_215] {
            let c = u64::from(dense_leaf_cells(limit));
            assert!((c + 1) * (c + 1) + 10 * c <= u64::from(limit), "{limit}");
            assert!((c + 2) * (c + 2) + 10 * (c + 1) > u64::from(limit), "{limit}");
        }
    }
}
