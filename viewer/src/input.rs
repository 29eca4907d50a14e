//! What the keys and the mouse do, apart from the window: the window loop
//! (`main.rs`) turns winit events into these calls, and the tests drive
//! them directly.
//!
//! Keys: `f` fog, `l` lighting, `w` the mode (shaded → wireframe → both),
//! `k` skirts, `m` the morph schedule, `+`/`-` τ ×/÷ √2 (capped at the
//! tileset's τ_max unless forced), `q` quit. Flying: forward/back, left/
//! right, up/down at a speed that follows the height above the terrain's
//! lowest point, ×4 with shift. Right mouse button held: mouse-look.

use std::collections::HashSet;

use terrachunk::lod::MorphSchedule;

use crate::camera::Camera;
use crate::viewer::Options;

/// What a key asks of the window loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    /// Nothing beyond the change to the options.
    None,
    /// Close the viewer.
    Quit,
}

/// Applies one key press (the character it types) to the options.
pub fn key(opts: &mut Options, typed: &str) -> Action {
    let look = &mut opts.look;
    match typed {
        "f" => look.fog = !look.fog,
        "l" => look.lighting = !look.lighting,
        "w" => look.mode = look.mode.next(),
        "k" => look.skirts = !look.skirts,
        "m" => {
            opts.schedule = match opts.schedule {
                MorphSchedule::Bounded => MorphSchedule::Ulrich,
                MorphSchedule::Ulrich => MorphSchedule::Bounded,
            }
        }
        "+" | "=" => {
            opts.set_tau(opts.tau_px * std::f64::consts::SQRT_2);
        }
        "-" => {
            opts.set_tau(opts.tau_px / std::f64::consts::SQRT_2);
        }
        "q" => return Action::Quit,
        _ => {}
    }
    Action::None
}

/// A direction of flight, held down.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Move {
    /// Along the view direction.
    Forward,
    /// Against it.
    Back,
    /// Horizontally to the right.
    Right,
    /// To the left.
    Left,
    /// Straight up.
    Up,
    /// Straight down.
    Down,
    /// Four times as fast.
    Fast,
}

/// Moves the camera for `dt_s` seconds with the `held` directions, at a
/// speed of 0.6 × the height above `ground_m` per second (at least 5 m up),
/// so that flying feels the same over a hill and over a continent.
pub fn fly(cam: &mut Camera, held: &HashSet<Move>, dt_s: f64, ground_m: f64) {
    let alt = (cam.eye[1] - ground_m).max(5.0);
    let mut speed = alt * 0.6 * dt_s;
    if held.contains(&Move::Fast) {
        speed *= 4.0;
    }
    let (f, r) = (cam.forward(), cam.right());
    let axes = [
        (Move::Forward, f, 1.0),
        (Move::Back, f, -1.0),
        (Move::Right, r, 1.0),
        (Move::Left, r, -1.0),
        (Move::Up, [0.0, 1.0, 0.0], 1.0),
        (Move::Down, [0.0, 1.0, 0.0], -1.0),
    ];
    for (m, dir, sign) in axes {
        if held.contains(&m) {
            for (e, d) in cam.eye.iter_mut().zip(dir) {
                *e += sign * d * speed;
            }
        }
    }
}

/// Mouse-look: `dx`, `dy` in pixels of mouse motion, 0.15° each; pitch
/// stays within ±89°.
pub fn look(cam: &mut Camera, dx: f64, dy: f64) {
    cam.yaw_deg = (cam.yaw_deg + dx * 0.15).rem_euclid(360.0);
    cam.pitch_deg = (cam.pitch_deg - dy * 0.15).clamp(-89.0, 89.0);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Look, Mode};

    fn opts() -> Options {
        Options {
            tau_px: 2.0,
            tau_max_px: Some(4.0),
            force_tau: false,
            schedule: MorphSchedule::Bounded,
            budget_bytes: 1 << 20,
            threads: 1,
            max_pending: 4,
            max_uploads_per_frame: 4,
            upload_bytes_per_frame: 1 << 20,
            upload_ms_per_frame: None,
            fade_frames: 8,
            prefetch: true,
            lookahead_frames: 10.0,
            look: Look {
                fog: true,
                lighting: true,
                mode: Mode::Shaded,
                skirts: true,
                clear: [0.0; 3],
                fog_density: 1e-3,
                sun: [0.0, 1.0, 0.0],
            },
        }
    }

    fn cam() -> Camera {
        Camera { eye: [0.0, 105.0, 0.0], yaw_deg: 90.0, pitch_deg: 0.0, hfov_deg: 60.0, near_m: 1.0 }
    }

    #[test]
    fn f_l_and_k_toggle_fog_lighting_and_skirts() {
        let mut o = opts();
        for (k, get) in [
            ("f", (|o: &Options| o.look.fog) as fn(&Options) -> bool),
            ("l", |o: &Options| o.look.lighting),
            ("k", |o: &Options| o.look.skirts),
        ] {
            let before = get(&o);
            assert_eq!(key(&mut o, k), Action::None);
            assert_eq!(get(&o), !before, "{k}");
            key(&mut o, k);
            assert_eq!(get(&o), before, "{k}");
        }
    }

    #[test]
    fn w_cycles_shaded_wireframe_and_overlay() {
        let mut o = opts();
        let mut seen = vec![o.look.mode];
        for _ in 0..3 {
            key(&mut o, "w");
            seen.push(o.look.mode);
        }
        assert_eq!(seen, [Mode::Shaded, Mode::Wireframe, Mode::Overlay, Mode::Shaded]);
    }

    #[test]
    fn m_switches_the_morph_schedule() {
        let mut o = opts();
        key(&mut o, "m");
        assert_eq!(o.schedule, MorphSchedule::Ulrich);
        key(&mut o, "m");
        assert_eq!(o.schedule, MorphSchedule::Bounded);
    }

    #[test]
    fn plus_and_minus_scale_tau_and_stop_at_tau_max() {
        let mut o = opts();
        key(&mut o, "-");
        assert!((o.tau_px - 2.0 / 2f64.sqrt()).abs() < 1e-12);
        key(&mut o, "+");
        key(&mut o, "=");
        assert!((o.tau_px - 2.0 * 2f64.sqrt()).abs() < 1e-12);
        for _ in 0..5 {
            key(&mut o, "+");
        }
        assert_eq!(o.tau_px, 4.0, "capped at τ_max");
        o.force_tau = true;
        key(&mut o, "+");
        assert!((o.tau_px - 4.0 * 2f64.sqrt()).abs() < 1e-12, "forced past τ_max");
    }

    #[test]
    fn q_quits_and_other_keys_do_nothing() {
        let mut o = opts();
        assert_eq!(key(&mut o, "q"), Action::Quit);
        let before = format!("{:?}", o.look);
        assert_eq!(key(&mut o, "x"), Action::None);
        assert_eq!(format!("{:?}", o.look), before);
        assert_eq!(o.tau_px, 2.0);
    }

    #[test]
    fn each_move_key_flies_its_way_at_a_speed_set_by_height() {
        // Looking east from 100 m above the ground: 60 m/s, one second.
        let cases = [
            (Move::Forward, [60.0, 0.0, 0.0]),
            (Move::Back, [-60.0, 0.0, 0.0]),
            (Move::Right, [0.0, 0.0, 60.0]),
            (Move::Left, [0.0, 0.0, -60.0]),
            (Move::Up, [0.0, 60.0, 0.0]),
            (Move::Down, [0.0, -60.0, 0.0]),
        ];
        for (m, want) in cases {
            let mut c = cam();
            fly(&mut c, &HashSet::from([m]), 1.0, 5.0);
            for (a, w) in want.iter().enumerate() {
                assert!((c.eye[a] - cam().eye[a] - w).abs() < 1e-9, "{m:?}: {:?}", c.eye);
            }
        }
        let mut c = cam();
        fly(&mut c, &HashSet::from([Move::Forward, Move::Fast]), 0.5, 5.0);
        assert!((c.eye[0] - 120.0).abs() < 1e-9, "shift: ×4");
        // Near the ground the speed keeps a floor of 5 m of height.
        let mut c = cam();
        fly(&mut c, &HashSet::from([Move::Up]), 1.0, 200.0);
        assert!((c.eye[1] - 108.0).abs() < 1e-9, "{:?}", c.eye);
    }

    #[test]
    fn mouse_look_turns_and_keeps_pitch_within_89_degrees() {
        let mut c = cam();
        look(&mut c, 100.0, -100.0);
        assert!((c.yaw_deg - 105.0).abs() < 1e-12 && (c.pitch_deg - 15.0).abs() < 1e-12);
        look(&mut c, 2000.0, -2000.0);
        assert!((c.yaw_deg - (105.0f64 + 300.0).rem_euclid(360.0)).abs() < 1e-9);
        assert_eq!(c.pitch_deg, 89.0);
        look(&mut c, 0.0, 5000.0);
        assert_eq!(c.pitch_deg, -89.0);
    }
}
