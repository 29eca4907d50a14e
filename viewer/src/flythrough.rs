//! Camera paths for `--flythrough`: a JSON file
//! `{"cameras": [[x, y, z, yaw, pitch], …], "frames_per_segment": 30}`
//! (world metres, degrees; see [`crate::camera::Camera`]), flown at a
//! constant number of frames between consecutive cameras, linearly
//! interpolated (yaw the short way round).

use std::path::Path;

use anyhow::{Context, Result, bail};
use serde::Deserialize;

use crate::camera::Camera;

/// A flythrough file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Flythrough {
    /// Key cameras: x, y, z (m), yaw, pitch (degrees).
    pub cameras: Vec<[f64; 5]>,
    /// Frames from one key camera to the next (≥ 1).
    #[serde(default = "default_frames")]
    pub frames_per_segment: u32,
}

fn default_frames() -> u32 {
    30
}

impl Flythrough {
    /// Reads a flythrough file.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?;
        let f: Flythrough =
            serde_json::from_str(&text).with_context(|| format!("{}: not a flythrough", path.display()))?;
        if f.cameras.is_empty() || f.frames_per_segment == 0 {
            bail!("{}: needs at least one camera and frames_per_segment ≥ 1", path.display());
        }
        Ok(f)
    }

    /// Every frame's camera (`base` gives fov and near plane).
    pub fn frames(&self, base: &Camera) -> Vec<Camera> {
        let cam = |c: [f64; 5]| Camera { eye: [c[0], c[1], c[2]], yaw_deg: c[3], pitch_deg: c[4], ..*base };
        let mut out = Vec::new();
        for w in self.cameras.windows(2) {
            let (a, b) = (w[0], w[1]);
            let dyaw = (b[3] - a[3] + 540.0).rem_euclid(360.0) - 180.0;
            for i in 0..self.frames_per_segment {
                let t = f64::from(i) / f64::from(self.frames_per_segment);
                let mut c: [f64; 5] = std::array::from_fn(|k| a[k] + t * (b[k] - a[k]));
                c[3] = a[3] + t * dyaw;
                out.push(cam(c));
            }
        }
        out.push(cam(*self.cameras.last().expect("non-empty")));
        out
    }
}
