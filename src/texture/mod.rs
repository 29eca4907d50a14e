//! Texture: one image tile per chunk whose texel ground size keeps
//! T_g ≤ δ(L)/τ_max (Ulrich 2002, §13; DESIGN.md, "Texture").
//!
//! A chunk drawn at screen error ρ ≤ τ_max is never nearer than
//! D_min = δ·K/τ_max, where a texel of ground size T_g covers T_g·K/D_min
//! = T_g·τ_max/δ pixels: at most one when T_g ≤ δ/τ_max. Each axis of a
//! tile is sized on its own ([`size_axis`]): the fewest texels that keep the
//! bound, rounded up to a power of two, but never finer than the source
//! (then the source's own resolution, the nearest size that still keeps the
//! bound if it can) and never wider than `max_texture_px`. Where the source
//! or the cap stops the tile short of the bound, the level's record says
//! which; a source coarser than δ/τ_max cannot do better, while a capped
//! level is a stated exception that a larger `max_texture_px` removes.
//!
//! Texel `k` of `n` along an axis lies at `x0 + k·(x1 − x0)/(n − 1)`: the
//! first and last texel centres lie on the footprint's edges, so T_g =
//! footprint / (n − 1), and neighbours sample their shared edge at the same
//! places ([`resample()`] makes those texels equal bit for bit). TEXCOORD_0
//! maps the footprint exactly onto the texel centres,
//! `u = (½ + (n − 1)·(x − x0)/(x1 − x0)) / n`, with clamp-to-edge sampling:
//! each ground point shows the colour sampled at that point, and both sides
//! of a shared edge show the same texels. Skirt vertices take their top
//! vertex's (x, z), hence its UV.
//!
//! The optional normal map holds the full-resolution DEM's normals,
//! averaged over each texel, in a tangent frame that the chunk's vertices
//! fix to the map's axes (NORMAL = +y, TANGENT = +x, bitangent north): the
//! map alone carries the shading, and its borders match like the colour's.

pub mod resample;
pub mod source;

use std::path::PathBuf;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::config::{Config, TextureFormat};
use crate::mesh::dem_normal;
use crate::mesh::grid::Grid;
use crate::quadtree::{ChunkKey, ChunkTree, Span};
use resample::{AxisSampling, Raster, linear_to_srgb, resample};
pub use source::{ColourSource, TextureSource};

/// Why a texture could not be made.
#[derive(Debug, thiserror::Error)]
pub enum TextureError {
    /// The image file could not be read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The image is not usable (format, size, georeference, coverage).
    #[error("{path}: {what}")]
    Image {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// A TIFF image could not be read (the message names the file).
    #[error(transparent)]
    Tiff(crate::dem::DemError),
    /// The generated colour map would not fit in memory.
    #[error("{0}")]
    TooLarge(String),
    /// An image encoder failed.
    #[error("chunk {chunk}: cannot encode its texture: {what}")]
    Encode {
        /// `L/x/y`.
        chunk: String,
        /// The encoder's message.
        what: String,
    },
}

/// What set a tile's size along one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Limit {
    /// T_g ≤ δ/τ_max (rounded up to a power of two): the bound holds.
    Bound,
    /// The source's resolution: a finer tile would invent detail.
    Source,
    /// `max_texture_px`.
    MaxTexturePx,
}

/// One axis of a tile.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisSize {
    /// Texels along the axis (≥ 2).
    pub texels: u32,
    /// Ground distance between texel centres, metres: footprint / (texels − 1).
    pub texel_m: f64,
    /// What chose `texels`.
    pub limit: Limit,
}

/// Relative slack for comparing lengths computed along different paths.
const REL: f64 = 1e-9;

/// Texels for one axis of a footprint `extent_m` long: the fewest that keep
/// T_g ≤ `bound_m`, rounded up to a power of two; where that is finer than
/// the source (`source_texel_m`) or wider than `max_px`, the largest size
/// either allows (which still keeps the bound when it can). At least 2.
pub fn size_axis(extent_m: f64, bound_m: f64, source_texel_m: f64, max_px: u32) -> AxisSize {
    let count = |x: f64| if x.is_finite() { x.clamp(0.0, 1e9) as u64 } else { 1_000_000_000 };
    // n − 1 intervals of at most bound_m each.
    let need = (count((extent_m / bound_m * (1.0 - REL)).ceil()) + 1).max(2);
    // n − 1 intervals of at least one source pixel each.
    let by_source = (count((extent_m / source_texel_m * (1.0 + REL)).floor()) + 1).max(2);
    let cap = u64::from(max_px.max(2));
    let allowed = by_source.min(cap);
    let pow2 = need.next_power_of_two();
    let (texels, limit) = if pow2 <= allowed {
        (pow2, Limit::Bound)
    } else {
        (allowed, if by_source <= cap { Limit::Source } else { Limit::MaxTexturePx })
    };
    AxisSize { texels: texels as u32, texel_m: extent_m / (texels - 1) as f64, limit }
}

/// One image per chunk: its source, where the source lies, and its filter
/// radius per level.
struct Layer<'a> {
    raster: &'a dyn Raster,
    /// Grid → source pixel, per axis: `pixel = offset + scale · grid`.
    to_px: [(f64, f64); 2],
    /// Ground size of a source pixel, metres.
    texel_m: [f64; 2],
    /// Per level and axis: the tent radius in source pixels, the largest
    /// texel spacing of any chunk of the level (at least 1, bilinear).
    radius: Vec<[f64; 2]>,
}

impl<'a> Layer<'a> {
    fn new(raster: &'a dyn Raster, to_px: [(f64, f64); 2], texel_m: [f64; 2], sizing: &Sizing) -> Self {
        let tree = sizing.tree;
        let radius = (0..=tree.depth())
            .map(|l| {
                let spans = [&tree.xs[l as usize], &tree.zs[l as usize]];
                [0, 1].map(|a| {
                    spans[a]
                        .iter()
                        .map(|&s| {
                            let n = sizing.axis(l, s, a, texel_m[a]).texels;
                            f64::from(s.1 - s.0) / f64::from(n - 1) * to_px[a].1.abs()
                        })
                        .fold(1.0, f64::max)
                })
            })
            .collect();
        Layer { raster, to_px, texel_m, radius }
    }

    /// Sizes and linear pixels of chunk `key`'s tile.
    fn render(&self, sizing: &Sizing, key: ChunkKey) -> ([AxisSize; 2], Vec<f32>) {
        let (size, axes) = self.sampling(sizing, key);
        (size, resample(self.raster, &axes[0], &axes[1]))
    }

    /// Sizes of chunk `key`'s tile and where its texels sample the source.
    fn sampling(&self, sizing: &Sizing, key: ChunkKey) -> ([AxisSize; 2], [AxisSampling; 2]) {
        let fp = sizing.tree.footprint(key);
        let spans = [fp.0, fp.1];
        let size = [0, 1].map(|a| sizing.axis(key.level, spans[a], a, self.texel_m[a]));
        let axes = [0, 1].map(|a| {
            let (s, n) = (spans[a], u64::from(size[a].texels));
            let (offset, scale) = self.to_px[a];
            // Exact integer numerator: the edge texels land exactly on the
            // footprint edges, identically in both neighbours.
            let centres = (0..n)
                .map(|k| {
                    let g = (u64::from(s.0) * (n - 1) + k * u64::from(s.1 - s.0)) as f64 / (n - 1) as f64;
                    offset + scale * g
                })
                .collect();
            AxisSampling { centres, radius: self.radius[key.level as usize][a] }
        });
        (size, axes)
    }
}

/// The source pixel each texel of `axis` copies, when every one lands on a
/// pixel centre and the filter is bilinear (radius 1): the tent then has a
/// single tap of weight 1, so resampling gives the pixel's own value (edge
/// pixels standing in beyond the edge, as the tent clamps). `None` when
/// any texel falls between pixels or the tile is coarser than its source.
fn pixel_copy(axis: &AxisSampling, len: usize) -> Option<Vec<usize>> {
    if axis.radius != 1.0 || len == 0 {
        return None;
    }
    let last = (len - 1) as f64;
    axis.centres.iter().map(|&c| (c.fract() == 0.0).then(|| c.clamp(0.0, last) as usize)).collect()
}

/// The sRGB bytes of the tile sampled at `axes`: a straight copy of the
/// source's bytes where [`pixel_copy`] allows on both axes (a source byte
/// through linear light and back is itself, tested), else resampled in
/// linear light and encoded.
fn colour_tile(source: &ColourSource, axes: &[AxisSampling; 2]) -> Vec<u8> {
    match (pixel_copy(&axes[0], source.width), pixel_copy(&axes[1], source.height)) {
        (Some(cols), Some(rows)) => {
            let mut rgb = Vec::with_capacity(cols.len() * rows.len() * 3);
            for &i in &rows {
                let row = &source.rgb[i * source.width * 3..(i + 1) * source.width * 3];
                for &j in &cols {
                    rgb.extend_from_slice(&row[j * 3..j * 3 + 3]);
                }
            }
            rgb
        }
        _ => resample(source, &axes[0], &axes[1]).iter().map(|&v| linear_to_srgb(v)).collect(),
    }
}

/// The inputs of [`size_axis`] that are fixed for a build.
struct Sizing<'a> {
    tree: &'a ChunkTree,
    spacing_m: [f64; 2],
    tau_max_px: f64,
    max_px: u32,
}

impl Sizing<'_> {
    fn axis(&self, level: u32, span: Span, axis: usize, source_texel_m: f64) -> AxisSize {
        let extent_m = f64::from(span.1 - span.0) * self.spacing_m[axis];
        size_axis(extent_m, self.tree.delta_m[level as usize] / self.tau_max_px, source_texel_m, self.max_px)
    }
}

/// The DEM's own normals, one per sample, as a source raster.
pub struct NormalSource<'a> {
    grid: &'a Grid<'a>,
    spacing_m: [f64; 2],
}

impl<'a> NormalSource<'a> {
    /// Normals of `grid` (central differences, as the vertex normals).
    pub fn new(grid: &'a Grid<'a>, spacing_m: [f64; 2]) -> Self {
        NormalSource { grid, spacing_m }
    }
}

impl Raster for NormalSource<'_> {
    fn channels(&self) -> usize {
        3
    }

    fn size(&self) -> (usize, usize) {
        (self.grid.width, self.grid.height)
    }

    fn read_row(&self, i: usize, j0: usize, j1: usize, out: &mut [f32]) {
        for j in j0..j1 {
            let n = dem_normal(self.grid, self.spacing_m, j as f64, i as f64);
            out[(j - j0) * 3..][..3].copy_from_slice(&n);
        }
    }
}

/// One encoded image of a tile.
#[derive(Clone, Debug)]
pub struct TileImage {
    /// Texels across (x, east) and down (z, south).
    pub texels: [u32; 2],
    /// Ground distance between texel centres per axis, metres.
    pub texel_m: [f64; 2],
    /// What chose each axis's size.
    pub limit: [Limit; 2],
    /// PNG or JPEG bytes.
    pub bytes: Vec<u8>,
    /// `image/png` or `image/jpeg`.
    pub mime: &'static str,
}

impl TileImage {
    /// T_g: the larger texel spacing of the two axes, metres.
    pub fn texel_size_m(&self) -> f64 {
        self.texel_m[0].max(self.texel_m[1])
    }
}

/// A chunk's textures.
#[derive(Clone, Debug)]
pub struct TextureTile {
    /// Base colour.
    pub colour: TileImage,
    /// Tangent-space normal map, when asked for.
    pub normal: Option<TileImage>,
}

/// Makes every chunk's tile.
pub struct Texturer<'a> {
    sizing: Sizing<'a>,
    colour: Layer<'a>,
    normal: Option<Layer<'a>>,
    colour_source: &'a ColourSource,
    format: TextureFormat,
    jpeg_quality: u8,
}

impl<'a> Texturer<'a> {
    /// Plans the tiles of `tree` from `colour` (and `normals`).
    pub fn new(
        colour: &'a ColourSource,
        normals: Option<&'a NormalSource<'a>>,
        tree: &'a ChunkTree,
        spacing_m: [f64; 2],
        cfg: &Config,
    ) -> Self {
        let sizing = Sizing { tree, spacing_m, tau_max_px: cfg.tau_max_px, max_px: cfg.max_texture_px };
        let colour_layer = Layer::new(colour, colour.to_px, colour.texel_m, &sizing);
        let normal = normals.map(|n| Layer::new(n, [(0.0, 1.0), (0.0, 1.0)], spacing_m, &sizing));
        Texturer {
            sizing,
            colour: colour_layer,
            normal,
            colour_source: colour,
            format: cfg.texture_format,
            jpeg_quality: cfg.jpeg_quality,
        }
    }

    /// The tile(s) of chunk `key`.
    pub fn tile(&self, key: ChunkKey) -> Result<TextureTile, TextureError> {
        let chunk = format!("{}/{}/{}", key.level, key.x, key.y);
        let encode_err = |e: image::ImageError| TextureError::Encode { chunk: chunk.clone(), what: e.to_string() };
        let (size, axes) = self.colour.sampling(&self.sizing, key);
        let rgb = colour_tile(self.colour_source, &axes);
        let [w, h] = size.map(|s| s.texels);
        let (bytes, mime) = match self.format {
            TextureFormat::Png => (encode_png(&rgb, w, h).map_err(encode_err)?, "image/png"),
            TextureFormat::Jpeg => (encode_jpeg(&rgb, w, h, self.jpeg_quality).map_err(encode_err)?, "image/jpeg"),
        };
        let colour =
            TileImage { texels: [w, h], texel_m: size.map(|s| s.texel_m), limit: size.map(|s| s.limit), bytes, mime };
        let normal = match &self.normal {
            None => None,
            Some(layer) => {
                let (size, sum) = layer.render(&self.sizing, key);
                let [w, h] = size.map(|s| s.texels);
                let rgb: Vec<u8> = sum.chunks_exact(3).flat_map(|n| tangent_space_rgb([n[0], n[1], n[2]])).collect();
                Some(TileImage {
                    texels: [w, h],
                    texel_m: size.map(|s| s.texel_m),
                    limit: size.map(|s| s.limit),
                    bytes: encode_png(&rgb, w, h).map_err(encode_err)?,
                    mime: "image/png",
                })
            }
        };
        Ok(TextureTile { colour, normal })
    }

    /// The texture record for the tileset extras.
    pub fn extras(&self, cfg: &Config, generated: bool) -> TextureExtras {
        let tree = self.sizing.tree;
        let levels = (0..=tree.depth())
            .map(|l| {
                let bound_m = tree.delta_m[l as usize] / self.sizing.tau_max_px;
                let spans = [&tree.xs[l as usize], &tree.zs[l as usize]];
                let (mut texel_m, mut limit, mut texels) = (0.0f64, Limit::Bound, [0u32; 2]);
                for a in 0..2 {
                    for &s in spans[a] {
                        let size = self.sizing.axis(l, s, a, self.colour.texel_m[a]);
                        texel_m = texel_m.max(size.texel_m);
                        limit = limit.max(size.limit);
                        texels[a] = texels[a].max(size.texels);
                    }
                }
                TextureLevel {
                    level: l,
                    texel_m,
                    bound_m,
                    bound_holds: texel_m <= bound_m * (1.0 + REL),
                    limit,
                    texels,
                }
            })
            .collect();
        let src = self.colour_source;
        TextureExtras {
            source: src.name.clone(),
            placement: src.placement.clone(),
            source_texel_m: src.texel_m,
            format: self.format,
            jpeg_quality: (self.format == TextureFormat::Jpeg).then_some(self.jpeg_quality),
            max_texture_px: self.sizing.max_px,
            texel_rule: "T_g = footprint / (texels - 1) per axis <= delta / tau_max_px, texels rounded up to a power \
                         of two; never finer than the source (then as fine as the source allows) nor wider than \
                         max_texture_px (then the bound does not hold: see levels[].limit)"
                .into(),
            uv: "TEXCOORD_0 u = (0.5 + (n - 1) * (x - x0) / (x1 - x0)) / n, v likewise from z (south): the footprint \
                 maps onto the texel centres, the edge texels lie on the footprint edges; sampler clamp to edge"
                .into(),
            filter: "tent (bilinear when radius = 1 source pixel) in linear light; radius = the level's largest \
                     texel spacing, so neighbours' shared border texels are equal"
                .into(),
            hillshade: generated.then_some(Hillshade {
                sun_azimuth_deg: cfg.sun_azimuth_deg,
                sun_elevation_deg: cfg.sun_elevation_deg,
                multiple: cfg.hillshade_multiple,
            }),
            normal_map: self.normal.as_ref().map(|_| {
                "normalTexture from the DEM's normals (texCoord 1 when its size differs from the colour's); \
                 vertices carry NORMAL = +y and TANGENT = +x (w = 1), so the map alone shades the chunk"
                    .to_string()
            }),
            levels,
        }
    }
}

/// A DEM normal (x east, y up, z south) in the tangent frame T = +x
/// (east, +u), B = north (−z, up the image), N = +y, as 8-bit RGB.
fn tangent_space_rgb(n: [f32; 3]) -> [u8; 3] {
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let n = if len > 0.0 { n.map(|c| c / len) } else { [0.0, 1.0, 0.0] };
    [n[0], -n[2], n[1]].map(|c| ((c + 1.0) * 127.5).round().clamp(0.0, 255.0) as u8)
}

/// PNG at the fast DEFLATE setting: on SRTM3 Provence it is 7× quicker
/// than the default for 9 % more texture bytes, and the tiles are a few
/// per cent of a chunk's bytes.
fn encode_png(rgb: &[u8], w: u32, h: u32) -> Result<Vec<u8>, image::ImageError> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive).write_image(
        rgb,
        w,
        h,
        image::ExtendedColorType::Rgb8,
    )?;
    Ok(out)
}

fn encode_jpeg(rgb: &[u8], w: u32, h: u32, quality: u8) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality).encode(
        rgb,
        w,
        h,
        image::ExtendedColorType::Rgb8,
    )?;
    Ok(out)
}

/// `extras.terrachunk.texture` on the tileset: how the tiles were made and
/// what bounds them, level by level.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TextureExtras {
    /// The colour source: the image's file name, or the generator.
    pub source: String,
    /// How the source was placed over the DEM.
    pub placement: String,
    /// Ground size of one source pixel, metres `[east-west, north-south]`.
    pub source_texel_m: [f64; 2],
    /// `png` or `jpeg`.
    pub format: TextureFormat,
    /// JPEG quality (1..=100), for `jpeg`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jpeg_quality: Option<u8>,
    /// The widest a tile may be, texels.
    pub max_texture_px: u32,
    /// How tiles are sized.
    pub texel_rule: String,
    /// How TEXCOORD_0 maps the footprint.
    pub uv: String,
    /// How texels are filtered.
    pub filter: String,
    /// The generated colour map's settings (absent for an image source).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hillshade: Option<Hillshade>,
    /// How the normal map is to be read (absent without one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normal_map: Option<String>,
    /// Per level, top first.
    pub levels: Vec<TextureLevel>,
}

/// The generated colour map's settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Hillshade {
    /// Sun azimuth, degrees clockwise from north.
    pub sun_azimuth_deg: f64,
    /// Sun elevation, degrees.
    pub sun_elevation_deg: f64,
    /// Texels per DEM sample spacing.
    pub multiple: f64,
}

/// One level's tiles.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TextureLevel {
    /// Level.
    pub level: u32,
    /// Largest T_g of any chunk of the level (either axis), metres.
    pub texel_m: f64,
    /// δ(L)/τ_max, metres.
    pub bound_m: f64,
    /// Whether `texel_m ≤ bound_m`.
    pub bound_holds: bool,
    /// What sized the level's tiles: the worst of its chunks' axes.
    pub limit: Limit,
    /// Largest tile of the level, texels `[across, down]`.
    pub texels: [u32; 2],
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bound_rounds_up_to_a_power_of_two() {
        // 100 m at T_g ≤ 1 m needs 101 texels: 128 (T_g = 100/127 m).
        let s = size_axis(100.0, 1.0, 0.01, 512);
        assert_eq!((s.texels, s.limit), (128, Limit::Bound));
        assert!((s.texel_m - 100.0 / 127.0).abs() < 1e-12);
        // Exactly 100 intervals of 1 m also need 101.
        assert_eq!(size_axis(128.0, 1.0, 0.01, 512).texels, 256);
        assert_eq!(size_axis(127.0, 1.0, 0.01, 512).texels, 128);
    }

    #[test]
    fn the_source_stops_the_power_of_two_and_keeps_the_bound_when_it_can() {
        // A 200-cell chunk of a 30 m DEM, δ/τ = 40 m: 151 texels needed, 256
        // would be finer than the source, 201 (one per sample) keeps the bound.
        let s = size_axis(6000.0, 40.0, 30.0, 512);
        assert_eq!((s.texels, s.limit), (201, Limit::Source));
        assert!(s.texel_m <= 40.0 && (s.texel_m - 30.0).abs() < 1e-12);
        // δ/τ = 0.5 m: the 30 m source cannot keep it; as fine as the source.
        let s = size_axis(6000.0, 0.5, 30.0, 512);
        assert_eq!((s.texels, s.limit), (201, Limit::Source));
    }

    #[test]
    fn the_cap_binds_last_and_is_named() {
        let s = size_axis(60_000.0, 10.0, 30.0, 512);
        assert_eq!((s.texels, s.limit), (512, Limit::MaxTexturePx));
        assert!(s.texel_m > 10.0);
        assert_eq!(size_axis(60_000.0, 10.0, 30.0, 8192).limit, Limit::Source);
    }

    #[test]
    fn a_chunk_narrower_than_a_source_pixel_still_gets_two_texels() {
        let s = size_axis(10.0, 100.0, 30.0, 512);
        assert_eq!(s.texels, 2);
        assert_eq!(s.texel_m, 10.0);
    }

    #[test]
    fn a_tile_on_pixel_centres_is_the_resampled_tile_byte_for_byte() {
        let (width, height) = (7, 5);
        let mut state = 0x2545_f491_u32;
        let rgb: Vec<u8> = (0..width * height * 3)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                state as u8
            })
            .collect();
        let source = ColourSource {
            width,
            height,
            rgb: rgb.into(),
            to_px: [(0.0, 1.0), (0.0, 1.0)],
            texel_m: [1.0, 1.0],
            name: "noise".into(),
            placement: "test".into(),
        };
        let axis = |centres: &[f64], radius| AxisSampling { centres: centres.to_vec(), radius };
        let resampled = |axes: &[AxisSampling; 2]| -> Vec<u8> {
            resample(&source, &axes[0], &axes[1]).iter().map(|&v| linear_to_srgb(v)).collect()
        };
        // Every pixel, a crop, and centres beyond either edge (the edge
        // pixel stands in): copied, and what resampling gives.
        for axes in [
            [axis(&[0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 1.0), axis(&[0.0, 1.0, 2.0, 3.0, 4.0], 1.0)],
            [axis(&[2.0, 3.0, 4.0], 1.0), axis(&[1.0, 2.0], 1.0)],
            [axis(&[-1.0, 0.0, 6.0, 7.0], 1.0), axis(&[-2.0, 4.0, 5.0], 1.0)],
        ] {
            assert!(pixel_copy(&axes[0], width).is_some() && pixel_copy(&axes[1], height).is_some());
            assert_eq!(colour_tile(&source, &axes), resampled(&axes));
        }
        // Between pixels, or a wider tent: resampled, not copied.
        let between = [axis(&[0.5, 1.0], 1.0), axis(&[1.0, 2.0], 1.0)];
        let wide = [axis(&[0.0, 2.0], 2.0), axis(&[1.0, 3.0], 2.0)];
        assert!(pixel_copy(&between[0], width).is_none() && pixel_copy(&wide[0], width).is_none());
        assert_eq!(colour_tile(&source, &between), resampled(&between));
        assert_ne!(resampled(&wide)[..3], source.rgb[..3], "a wide tent averages, unlike a copy");
    }

    #[test]
    fn tangent_frame_maps_up_to_blue_and_east_facing_to_red() {
        assert_eq!(tangent_space_rgb([0.0, 1.0, 0.0]), [128, 128, 255]);
        // A slope facing east (normal tilted +x) reads +r; facing north (−z) +g.
        let e = tangent_space_rgb([0.6, 0.8, 0.0]);
        let n = tangent_space_rgb([0.0, 0.8, -0.6]);
        assert!(e[0] > 128 && e[1] == 128 && n[1] > 128 && n[0] == 128, "{e:?} {n:?}");
    }
}
