//! A spinning multi-beam LiDAR in a procedural street: frames as a driver writes them, with the
//! sensor's true poses.
//!
//! The street is an L: a main street along +x that turns left into a cross street along +y at
//! [`TURN_X`]. Building fronts with glazed windows, parked cars, poles and kerb-side clutter
//! line both; the ground is the plane z = 0. The scanner has fixed beam elevations and fixed
//! column azimuths (as Ouster-type sensors), so the same beam and column of two frames taken
//! from nearby poses hit nearly the same place relative to the sensor: the sensor-geometry
//! structure a registration must not mistake for the scene's.
use std::f64::consts::TAU;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::rngs::Xoshiro256PlusPlus;
use rand::{RngExt, SeedableRng};
use rand_distr::Distribution;

use super::{gaussian, splitmix};
use crate::point::Point;

/// Where the main street turns left into the cross street (m along x).
pub const TURN_X: f64 = 250.0;
/// Half the distance between the building fronts of a street (m).
const STREET_HALF_WIDTH: f64 = 9.0;
/// Distance of the parked cars' centres from the street's axis (m).
const PARKING_OFFSET: f64 = 6.4;
/// Distance of the poles from the street's axis (m).
const POLE_OFFSET: f64 = 7.8;
/// Returns closer than this hit the vehicle carrying the sensor and are dropped (m).
const MIN_RANGE: f64 = 1.0;

/// A spinning LiDAR: `beams` fixed elevations by `columns` fixed azimuths per sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct Scanner {
    /// Rows of the organised frame, evenly spread over the elevation range.
    pub beams: usize,
    /// Azimuths per sweep; column j looks at 2π·j / `columns` in the sensor frame.
    pub columns: usize,
    /// Lowest and highest beam elevation (degrees above the sensor's xy-plane).
    pub elevation_degrees: [f64; 2],
    /// Farther surfaces give no return (m).
    pub max_range: f64,
    /// Standard deviation of the range noise along the beam: `[at zero range (m), growth per
    /// metre of range]`.
    pub range_noise: [f64; 2],
    /// Standard deviation of each beam's fixed range offset (m): what is left of a real
    /// sensor's per-laser calibration, the same in every sweep.
    pub beam_range_bias: f64,
}

impl Scanner {
    /// A 32-beam, 1024-column sensor with a ±22.5° field of view (as an Ouster OS1-32), range
    /// noise 1 cm + 1 mm per 10 m.
    pub fn thirty_two_beams() -> Self {
        Scanner {
            beams: 32,
            columns: 1024,
            elevation_degrees: [-22.5, 22.5],
            max_range: 120.0,
            range_noise: [0.01, 0.0001],
            beam_range_bias: 0.005,
        }
    }

    /// A 64-beam, 2048-column sensor looking mostly down (−24.8° to +2°, as a Velodyne HDL-64),
    /// range noise 1 cm + 1 mm per 10 m, beam offsets of 5 mm.
    pub fn sixty_four_beams() -> Self {
        Scanner {
            beams: 64,
            columns: 2048,
            elevation_degrees: [-24.8, 2.0],
            ..Scanner::thirty_two_beams()
        }
    }

    /// Each beam's fixed range offset, the same for every sweep of this scanner.
    fn beam_offsets(&self) -> Vec<f64> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(0x5CA7_7E12);
        let unit = gaussian(1.0);
        (0..self.beams)
            .map(|_| self.beam_range_bias * unit.sample(&mut rng))
            .collect()
    }

    /// Unit direction of beam `beam`, column `column`, in the sensor frame.
    fn direction(&self, beam: usize, column: usize) -> Vector3<f64> {
        let [low, high] = self.elevation_degrees;
        let share = if self.beams > 1 {
            beam as f64 / (self.beams - 1) as f64
        } else {
            0.5
        };
        let elevation = (low + share * (high - low)).to_radians();
        let azimuth = TAU * column as f64 / self.columns.max(1) as f64;
        Vector3::new(
            elevation.cos() * azimuth.cos(),
            elevation.cos() * azimuth.sin(),
            elevation.sin(),
        )
    }

    /// One sweep from `pose` (T_world_sensor), organised beam-major: `beams × columns` points in
    /// the sensor frame, a missing return (no surface in range, glass, sky) written as
    /// `[0, 0, 0]` as drivers write it. Range noise along each beam from a stream seeded by
    /// `seed`.
    ///
    /// `motion_during_sweep`: the sensor's motion from the first column to the end of the
    /// sweep (T_start_end), for a sweep taken while moving; column j is then measured from
    /// `pose` moved by the share j / `columns` of it and written in the sensor's frame at that
    /// moment, as a driver without de-skewing writes it: the sweep is distorted by the motion.
    pub fn sweep(
        &self,
        street: &Street,
        pose: &Isometry3<f64>,
        motion_during_sweep: Option<&Isometry3<f64>>,
        seed: u64,
    ) -> Vec<Point> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let near: Vec<&Solid> = street
            .solids
            .iter()
            .filter(|s| s.within(&pose.translation.vector, self.max_range + 50.0))
            .collect();
        let unit_noise = gaussian(1.0);
        let beam_offsets = self.beam_offsets();
        let mut frame = vec![[0.0; 3]; self.beams * self.columns];
        for column in 0..self.columns {
            let skew = motion_during_sweep.map_or_else(Isometry3::identity, |motion| {
                motion_share(motion, column as f64 / self.columns as f64)
            });
            let column_pose = pose * skew;
            for beam in 0..self.beams {
                let direction = self.direction(beam, column);
                let world_direction = column_pose.rotation * direction;
                let origin = column_pose.translation.vector;
                let hit = near
                    .iter()
                    .filter_map(|s| s.hit(&origin, &world_direction))
                    .chain(ground_hit(&origin, &world_direction).map(Hit::Surface))
                    .min_by(|a, b| a.range().total_cmp(&b.range()));
                let noise = unit_noise.sample(&mut rng);
                let Some(Hit::Surface(range)) = hit else {
                    continue;
                };
                if !(MIN_RANGE..=self.max_range).contains(&range) {
                    continue;
                }
                let measured =
                    range + beam_offsets[beam] + noise * (self.range_noise[0] + self.range_noise[1] * range);
                let p = direction * measured;
                frame[beam * self.columns + column] = [p.x, p.y, p.z];
            }
        }
        frame
    }
}

/// The share `s` ∈ [0, 1] of a motion: rotation by s of its angle, s of its translation.
fn motion_share(motion: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
    let rotation = UnitQuaternion::identity().slerp(&motion.rotation, s);
    Isometry3::from_parts(Translation3::from(motion.translation.vector * s), rotation)
}

/// What a beam meets first.
#[derive(Clone, Copy, Debug)]
enum Hit {
    /// A surface that returns the beam, at this range.
    Surface(f64),
    /// Glass at this range: the beam passes and nothing comes back.
    Glass(f64),
}

impl Hit {
    fn range(&self) -> f64 {
        match *self {
            Hit::Surface(r) | Hit::Glass(r) => r,
        }
    }
}

fn ground_hit(origin: &Vector3<f64>, direction: &Vector3<f64>) -> Option<f64> {
    (direction.z < -1e-12)
        .then(|| -origin.z / direction.z)
        .filter(|&t| t > 0.0)
}

/// A solid of the street.
#[derive(Clone, Debug, PartialEq)]
enum Solid {
    /// An axis-aligned box; a building's sides carry windows (glass) on every storey.
    Block {
        min: [f64; 3],
        max: [f64; 3],
        glazed: bool,
    },
    /// A vertical cylinder standing on the ground.
    Pole {
        centre: [f64; 2],
        radius: f64,
        height: f64,
    },
}

/// Storey height and the window band within a storey (m): windows from 1.0 to 2.3 m above each
/// storey's floor, 1.6 m wide every 3 m along the front.
const STOREY: f64 = 3.0;
const WINDOW_BAND: [f64; 2] = [1.0, 2.3];
const WINDOW_PITCH: f64 = 3.0;
const WINDOW_WIDTH: f64 = 1.6;

impl Solid {
    fn within(&self, centre: &Vector3<f64>, reach: f64) -> bool {
        let (min, max) = match self {
            Solid::Block { min, max, .. } => (*min, *max),
            Solid::Pole {
                centre: c,
                radius,
                height,
            } => (
                [c[0] - radius, c[1] - radius, 0.0],
                [c[0] + radius, c[1] + radius, *height],
            ),
        };
        let gap: f64 = (0..2)
            .map(|d| (min[d] - centre[d]).max(centre[d] - max[d]).max(0.0).powi(2))
            .sum();
        gap.sqrt() <= reach
    }

    fn hit(&self, origin: &Vector3<f64>, direction: &Vector3<f64>) -> Option<Hit> {
        match self {
            Solid::Block { min, max, glazed } => {
                let (mut enter, mut exit, mut face) = (f64::NEG_INFINITY, f64::INFINITY, 0);
                for d in 0..3 {
                    if direction[d].abs() < 1e-15 {
                        if origin[d] < min[d] || origin[d] > max[d] {
                            return None;
                        }
                        continue;
                    }
                    let (a, b) = (
                        (min[d] - origin[d]) / direction[d],
                        (max[d] - origin[d]) / direction[d],
                    );
                    let (near, far) = if a < b { (a, b) } else { (b, a) };
                    if near > enter {
                        enter = near;
                        face = d;
                    }
                    exit = exit.min(far);
                }
                if enter > exit || enter <= 0.0 {
                    return None;
                }
                let p = origin + direction * enter;
                // Windows on the vertical faces: along the face, and by height.
                let along = if face == 0 { p.y } else { p.x };
                let in_window = *glazed
                    && face != 2
                    && (p.z % STOREY) >= WINDOW_BAND[0]
                    && (p.z % STOREY) <= WINDOW_BAND[1]
                    && along.rem_euclid(WINDOW_PITCH) < WINDOW_WIDTH;
                Some(if in_window {
                    Hit::Glass(enter)
                } else {
                    Hit::Surface(enter)
                })
            }
            Solid::Pole {
                centre,
                radius,
                height,
            } => {
                let (ox, oy) = (origin.x - centre[0], origin.y - centre[1]);
                let a = direction.x * direction.x + direction.y * direction.y;
                if a < 1e-15 {
                    return None;
                }
                let b = ox * direction.x + oy * direction.y;
                let c = ox * ox + oy * oy - radius * radius;
                let discriminant = b * b - a * c;
                if discriminant < 0.0 {
                    return None;
                }
                let t = (-b - discriminant.sqrt()) / a;
                let z = origin.z + t * direction.z;
                (t > 0.0 && (0.0..=*height).contains(&z)).then_some(Hit::Surface(t))
            }
        }
    }
}

/// The street the scanner drives through: building blocks, parked cars, poles and clutter.
#[derive(Clone, Debug, PartialEq)]
pub struct Street {
    solids: Vec<Solid>,
}

impl Street {
    /// A street drawn from `seed` (see the module's description) whose cross street reaches
    /// `cross_street_end` along y (m).
    pub fn generate(seed: u64, cross_street_end: f64) -> Street {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut solids = Vec::new();
        let w = STREET_HALF_WIDTH;
        // Building rows: (along the x axis?, fixed coordinate of the front, side: +1 the
        // buildings lie beyond the front in +, −1 in −, from, to).
        let rows = [
            (true, w, 1.0, -60.0, TURN_X - w),
            (true, -w, -1.0, -60.0, TURN_X + w + 12.0),
            (false, TURN_X + w, 1.0, -w - 12.0, cross_street_end),
            (false, TURN_X - w, -1.0, w, cross_street_end),
        ];
        for (along_x, front, side, from, to) in rows {
            let mut at = from;
            while at < to {
                let length = rng.random_range(8.0..25.0f64).min(to - at);
                let setback = rng.random_range(0.0..1.5);
                let height = rng.random_range(6.0..20.0);
                let (near, far) = (front + side * setback, front + side * (setback + 10.0));
                let (lo, hi) = (near.min(far), near.max(far));
                let (min, max) = if along_x {
                    ([at, lo, 0.0], [at + length, hi, height])
                } else {
                    ([lo, at, 0.0], [hi, at + length, height])
                };
                solids.push(Solid::Block {
                    min,
                    max,
                    glazed: true,
                });
                at += length + rng.random_range(0.0..4.0);
            }
        }
        // Parked cars, poles and clutter along both kerbs of both streets.
        let kerbs = [
            (true, 1.0, -60.0, TURN_X - w - 2.0),
            (true, -1.0, -60.0, TURN_X + w),
            (false, 1.0, w + 2.0, cross_street_end),
            (false, -1.0, w + 2.0, cross_street_end),
        ];
        let axis = |along_x: bool| if along_x { 0.0 } else { TURN_X };
        for (along_x, side, from, to) in kerbs {
            let place = |s: f64, offset: f64| -> [f64; 2] {
                if along_x {
                    [s, side * offset]
                } else {
                    [axis(along_x) + side * offset, s]
                }
            };
            let mut at = from;
            while at < to {
                at += rng.random_range(1.0..9.0);
                let [cx, cy] = place(at + 2.2, PARKING_OFFSET);
                let (half_long, half_wide) = (2.2, 0.9);
                let (hx, hy) = if along_x {
                    (half_long, half_wide)
                } else {
                    (half_wide, half_long)
                };
                solids.push(Solid::Block {
                    min: [cx - hx, cy - hy, 0.3],
                    max: [cx + hx, cy + hy, 1.0],
                    glazed: false,
                });
                let (cabin_x, cabin_y) = if along_x { (1.2, 0.8) } else { (0.8, 1.2) };
                solids.push(Solid::Block {
                    min: [cx - cabin_x, cy - cabin_y, 1.0],
                    max: [cx + cabin_x, cy + cabin_y, 1.5],
                    glazed: false,
                });
                at += 4.4;
            }
            let mut at = from + rng.random_range(0.0..10.0);
            while at < to {
                solids.push(Solid::Pole {
                    centre: place(at, POLE_OFFSET),
                    radius: 0.1,
                    height: 7.0,
                });
                at += rng.random_range(15.0..25.0);
            }
            let mut at = from;
            while at < to {
                at += rng.random_range(3.0..15.0);
                let [cx, cy] = place(at, w - rng.random_range(0.3..0.8));
                let half = rng.random_range(0.25..0.5);
                solids.push(Solid::Block {
                    min: [cx - half, cy - half, 0.0],
                    max: [cx + half, cy + half, rng.random_range(0.5..1.2)],
                    glazed: false,
                });
            }
        }
        Street { solids }
    }
}

/// A drive through a [`Street`]: sweeps and the sensor's true poses.
#[derive(Clone, Debug, PartialEq)]
pub struct Drive {
    /// Sweep i, organised (`beams × columns`, missing returns `[0, 0, 0]`), in the sensor
    /// frame at the start of the sweep.
    pub frames: Vec<Vec<Point>>,
    /// T_world_sensor at the start of sweep i.
    pub poses: Vec<Isometry3<f64>>,
}

/// Height of the sensor above the ground (m).
pub const SENSOR_HEIGHT: f64 = 1.8;

/// Sensor poses of a drive along the street at 10 Hz, `frames` of them: stand for the first
/// tenth, accelerate at 4 m/s² to 20 m/s, brake at 6 m/s² to 4 m/s for the left turn at
/// [`TURN_X`] (a quarter circle of 9 m radius), then accelerate again; from seven tenths brake
/// to a standstill of at least a tenth of the frames. Up to 2 m between frames at full speed.
/// Small pitch and roll from the suspension. The whole story takes about 300 frames; a shorter
/// drive ends earlier in it.
pub fn drive_poses(frames: usize) -> Vec<Isometry3<f64>> {
    const RATE: f64 = 10.0;
    const TOP_SPEED: f64 = 20.0;
    const TURN_SPEED: f64 = 4.0;
    const ACCELERATION: f64 = 4.0;
    const BRAKING: f64 = 6.0;
    const TURN_RADIUS: f64 = 9.0;
    let dt = 1.0 / RATE;
    let stand_until = frames / 10;
    let stop_from = frames * 7 / 10;
    // Braking from full speed takes 34 frames.
    let stop_until = stop_from + frames / 10 + 35;
    // Arc length along the path: straight to TURN_X − R, quarter circle, straight along +y.
    let turn_start = TURN_X - TURN_RADIUS;
    let turn_length = TURN_RADIUS * std::f64::consts::FRAC_PI_2;
    // The start: far enough from the turn to reach full speed after the first standstill.
    let (mut s, mut speed) = (TURN_X - 110.0, 0.0_f64);
    let mut poses = Vec::with_capacity(frames);
    for i in 0..frames {
        let standing = i < stand_until || (stop_from..stop_until).contains(&i);
        // The speed that still allows braking to TURN_SPEED before the turn.
        let to_turn = turn_start - s;
        let brake_limit = if to_turn > 0.0 {
            (TURN_SPEED * TURN_SPEED + 2.0 * BRAKING * to_turn).sqrt()
        } else if to_turn > -turn_length {
            TURN_SPEED
        } else {
            TOP_SPEED
        };
        let (x, y, heading) = if s < turn_start {
            (s, 0.0, 0.0)
        } else if s < turn_start + turn_length {
            let angle = (s - turn_start) / TURN_RADIUS;
            (
                turn_start + TURN_RADIUS * angle.sin(),
                TURN_RADIUS * (1.0 - angle.cos()),
                angle,
            )
        } else {
            (
                TURN_X,
                TURN_RADIUS + (s - turn_start - turn_length),
                std::f64::consts::FRAC_PI_2,
            )
        };
        let sway = (s * 0.37).sin();
        let rotation = UnitQuaternion::from_euler_angles(0.004 * sway, 0.006 * (s * 0.23).cos(), heading);
        poses.push(Isometry3::from_parts(
            Translation3::new(x, y, SENSOR_HEIGHT + 0.01 * sway),
            rotation,
        ));
        let target = if standing { 0.0 } else { TOP_SPEED.min(brake_limit) };
        speed = if target > speed {
            (speed + ACCELERATION * dt).min(target)
        } else {
            (speed - BRAKING * dt).max(target)
        };
        s += speed * dt;
    }
    poses
}

/// A drive of `frames` sweeps through the street of `seed` with `scanner` (see [`drive_poses`]).
/// With `skewed`, each sweep is taken while moving towards the next pose (motion distortion).
pub fn drive(scanner: &Scanner, frames: usize, seed: u64, skewed: bool) -> Drive {
    let poses = drive_poses(frames);
    let reach = poses.last().map_or(0.0, |p| p.translation.y) + scanner.max_range;
    let street = Street::generate(seed, reach.max(100.0));
    let frames = poses
        .iter()
        .enumerate()
        .map(|(i, pose)| {
            let motion = poses.get(i + 1).map(|next| pose.inverse() * next);
            let skew = if skewed { motion.as_ref() } else { None };
            scanner.sweep(&street, pose, skew, seed ^ splitmix(i as u64 + 1))
        })
        .collect();
    Drive { frames, poses }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small_scanner() -> Scanner {
        Scanner {
            columns: 256,
            ..Scanner::thirty_two_beams()
        }
    }

    fn at(x: f64, y: f64) -> Isometry3<f64> {
        Isometry3::translation(x, y, SENSOR_HEIGHT)
    }

    #[test]
    fn a_sweep_is_organised_with_missing_returns_at_the_origin() {
        let scanner = small_scanner();
        let street = Street::generate(3, 100.0);
        let frame = scanner.sweep(&street, &at(20.0, 0.0), None, 1);
        assert_eq!(frame.len(), 32 * 256);
        let missing = frame.iter().filter(|p| **p == [0.0; 3]).count();
        // The upper beams see sky over the street and glass in the fronts.
        assert!(
            missing > frame.len() / 20 && missing < frame.len() / 2,
            "{missing}"
        );
        // The lowest beam, looking forward along the street, meets the ground at h / tan(22.5°)
        // (within the range noise).
        let ground = frame[0];
        let expected = SENSOR_HEIGHT / 22.5f64.to_radians().tan();
        assert!(
            (ground[0] - expected).abs() < 0.06 && ground[1].abs() < 1e-9,
            "{ground:?}"
        );
        assert!((ground[2] + SENSOR_HEIGHT).abs() < 0.03, "{ground:?}");
    }

    #[test]
    fn sweeps_are_reproducible_from_their_seeds() {
        let scanner = small_scanner();
        let street = Street::generate(3, 100.0);
        let pose = at(10.0, 0.5);
        let a = scanner.sweep(&street, &pose, None, 1);
        assert_eq!(a, scanner.sweep(&Street::generate(3, 100.0), &pose, None, 1));
        let b = scanner.sweep(&street, &pose, None, 2);
        // Same rays, other noise: the same returns, at other ranges.
        assert_eq!(
            a.iter().map(|p| *p == [0.0; 3]).collect::<Vec<_>>(),
            b.iter().map(|p| *p == [0.0; 3]).collect::<Vec<_>>()
        );
        assert_ne!(a, b);
        assert_ne!(Street::generate(3, 100.0), Street::generate(4, 100.0));
    }

    #[test]
    fn a_skewed_sweep_measures_each_column_from_where_the_sensor_then_is() {
        let scanner = small_scanner();
        let street = Street::generate(3, 100.0);
        let pose = at(10.0, 0.0);
        // A turning sweep: 1 m forward and 10° to the left.
        let motion = Isometry3::from_parts(
            Translation3::new(1.0, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 10f64.to_radians()),
        );
        let skewed = scanner.sweep(&street, &pose, Some(&motion), 1);
        // Column 0 is measured before any motion; column 64 of 256 (looking left, at the fronts)
        // a quarter along it. Each column is what a still sweep from that pose measures (the
        // same rays, the same noise).
        let still = scanner.sweep(&street, &pose, None, 1);
        let quarter_way = scanner.sweep(&street, &(pose * motion_share(&motion, 0.25)), None, 1);
        let columns = 256;
        for beam in 0..32 {
            assert_eq!(skewed[beam * columns], still[beam * columns], "beam {beam}");
            assert_eq!(
                skewed[beam * columns + 64],
                quarter_way[beam * columns + 64],
                "beam {beam}"
            );
        }
        // And it is distorted: returns of column 64 differ from the still sweep's.
        assert!((0..32).any(|beam| skewed[beam * columns + 64] != still[beam * columns + 64]));
    }

    #[test]
    fn a_drive_stands_accelerates_turns_and_stops() {
        let frames = 300;
        let poses = drive_poses(frames);
        assert_eq!(poses.len(), frames);
        let step = |i: usize| (poses[i + 1].translation.vector - poses[i].translation.vector).norm();
        assert_eq!(step(0), 0.0);
        let steps: Vec<f64> = (0..frames - 1).map(step).collect();
        let longest = steps.iter().copied().fold(0.0, f64::max);
        // 2 m a frame at 20 m/s, and the suspension's millimetres.
        assert!(longest > 1.9 && longest <= 2.001, "{longest}");
        // A standstill late in the drive, after moving.
        let still = (frames / 2..frames - 1).filter(|&i| steps[i] == 0.0).count();
        assert!(still >= frames / 10, "{still}");
        // The heading turns through 90° (the left turn into the cross street).
        let heading = |i: usize| poses[i].rotation.euler_angles().2.to_degrees();
        assert!(heading(0).abs() < 1.0 && (heading(frames - 1) - 90.0).abs() < 1.0);
        let turning = (0..frames - 1)
            .map(|i| (heading(i + 1) - heading(i)).abs())
            .fold(0.0, f64::max);
        assert!(turning > 2.0, "{turning}");
    }
}
