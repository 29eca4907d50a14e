//! Resample one tile from its source raster.
//!
//! A tile's texels sit on a regular grid whose first and last centres lie
//! exactly on the chunk's footprint edges, so two neighbouring tiles each
//! have a row (or column) of texels on their shared edge at the same ground
//! positions. Each texel is a tent-filtered average of the source around its
//! centre (a tent of radius 1 source pixel is bilinear interpolation; wider
//! tents prefilter when the tile is coarser than its source). The tent's
//! radius is a constant of the level and axis, not of the chunk, and a
//! texel's weights depend only on its centre and that radius: the shared
//! border texels of two neighbours are computed from the same source pixels
//! with the same weights in the same order, hence equal bit for bit. Beyond
//! the source's edge the edge pixels repeat; nothing is read from, or blended
//! with, another tile. Colours are averaged in linear light.

use std::sync::LazyLock;

use rayon::prelude::*;

/// A source image the resampler reads row by row.
pub trait Raster: Sync {
    /// Values per pixel.
    fn channels(&self) -> usize;
    /// Pixels per row, and rows.
    fn size(&self) -> (usize, usize);
    /// Row `i`, columns `j0..j1`, as linear values with the channels
    /// interleaved, into `out` (`(j1 − j0)·channels` values).
    fn read_row(&self, i: usize, j0: usize, j1: usize, out: &mut [f32]);
}

/// Where one axis of a tile samples its source.
#[derive(Clone, Debug)]
pub struct AxisSampling {
    /// Texel centres, in source pixel coordinates (pixel `j`'s centre is `j`).
    pub centres: Vec<f64>,
    /// Tent radius in source pixels (≥ 1; exactly 1 is bilinear).
    pub radius: f64,
}

/// The source pixels one texel reads along one axis, and their weights.
struct Taps {
    first: usize,
    weights: Vec<f32>,
}

fn taps(centre: f64, radius: f64, len: usize) -> Taps {
    let last = len as i64 - 1;
    let lo = (centre - radius).ceil() as i64;
    let hi = (centre + radius).floor() as i64;
    let first = lo.clamp(0, last);
    let end = hi.clamp(0, last);
    let mut w = vec![0.0f64; (end - first + 1) as usize];
    for j in lo..=hi {
        let wt = 1.0 - (j as f64 - centre).abs() / radius;
        if wt > 0.0 {
            // Beyond the edge, the edge pixel stands in (clamp to edge).
            w[(j.clamp(0, last) - first) as usize] += wt;
        }
    }
    // Drop zero weights at either end (a texel on a pixel centre reads one pixel).
    let skip = w.iter().take_while(|&&x| x == 0.0).count().min(w.len() - 1);
    let keep = w.len() - w.iter().rev().take_while(|&&x| x == 0.0).count().min(w.len() - 1 - skip);
    let sum: f64 = w[skip..keep].iter().sum();
    Taps { first: first as usize + skip, weights: w[skip..keep].iter().map(|&x| (x / sum) as f32).collect() }
}

/// Resamples `src` at the texel centres `xs` × `zs`; returns
/// `zs.len() × xs.len()` pixels, row-major, channels interleaved, linear.
pub fn resample<R: Raster + ?Sized>(src: &R, xs: &AxisSampling, zs: &AxisSampling) -> Vec<f32> {
    let (w, h) = src.size();
    let c = src.channels();
    let tx: Vec<Taps> = xs.centres.iter().map(|&p| taps(p, xs.radius, w)).collect();
    let tz: Vec<Taps> = zs.centres.iter().map(|&p| taps(p, zs.radius, h)).collect();
    let span = |t: &[Taps]| {
        let lo = t.iter().map(|t| t.first).min().unwrap_or(0);
        let hi = t.iter().map(|t| t.first + t.weights.len()).max().unwrap_or(0);
        (lo, hi)
    };
    let (j_lo, j_hi) = span(&tx);
    let (i_lo, i_hi) = span(&tz);
    let nx = tx.len();
    // Pass 1: every source row the tile needs, filtered along x.
    let mut rows = vec![0.0f32; (i_hi - i_lo) * nx * c];
    rows.par_chunks_mut(nx * c).enumerate().for_each_init(
        || vec![0.0f32; (j_hi - j_lo) * c],
        |line, (r, out)| {
            src.read_row(i_lo + r, j_lo, j_hi, line);
            for (k, t) in tx.iter().enumerate() {
                let base = (t.first - j_lo) * c;
                for ch in 0..c {
                    let mut acc = 0.0f32;
                    for (q, &wt) in t.weights.iter().enumerate() {
                        acc += wt * line[base + q * c + ch];
                    }
                    out[k * c + ch] = acc;
                }
            }
        },
    );
    // Pass 2: along z.
    let mut out = vec![0.0f32; tz.len() * nx * c];
    out.par_chunks_mut(nx * c).zip(&tz).for_each(|(dst, t)| {
        for (q, &wt) in t.weights.iter().enumerate() {
            let row = &rows[(t.first + q - i_lo) * nx * c..][..nx * c];
            for (d, &s) in dst.iter_mut().zip(row) {
                *d += wt * s;
            }
        }
    });
    out
}

/// sRGB byte → linear light (IEC 61966-2-1).
pub static SRGB_TO_LINEAR: LazyLock<[f32; 256]> = LazyLock::new(|| {
    std::array::from_fn(|i| {
        let v = i as f64 / 255.0;
        (if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }) as f32
    })
});

/// The linear values at which the sRGB byte steps up: byte `k + 1` from
/// the value whose sRGB encoding is `(k + ½)/255`.
static SRGB_STEPS: LazyLock<[f32; 255]> = LazyLock::new(|| {
    std::array::from_fn(|k| {
        let s = (k as f64 + 0.5) / 255.0;
        (if s <= 0.04045 { s / 12.92 } else { ((s + 0.055) / 1.055).powf(2.4) }) as f32
    })
});

/// Buckets of the non-negative f32 below 2, by their top 16 bits.
const SRGB_BUCKETS: usize = (2.0f32.to_bits() >> 16) as usize;

/// Per bucket, the byte of its smallest value: where [`linear_to_srgb`]
/// starts among the steps (a bucket spans at most two of them).
static SRGB_START: LazyLock<Vec<u8>> =
    LazyLock::new(|| (0..SRGB_BUCKETS).map(|b| slow_linear_to_srgb(f32::from_bits((b as u32) << 16))).collect());

/// The byte as the count of steps at or below `v` (NaN: 0).
fn slow_linear_to_srgb(v: f32) -> u8 {
    SRGB_STEPS.partition_point(|&t| t <= v) as u8
}

/// Linear light → sRGB byte, rounded to nearest (inverse of
/// [`SRGB_TO_LINEAR`]): the count of steps at or below `v`, not a power per
/// value, found from the byte of `v`'s bucket (top 16 bits) in a step or
/// two; the same count a binary search of all 255 gives (tested), at a
/// fraction of its cost (it was 3 % of a textured Fuji build).
pub fn linear_to_srgb(v: f32) -> u8 {
    let b = (v.to_bits() >> 16) as usize;
    if b >= SRGB_BUCKETS {
        // Negative, 2 or more, or NaN.
        return slow_linear_to_srgb(v);
    }
    // A bucket holds at most two steps (tested): count them without a
    // loop, whose exit after none, one or two steps the branch predictor
    // cannot guess (it was 30 % of the generated colour map's time).
    let steps = &*SRGB_STEPS;
    let over = |k: usize| usize::from(steps.get(k).is_some_and(|&t| t <= v));
    let k = SRGB_START[b] as usize;
    let k = k + over(k);
    (k + over(k)) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Ramp {
        w: usize,
        h: usize,
    }

    impl Raster for Ramp {
        fn channels(&self) -> usize {
            2
        }
        fn size(&self) -> (usize, usize) {
            (self.w, self.h)
        }
        fn read_row(&self, i: usize, j0: usize, j1: usize, out: &mut [f32]) {
            for j in j0..j1 {
                out[(j - j0) * 2] = j as f32;
                out[(j - j0) * 2 + 1] = i as f32;
            }
        }
    }

    #[test]
    fn srgb_by_bucket_counts_the_steps_as_a_binary_search_does() {
        let mut values = vec![-1.0f32, -0.0, 0.0, 1.0, 2.0, 1e30, f32::INFINITY, f32::NEG_INFINITY, f32::NAN];
        // Every step and its neighbours a few ulps either side.
        for &t in SRGB_STEPS.iter() {
            for d in -4i32..=4 {
                values.push(f32::from_bits(t.to_bits().wrapping_add_signed(d)));
            }
        }
        // A walk over every bucket (and past the last) in odd strides.
        values.extend((0..(SRGB_BUCKETS as u32 + 8) << 16).step_by(4099).map(f32::from_bits));
        for v in values {
            assert_eq!(linear_to_srgb(v), slow_linear_to_srgb(v), "{v:e}");
        }
    }

    /// What `linear_to_srgb` counts on: from its bucket's first byte, a
    /// value passes at most two more steps.
    #[test]
    fn an_srgb_bucket_holds_at_most_two_steps() {
        for b in 0..SRGB_BUCKETS {
            let (lo, hi) = (f32::from_bits((b as u32) << 16), f32::from_bits(((b as u32 + 1) << 16) - 1));
            let inside = SRGB_STEPS.iter().filter(|&&t| t > lo && t <= hi).count();
            assert!(inside <= 2, "bucket {b} ({lo:e}..={hi:e}) holds {inside} steps");
            assert_eq!(SRGB_START[b], slow_linear_to_srgb(lo), "bucket {b}");
        }
    }

    #[test]
    fn srgb_round_trips_every_byte() {
        for b in 0..=255u8 {
            assert_eq!(linear_to_srgb(SRGB_TO_LINEAR[b as usize]), b);
        }
    }

    #[test]
    fn srgb_encoding_rounds_the_standard_curve() {
        for k in 0..=20_000 {
            let v = k as f64 / 20_000.0;
            let s = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
            let want = (s * 255.0).round();
            let got = f64::from(linear_to_srgb(v as f32));
            assert!((got - want).abs() <= f64::from(((s * 255.0).fract() - 0.5).abs() < 1e-4), "{v}: {got} vs {want}");
        }
    }

    #[test]
    fn bilinear_at_pixel_centres_copies_and_between_interpolates() {
        let src = Ramp { w: 5, h: 4 };
        let xs = AxisSampling { centres: vec![0.0, 1.5, 4.0], radius: 1.0 };
        let zs = AxisSampling { centres: vec![0.0, 3.0], radius: 1.0 };
        let out = resample(&src, &xs, &zs);
        let px: Vec<[f32; 2]> = out.chunks(2).map(|p| [p[0], p[1]]).collect();
        assert_eq!(px, vec![[0.0, 0.0], [1.5, 0.0], [4.0, 0.0], [0.0, 3.0], [1.5, 3.0], [4.0, 3.0]]);
    }

    #[test]
    fn a_wide_tent_averages_a_ramp_to_its_centre_and_clamps_at_the_edge() {
        let src = Ramp { w: 40, h: 3 };
        let out = resample(
            &src,
            &AxisSampling { centres: vec![20.0, 0.0], radius: 4.0 },
            &AxisSampling { centres: vec![1.0], radius: 1.0 },
        );
        assert!((out[0] - 20.0).abs() < 1e-5, "{}", out[0]);
        // At the edge the tent's outer half reads pixel 0 again: the mean lies inside.
        assert!(out[2] > 0.0 && out[2] < 1.0, "{}", out[2]);
    }

    #[test]
    fn the_same_centre_gives_the_same_bits_whatever_the_other_texels() {
        // Two tiles sharing an edge at source x = 12.0, with different texel counts across.
        let src = Ramp { w: 30, h: 30 };
        let zs = AxisSampling { centres: (0..7).map(|k| 3.0 + k as f64 * 2.5).collect(), radius: 2.5 };
        let a = resample(&src, &AxisSampling { centres: vec![2.0, 7.0, 12.0], radius: 5.0 }, &zs);
        let b = resample(&src, &AxisSampling { centres: vec![12.0, 15.5, 19.0, 22.5], radius: 5.0 }, &zs);
        for r in 0..7 {
            assert_eq!(a[(r * 3 + 2) * 2..][..2], b[(r * 4) * 2..][..2]);
        }
    }
}
