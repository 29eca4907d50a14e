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
        if let Some(i) = f.cameras.iter().position(|c| c[4].abs() > 89.0) {
            bail!("{}: camera {i} has pitch {}°, beyond ±89°", path.display(), f.cameras[i][4]);
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

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<Flythrough> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("path.json");
        std::fs::write(&p, text).unwrap();
        Flythrough::read(&p)
    }

    fn base() -> Camera {
        Camera { eye: [0.0; 3], yaw_deg: 0.0, pitch_deg: 0.0, hfov_deg: 50.0, near_m: 2.0 }
    }

    #[test]
    fn frames_run_from_each_camera_to_the_next_and_end_on_the_last() {
        let f = read(r#"{"cameras": [[0,10,0,0,-10], [40,10,0,90,-30], [40,50,80,90,-30]], "frames_per_segment": 4}"#)
            .unwrap();
        let frames = f.frames(&base());
        assert_eq!(frames.len(), 2 * 4 + 1);
        assert_eq!(frames[0].eye, [0.0, 10.0, 0.0]);
        assert_eq!(frames[2].eye, [20.0, 10.0, 0.0]);
        assert_eq!((frames[2].yaw_deg, frames[2].pitch_deg), (45.0, -20.0));
        assert_eq!(frames[4].eye, [40.0, 10.0, 0.0]);
        assert_eq!(frames[8].eye, [40.0, 50.0, 80.0]);
        assert!(frames.iter().all(|c| c.hfov_deg == 50.0 && c.near_m == 2.0), "fov and near from the base");
        // One camera: one frame; the default is 30 frames a segment.
        let f = read(r#"{"cameras": [[1,2,3,4,5]]}"#).unwrap();
        assert_eq!(f.frames_per_segment, 30);
        assert_eq!(f.frames(&base()).len(), 1);
    }

    #[test]
    fn yaw_turns_the_short_way_round() {
        let f = read(r#"{"cameras": [[0,0,0,350,0], [0,0,0,10,0]], "frames_per_segment": 2}"#).unwrap();
        let frames = f.frames(&base());
        assert_eq!(frames[1].yaw_deg, 360.0, "through north, not back through 180");
    }

    #[test]
    fn bad_files_are_errors_naming_the_file() {
        for (text, says) in [
            ("", "not a flythrough"),
            ("{", "not a flythrough"),
            (r#"{"cameras": []}"#, "at least one camera"),
            (r#"{"cameras": [[0,0,0,0,0]], "frames_per_segment": 0}"#, "frames_per_segment"),
            (r#"{"cameras": [[0,0,0,0]]}"#, "not a flythrough"),
            (r#"{"cameras": [[0,0,0,0,0]], "speed": 3}"#, "not a flythrough"),
            (r#"{"cameras": [[0,0,0,0,0], [0,0,0,0,95]]}"#, "camera 1 has pitch 95"),
        ] {
            let e = format!("{:#}", read(text).expect_err(text));
            assert!(e.contains("path.json") && e.contains(says), "{text}: {e}");
        }
        let e = format!("{:#}", Flythrough::read(Path::new("/nonexistent/fly.json")).unwrap_err());
        assert!(e.contains("fly.json: cannot read"), "{e}");
    }
}
