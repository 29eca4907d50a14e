//! The camera, in f64: position in world metres (glTF frame: x east, y up,
//! z south), yaw and pitch. The GPU only ever sees camera-relative f32 data
//! (each chunk's origin minus the eye, computed here in f64), so precision
//! does not degrade far from the world origin.

/// A pinhole camera with no roll.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position, metres.
    pub eye: [f64; 3],
    /// Heading in degrees: 0 looks north (−z), 90 east (+x).
    pub yaw_deg: f64,
    /// Degrees above the horizon (negative looks down), within ±89.
    pub pitch_deg: f64,
    /// Horizontal field of view, degrees.
    pub hfov_deg: f64,
    /// Near plane distance, metres (the far plane is at infinity).
    pub near_m: f64,
}

impl Camera {
    /// Unit view direction.
    pub fn forward(&self) -> [f64; 3] {
        let (y, p) = (self.yaw_deg.to_radians(), self.pitch_deg.to_radians());
        [y.sin() * p.cos(), p.sin(), -y.cos() * p.cos()]
    }

    /// Unit right vector (horizontal).
    pub fn right(&self) -> [f64; 3] {
        let y = self.yaw_deg.to_radians();
        [y.cos(), 0.0, y.sin()]
    }

    /// Camera-relative view-projection (row-major, f64): rotation only,
    /// then a reversed-Z infinite perspective (depth 1 at the near plane,
    /// → 0 at infinity) for `aspect` = width / height.
    pub fn view_proj(&self, aspect: f64) -> [[f64; 4]; 4] {
        let f = self.forward();
        let r = self.right();
        let u = cross(r, f);
        let tx = 1.0 / (self.hfov_deg.to_radians() / 2.0).tan();
        let ty = tx * aspect;
        // View space: x = r·p, y = u·p, z = −f·p. Clip: (tx·x, ty·y, near, −z).
        [
            [tx * r[0], tx * r[1], tx * r[2], 0.0],
            [ty * u[0], ty * u[1], ty * u[2], 0.0],
            [0.0, 0.0, 0.0, self.near_m],
            [f[0], f[1], f[2], 0.0],
        ]
    }

    /// Pixel coordinates (x right, y down, pixel centres at +0.5) of the
    /// world point `p`, or `None` behind the eye.
    pub fn project(&self, p: [f64; 3], size: [u32; 2]) -> Option<[f64; 2]> {
        let m = self.view_proj(f64::from(size[0]) / f64::from(size[1]));
        let rel = [p[0] - self.eye[0], p[1] - self.eye[1], p[2] - self.eye[2], 1.0];
        let c: Vec<f64> = m.iter().map(|row| (0..4).map(|i| row[i] * rel[i]).sum()).collect();
        if c[3] <= 0.0 {
            return None;
        }
        let (nx, ny) = (c[0] / c[3], c[1] / c[3]);
        Some([(nx + 1.0) / 2.0 * f64::from(size[0]), (1.0 - ny) / 2.0 * f64::from(size[1])])
    }

    /// The view frustum for `aspect` (left, right, bottom, top, near planes).
    pub fn frustum(&self, aspect: f64) -> Frustum {
        let m = self.view_proj(aspect);
        let plane = |s: f64, row: usize| -> [f64; 4] { [0, 1, 2, 3].map(|c| m[3][c] + s * m[row][c]) };
        Frustum {
            eye: self.eye,
            planes: [plane(1.0, 0), plane(-1.0, 0), plane(1.0, 1), plane(-1.0, 1), plane(-1.0, 2)],
        }
    }
}

/// Planes `a·x + b·y + c·z + d ≥ 0` inside, camera-relative.
#[derive(Clone, Copy, Debug)]
pub struct Frustum {
    eye: [f64; 3],
    planes: [[f64; 4]; 5],
}

impl Frustum {
    /// Whether the world box `[min, max]` may be visible (conservative).
    pub fn intersects_box(&self, min: [f64; 3], max: [f64; 3]) -> bool {
        let (lo, hi) = ([0, 1, 2].map(|a| min[a] - self.eye[a]), [0, 1, 2].map(|a| max[a] - self.eye[a]));
        self.planes.iter().all(|p| {
            let v = [0, 1, 2].map(|a| if p[a] >= 0.0 { hi[a] } else { lo[a] });
            p[0] * v[0] + p[1] * v[1] + p[2] * v[2] + p[3] >= 0.0
        })
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera { eye: [100.0, 50.0, 100.0], yaw_deg: 0.0, pitch_deg: 0.0, hfov_deg: 90.0, near_m: 1.0 }
    }

    #[test]
    fn projection_puts_the_view_axis_at_the_centre() {
        let c = cam();
        let p = c.project([100.0, 50.0, 0.0], [640, 480]).unwrap();
        assert!((p[0] - 320.0).abs() < 1e-9 && (p[1] - 240.0).abs() < 1e-9);
        // 90° hfov: a point 45° to the right lands on the right edge.
        let p = c.project([200.0, 50.0, 0.0], [640, 480]).unwrap();
        assert!((p[0] - 640.0).abs() < 1e-9);
        assert!(c.project([100.0, 50.0, 200.0], [640, 480]).is_none());
    }

    #[test]
    fn frustum_culls_boxes_behind_and_beside() {
        let f = cam().frustum(4.0 / 3.0);
        assert!(f.intersects_box([90.0, 0.0, 0.0], [110.0, 60.0, 10.0]));
        assert!(!f.intersects_box([90.0, 0.0, 150.0], [110.0, 60.0, 160.0]), "behind");
        assert!(!f.intersects_box([400.0, 0.0, 40.0], [410.0, 60.0, 50.0]), "far right");
        assert!(f.intersects_box([0.0, 0.0, 0.0], [1000.0, 10.0, 1000.0]), "around the eye");
    }
}
