//! The colour source every tile is resampled from: an image the user gives
//! (`--texture`), placed by its georeference or stretched over the DEM, or a
//! colour map generated from the DEM itself.
//!
//! The generated map follows Ulrich's `heightfield_shader` (chunklod demo):
//! a hypsometric tint by height (stretched over the DEM's land range; blues
//! by depth below 0 m) times a hillshade from a configurable sun, computed
//! at the DEM's sample positions or a multiple of that resolution. The
//! shade is Lambert's `n·l` with a little ambient light, scaled so flat
//! ground shows the plain tint.

use std::io::Read;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::TextureError;
use super::resample::{Raster, SRGB_TO_LINEAR, linear_to_srgb};
use crate::config::Config;
use crate::dem::geotiff::{RawGeoref, load_rgb8};
use crate::heightfield::{Crs, Heightfield};
use crate::store::{Big, Memory};

/// The most pixels a colour source may hold (2^30: 3 GiB of RGB).
pub const MAX_SOURCE_PIXELS: usize = 1 << 30;

/// An RGB image and where it lies over the DEM.
#[derive(Clone, Debug)]
pub struct ColourSource {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major sRGB, 3 bytes per pixel (a generated map past a build's
    /// memory limit in a mapped scratch file, [`crate::store`]).
    pub rgb: Big<u8>,
    /// DEM grid coordinate → source pixel coordinate, per axis (column,
    /// row): `pixel = offset + scale · grid`, pixel `j`'s centre at `j`.
    pub to_px: [(f64, f64); 2],
    /// Ground size of one source pixel, metres: `[east-west, north-south]`.
    pub texel_m: [f64; 2],
    /// What it is: the file name, or the generator.
    pub name: String,
    /// How it was placed over the DEM.
    pub placement: String,
}

impl Raster for ColourSource {
    fn channels(&self) -> usize {
        3
    }

    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn read_row(&self, i: usize, j0: usize, j1: usize, out: &mut [f32]) {
        let lut = &*SRGB_TO_LINEAR;
        for (o, &b) in out.iter_mut().zip(&self.rgb[(i * self.width + j0) * 3..(i * self.width + j1) * 3]) {
            *o = lut[b as usize];
        }
    }
}

fn image_error(path: &Path, what: impl Into<String>) -> TextureError {
    TextureError::Image { path: path.to_path_buf(), what: what.into() }
}

/// Reads a PNG, JPEG or 8-bit TIFF (GeoTIFF) colour image and places it
/// over `hf`: by its georeference when it has one in the DEM's CRS, else
/// stretched so its outer edges meet the DEM's outer cell edges.
pub fn load_image(path: &Path, hf: &Heightfield) -> Result<ColourSource, TextureError> {
    let io = |source| TextureError::Io { path: path.to_path_buf(), source };
    let meta = std::fs::metadata(path).map_err(io)?;
    if !meta.is_file() {
        return Err(image_error(path, "not a regular file"));
    }
    let mut head = Vec::with_capacity(32);
    std::fs::File::open(path).and_then(|f| f.take(32).read_to_end(&mut head)).map_err(io)?;
    let (width, height, rgb, georef) = if head.starts_with(b"II*\0")
        || head.starts_with(b"MM\0*")
        || head.starts_with(b"II+\0")
        || head.starts_with(b"MM\0+")
    {
        let t = load_rgb8(path).map_err(TextureError::Tiff)?;
        (t.width, t.height, t.rgb, t.georef)
    } else if head.starts_with(b"\x89PNG\r\n\x1a\n") || head.starts_with(&[0xff, 0xd8, 0xff]) {
        // PNG's IHDR: bit depth at byte 24. 16-bit colour would be cut to
        // 8 bits without a word; the README promises it is refused.
        if head.starts_with(b"\x89PNG") && head.get(24) == Some(&16) {
            return Err(image_error(path, "16-bit PNG; a texture needs 8 bits per channel (convert it first)"));
        }
        let open = || std::fs::File::open(path).map(std::io::BufReader::new).map_err(io);
        let file_len = std::fs::metadata(path).map_err(io)?.len();
        let cannot = |e: image::ImageError| image_error(path, format!("cannot decode: {e}"));
        let (w, h) =
            image::ImageReader::new(open()?).with_guessed_format().map_err(io)?.into_dimensions().map_err(cannot)?;
        let (w, h) = (w as usize, h as usize);
        if w.checked_mul(h).is_none_or(|n| n > MAX_SOURCE_PIXELS) {
            return Err(image_error(path, format!("{w} × {h} pixels is larger than terrachunk reads")));
        }
        crate::dem::check_expansion((w, h), 3, file_len).map_err(|e| image_error(path, e))?;
        let img = image::ImageReader::new(open()?).with_guessed_format().map_err(io)?.decode().map_err(cannot)?;
        let img = img.to_rgb8();
        (img.width() as usize, img.height() as usize, img.into_raw(), None)
    } else {
        let shown: String = head.iter().take(8).map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(" ");
        return Err(image_error(
            path,
            format!("not a PNG, JPEG or TIFF image (first bytes {shown}); a texture must be one of these"),
        ));
    };
    if width == 0 || height == 0 {
        return Err(image_error(path, format!("image is {width} × {height} pixels")));
    }
    let (to_px, placement) = place(path, hf, width, height, georef.as_ref())?;
    let texel_m = [0, 1].map(|a| hf.spacing_m[a] / to_px[a].1.abs());
    Ok(ColourSource {
        width,
        height,
        rgb: rgb.into(),
        to_px,
        texel_m,
        name: path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned()),
        placement,
    })
}

fn crs_name(c: &Crs) -> String {
    match c {
        Crs::Unknown => "an unknown CRS".into(),
        Crs::Geographic { epsg: Some(e) } | Crs::Projected { epsg: Some(e) } => format!("EPSG:{e}"),
        Crs::Geographic { epsg: None } => "geographic degrees".into(),
        Crs::Projected { epsg: None } => "an unnamed projected CRS".into(),
    }
}

/// Grid → pixel mapping per axis, and how it was decided.
type Placement = ([(f64, f64); 2], String);

fn place(
    path: &Path,
    hf: &Heightfield,
    width: usize,
    height: usize,
    georef: Option<&RawGeoref>,
) -> Result<Placement, TextureError> {
    let dem_crs = &hf.georef.crs;
    let usable = georef.filter(|g| g.crs != Crs::Unknown && *dem_crs != Crs::Unknown);
    let Some(g) = usable else {
        // The image's outer edges on the DEM's outer cell edges, [−½, n − ½]
        // in samples: a same-size image maps pixel to sample.
        let sx = width as f64 / hf.width as f64;
        let sz = height as f64 / hf.height as f64;
        let why = match georef {
            Some(_) if *dem_crs == Crs::Unknown => " (the DEM has no georeference to match the image's)",
            Some(_) => " (the image's georeference names no CRS)",
            None => "",
        };
        return Ok(([(0.5 * sx - 0.5, sx), (0.5 * sz - 0.5, sz)], format!("stretched over the DEM's extent{why}")));
    };
    let same = match (dem_crs, &g.crs) {
        (Crs::Geographic { .. }, Crs::Geographic { .. }) => true,
        (Crs::Projected { epsg: a }, Crs::Projected { epsg: b }) => a == b,
        _ => false,
    };
    if !same {
        return Err(image_error(
            path,
            format!(
                "georeferenced in {} but the DEM is in {}; reproject the image to the DEM's CRS \
                 (e.g. gdalwarp -t_srs), or remove its georeference to stretch it over the DEM",
                crs_name(&g.crs),
                crs_name(dem_crs)
            ),
        ));
    }
    // Both in the same model units: pixel = (X − o_img) / step_img with
    // X = o_dem + grid · step_dem.
    let d = &hf.georef;
    let to_px = [0, 1].map(|a| ((d.origin[a] - g.origin[a]) / g.step[a], d.step[a] / g.step[a]));
    let dims = [width, height];
    let extent = [hf.width, hf.height];
    for a in 0..2 {
        let ends = [to_px[a].0, to_px[a].0 + to_px[a].1 * (extent[a] - 1) as f64];
        let (lo, hi) = (ends[0].min(ends[1]), ends[0].max(ends[1]));
        // A pixel of slack: an image cut to the DEM's sample centres still covers it.
        if lo < -1.5 || hi > dims[a] as f64 + 0.5 {
            let axis = ["columns", "rows"][a];
            return Err(image_error(
                path,
                format!(
                    "does not cover the DEM: its {axis} span 0..{} but the DEM's samples fall at {axis} \
                     {lo:.1}..{hi:.1} of the image",
                    dims[a]
                ),
            ));
        }
    }
    Ok((to_px, format!("georeferenced ({})", crs_name(&g.crs))))
}

/// The generated colour map's width and height in pixels:
/// `hillshade_multiple` pixels per sample spacing, corner to corner.
fn generated_size(hf: &Heightfield, cfg: &Config) -> [usize; 2] {
    let m = cfg.hillshade_multiple;
    [hf.width, hf.height].map(|n| ((n - 1) as f64 * m).round() as usize + 1)
}

/// The generated colour map's [`ColourSource::to_px`], known before it is
/// made: the plan, which needs it, runs while the map is generated.
pub fn generated_to_px(hf: &Heightfield, cfg: &Config) -> [(f64, f64); 2] {
    let [width, height] = generated_size(hf, cfg);
    [(0.0, (width - 1) as f64 / (hf.width - 1) as f64), (0.0, (height - 1) as f64 / (hf.height - 1) as f64)]
}

/// The generated colour map: hypsometric tint × hillshade, at
/// `cfg.hillshade_multiple` texels per sample spacing. `filled` (void-filled
/// heights) gives nodata samples a plausible colour where a triangle
/// reaches over them.
pub fn generate(hf: &Heightfield, filled: Option<&[f32]>, cfg: &Config) -> Result<ColourSource, TextureError> {
    generate_in(hf, filled, cfg, None)
}

/// [`generate`], the map in a scratch file where `memory` says one its
/// size goes to one.
pub fn generate_in(
    hf: &Heightfield,
    filled: Option<&[f32]>,
    cfg: &Config,
    memory: Option<&Memory>,
) -> Result<ColourSource, TextureError> {
    let m = cfg.hillshade_multiple;
    let [width, height] = generated_size(hf, cfg);
    if width.checked_mul(height).is_none_or(|n| n > MAX_SOURCE_PIXELS) {
        return Err(TextureError::TooLarge(format!(
            "hillshade_multiple = {m} makes a {width} × {height} colour map ({:.1} GB of RGB); lower it",
            width as f64 * height as f64 * 3e-9
        )));
    }
    let heights = filled.unwrap_or(&hf.heights);
    let (lo, hi) = hf
        .heights
        .iter()
        .filter(|h| !h.is_nan())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &h| (a.min(f64::from(h)), b.max(f64::from(h))));
    let tint = Tint::new((lo.max(0.0), hi), lo.min(0.0));
    let (az, el) = (cfg.sun_azimuth_deg.to_radians(), cfg.sun_elevation_deg.to_radians());
    // Towards the sun, in the world frame (x east, y up, z south).
    let sun = [az.sin() * el.cos(), el.sin(), -az.cos() * el.cos()];
    let flat = AMBIENT + (1.0 - AMBIENT) * sun[1];
    let surface = Bilinear { w: hf.width, h: hf.height, heights };
    // Source pixel k sits at grid (k · (n − 1) / (N − 1)): exactly on the
    // samples when the multiple is 1.
    let gx = |c: usize| (c * (hf.width - 1)) as f64 / (width - 1) as f64;
    let gz = |r: usize| (r * (hf.height - 1)) as f64 / (height - 1) as f64;
    let (ex, ez) = ((hf.width - 1) as f64 / (width - 1) as f64, (hf.height - 1) as f64 / (height - 1) as f64);
    let [sx, sz] = hf.spacing_m;
    let mut rgb = Big::filled(width * height * 3, 0u8, memory)
        .map_err(|e| TextureError::TooLarge(format!("the generated colour map: {e}")))?;
    // One texel per sample (the default): every point read is a sample,
    // where `at` gives the sample itself, so it is read directly.
    let on_samples = width == hf.width && height == hf.height;
    let at = |x: f64, z: f64| if on_samples { surface.at_sample(z as usize, x as usize) } else { surface.at(x, z) };
    rgb.par_chunks_mut(width * 3).enumerate().for_each(|(r, row)| {
        let z = gz(r);
        let (zm, zp) = ((z - ez).max(0.0), (z + ez).min((hf.height - 1) as f64));
        // On the samples, a pixel whose four neighbours are samples off the
        // last row and column reads them directly (`Bilinear::sample`): the
        // same values `at` gives, with the same steps (two cells) between them.
        let inner_row = on_samples && r >= 1 && r + 2 < height;
        for c in 0..width {
            let (dx, dz, here) = if inner_row && c >= 1 && c + 2 < width {
                (
                    (surface.sample(r, c + 1) - surface.sample(r, c - 1)) / (2.0 * sx),
                    (surface.sample(r + 1, c) - surface.sample(r - 1, c)) / (2.0 * sz),
                    surface.sample(r, c),
                )
            } else {
                let x = gx(c);
                let (xm, xp) = ((x - ex).max(0.0), (x + ex).min((hf.width - 1) as f64));
                ((at(xp, z) - at(xm, z)) / ((xp - xm) * sx), (at(x, zp) - at(x, zm)) / ((zp - zm) * sz), at(x, z))
            };
            let n = [-dx, 1.0, -dz];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let lambert = ((n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2]) / len).max(0.0);
            let light = (AMBIENT + (1.0 - AMBIENT) * lambert) / flat;
            let colour = tint.at(here);
            for ch in 0..3 {
                row[c * 3 + ch] = linear_to_srgb((f64::from(colour[ch]) * light) as f32);
            }
        }
    });
    let to_px = generated_to_px(hf, cfg);
    Ok(ColourSource {
        width,
        height,
        rgb,
        to_px,
        texel_m: [sx * ex, sz * ez],
        name: "generated: hillshade × hypsometric tint".into(),
        placement: format!("{m} texel(s) per DEM sample spacing, on the sample grid"),
    })
}

/// Share of the light that reaches a slope turned away from the sun.
const AMBIENT: f64 = 0.25;

/// Bilinear interpolation of the (void-filled) heights at grid coordinates.
struct Bilinear<'a> {
    w: usize,
    h: usize,
    heights: &'a [f32],
}

impl Bilinear<'_> {
    fn at(&self, x: f64, z: f64) -> f64 {
        let j = (x.floor() as usize).min(self.w - 2);
        let i = (z.floor() as usize).min(self.h - 2);
        let (fx, fz) = (x - j as f64, z - i as f64);
        let v = |i: usize, j: usize| self.sample(i, j);
        let top = v(i, j) + (v(i, j + 1) - v(i, j)) * fx;
        let bottom = v(i + 1, j) + (v(i + 1, j + 1) - v(i + 1, j)) * fx;
        top + (bottom - top) * fz
    }

    /// [`Self::at`] on sample (row `i`, column `j`): off the last row and
    /// column its weights are 1 and 0, so it is the sample itself (nodata
    /// as 0); on them `at` interpolates from the cell before, as here.
    #[inline]
    fn at_sample(&self, i: usize, j: usize) -> f64 {
        if i + 1 < self.h && j + 1 < self.w { self.sample(i, j) } else { self.at(j as f64, i as f64) }
    }

    /// Sample (row `i`, column `j`), nodata as 0.
    #[inline]
    fn sample(&self, i: usize, j: usize) -> f64 {
        let h = self.heights[i * self.w + j];
        if h.is_nan() { 0.0 } else { f64::from(h) }
    }
}

/// Hypsometric tint: land colours stretched over the DEM's land heights,
/// sea blues by depth below 0 m (linear light).
struct Tint {
    land: (f64, f64),
    deepest: f64,
    /// [`LAND`] and [`SEA`] in linear light, converted once rather than per
    /// texel (the same values; about 5 % of the map's time).
    land_stops: [(f64, [f64; 3]); 6],
    sea_stops: [(f64, [f64; 3]); 3],
}

/// (fraction of the range, sRGB colour) stops.
const LAND: [(f64, [u8; 3]); 6] = [
    (0.0, [72, 128, 72]),
    (0.2, [128, 164, 96]),
    (0.45, [200, 188, 132]),
    (0.7, [166, 126, 90]),
    (0.88, [150, 142, 134]),
    (1.0, [248, 248, 248]),
];
const SEA: [(f64, [u8; 3]); 3] = [(0.0, [170, 210, 232]), (0.3, [82, 146, 196]), (1.0, [22, 52, 116])];

impl Tint {
    /// Land colours over `land` (lowest, highest land height), sea colours
    /// down to `deepest`.
    fn new(land: (f64, f64), deepest: f64) -> Self {
        let lut = &*SRGB_TO_LINEAR;
        let linear = |(t, c): (f64, [u8; 3])| (t, c.map(|b| f64::from(lut[b as usize])));
        Tint { land, deepest, land_stops: LAND.map(linear), sea_stops: SEA.map(linear) }
    }

    fn at(&self, h: f64) -> [f32; 3] {
        if h < 0.0 {
            let t = if self.deepest < 0.0 { h / self.deepest } else { 0.0 };
            ramp(&self.sea_stops, t)
        } else {
            let (lo, hi) = self.land;
            let t = if hi > lo { (h - lo) / (hi - lo) } else { 0.0 };
            ramp(&self.land_stops, t)
        }
    }
}

/// The colour at `t` (clamped to 0..=1) between linear-light stops.
fn ramp(stops: &[(f64, [f64; 3])], t: f64) -> [f32; 3] {
    let t = t.clamp(0.0, 1.0);
    let k = stops.iter().rposition(|s| s.0 <= t).unwrap_or(0).min(stops.len() - 2);
    let (a, b) = (stops[k], stops[k + 1]);
    let f = ((t - a.0) / (b.0 - a.0)).clamp(0.0, 1.0);
    std::array::from_fn(|c| (a.1[c] + (b.1[c] - a.1[c]) * f) as f32)
}

/// Where the colour comes from.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum TextureSource {
    /// Generate hillshade × hypsometric tint from the DEM (the default).
    #[default]
    Generated,
    /// No textures: untextured chunks, as before textures existed.
    None,
    /// This image (PNG, JPEG or 8-bit GeoTIFF).
    Image(PathBuf),
}

impl TextureSource {
    /// `none` → [`TextureSource::None`], anything else an image path.
    pub fn from_arg(arg: &str) -> Self {
        if arg == "none" { TextureSource::None } else { TextureSource::Image(PathBuf::from(arg)) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hillshade reads a sample directly where it has one texel per
    /// sample: the same value `at` interpolates there, on every sample of a
    /// grid with nodata, extreme and signed-zero heights, last row and
    /// column included.
    #[test]
    fn a_sample_read_directly_is_what_bilinear_gives_there() {
        let (w, h) = (13usize, 9usize);
        let heights: Vec<f32> = (0..w * h)
            .map(|k| match k % 11 {
                0 => f32::NAN,
                1 => -0.0,
                2 => 8848.86,
                3 => -10_994.0,
                4 => 1.0e-7,
                _ => (k as f32 * 0.731).sin() * 3000.0,
            })
            .collect();
        let surface = Bilinear { w, h, heights: &heights };
        for i in 0..h {
            for j in 0..w {
                let (direct, bilinear) = (surface.at_sample(i, j), surface.at(j as f64, i as f64));
                assert!(direct == bilinear && !direct.is_nan(), "({i}, {j}): {direct} against {bilinear}");
            }
        }
    }

    #[test]
    fn tint_is_green_low_white_high_and_blue_below_sea_level() {
        let t = Tint::new((0.0, 1000.0), -500.0);
        let srgb = |c: [f32; 3]| c.map(linear_to_srgb);
        assert_eq!(srgb(t.at(0.0)), LAND[0].1);
        assert_eq!(srgb(t.at(1000.0)), LAND[5].1);
        assert_eq!(srgb(t.at(-500.0)), SEA[2].1);
        let shallow = srgb(t.at(-1.0));
        assert!(shallow[2] > shallow[0], "{shallow:?}");
    }

    #[test]
    fn flat_ground_shows_the_plain_tint_and_a_sunward_slope_is_brighter() {
        let mut hf = Heightfield::ungeoreferenced(5, 5, vec![100.0; 25], "flat".into());
        hf.spacing_m = [10.0, 10.0];
        let cfg = Config::default();
        let flat = generate(&hf, None, &cfg).unwrap();
        assert_eq!((flat.width, flat.height), (5, 5));
        assert!(flat.rgb.chunks(3).all(|p| p == LAND[0].1), "{:?}", &flat.rgb[..3]);
        // Rising to the south-east, so it faces the north-west sun (azimuth 315°).
        let slope: Vec<f32> = (0..25).map(|k| 88.0 + 3.0 * ((k / 5) + (k % 5)) as f32).collect();
        let lit = generate(&Heightfield { heights: slope.clone().into(), ..hf.clone() }, None, &cfg).unwrap();
        // Falling to the south-east: turned away from it.
        let away: Vec<f32> = slope.iter().map(|h| 200.0 - h).collect();
        let dark = generate(&Heightfield { heights: away.into(), ..hf }, None, &cfg).unwrap();
        // The centre sample is mid-range in both, so both have the same tint.
        let tint = Tint::new((88.0, 112.0), 0.0).at(100.0).map(linear_to_srgb);
        let (l, d) = (&lit.rgb[12 * 3..12 * 3 + 3], &dark.rgb[12 * 3..12 * 3 + 3]);
        for c in 0..3 {
            assert!(l[c] > tint[c] && d[c] < tint[c], "lit {l:?}, tint {tint:?}, dark {d:?}");
        }
    }

    #[test]
    fn a_multiple_of_two_doubles_the_texels_between_samples() {
        let hf = Heightfield::ungeoreferenced(11, 6, vec![5.0; 66], "g".into());
        let cfg = Config { hillshade_multiple: 2.0, ..Config::default() };
        let s = generate(&hf, None, &cfg).unwrap();
        assert_eq!((s.width, s.height), (21, 11));
        assert_eq!(s.texel_m, [0.5, 0.5]);
        assert_eq!(s.to_px, [(0.0, 2.0), (0.0, 2.0)]);
    }
}
