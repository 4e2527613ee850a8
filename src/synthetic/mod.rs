//! Deterministic (seeded) test scenes shared by the demo, the tests and the benchmarks.
//!
//! * [`paper_simulation`]: the paper's correspondence experiment (§6).
//! * [`structured_simulation`] and [`random_motion`]: the same beyond the paper's grid: any
//!   motion, and outliers that follow a second rigid motion.
//! * [`room_scene`]: two partially overlapping noisy scans of a furnished room, with ground truth.
//! * [`room_trajectory`]: a scanner moving through that room, frame by frame, with its poses.
//! * [`depth_camera_trajectory`]: a depth camera on the same path, its noise growing as depth².
//! * [`lidar`]: a spinning multi-beam LiDAR driving through a procedural street.
use std::f64::consts::TAU;

use nalgebra::{Isometry3, Matrix4, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use rand::rngs::Xoshiro256PlusPlus;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

use crate::point::Point;

pub mod lidar;

/// Point pairs for correspondence registration: `source[i]` ↔ `target[i]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Correspondences {
    /// A after T0 (inliers only; outliers' A is left as drawn).
    pub source: Vec<Point>,
    /// B.
    pub target: Vec<Point>,
    /// Which pairs are inliers (the first `inliers` ones).
    pub is_inlier: Vec<bool>,
}

/// The paper's simulation (footnote in §6).
///
/// * Inliers: A uniform in \[0,1\]³, B = A + N(0, σ²) per axis.
/// * Outliers: A uniform in \[0,1\]³, B uniform in A + \[−1,1\]³.
/// * Then the inliers' A are transformed by `t0`: source = T0·A.
///
/// Inliers come first, then outliers. Registration maps source → target, so the ideal answer
/// `T_target_source` is ≈ T0⁻¹ (exactly T0⁻¹ for σ = 0).
///
/// # Panics
/// If `noise_sigma` is negative or not finite.
pub fn paper_simulation(
    inliers: usize,
    outliers: usize,
    noise_sigma: f64,
    t0: &Matrix4<f64>,
    seed: u64,
) -> Correspondences {
    let noise = gaussian(noise_sigma);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let total = inliers + outliers;
    let mut result = Correspondences {
        source: Vec::with_capacity(total),
        target: Vec::with_capacity(total),
        is_inlier: Vec::with_capacity(total),
    };
    for _ in 0..inliers {
        let a: Point = [0; 3].map(|_| rng.random::<f64>());
        let b = a.map(|c| c + noise.sample(&mut rng));
        result.source.push(transform_point(t0, &a));
        result.target.push(b);
        result.is_inlier.push(true);
    }
    for _ in 0..outliers {
        let a: Point = [0; 3].map(|_| rng.random::<f64>());
        let b = a.map(|c| c + rng.random_range(-1.0..1.0));
        result.source.push(a);
        result.target.push(b);
        result.is_inlier.push(false);
    }
    result
}

/// A rigid motion: rotation by `angle` (radians) about a uniformly random axis through the
/// origin, then translation by `shift` in a uniformly random direction.
pub fn random_motion(rng: &mut Xoshiro256PlusPlus, angle: f64, shift: f64) -> Matrix4<f64> {
    let axis = random_direction(rng);
    let direction = random_direction(rng);
    (Translation3::from(direction.into_inner() * shift) * UnitQuaternion::from_axis_angle(&axis, angle))
        .to_homogeneous()
}

/// A uniformly distributed unit vector.
fn random_direction(rng: &mut Xoshiro256PlusPlus) -> Unit<Vector3<f64>> {
    let normal = gaussian(1.0);
    loop {
        let v = Vector3::new(normal.sample(rng), normal.sample(rng), normal.sample(rng));
        if v.norm() > 1e-6 {
            return Unit::new_normalize(v);
        }
    }
}

/// The paper's simulation with a second structure among the outliers: of the `outliers`
/// pairs, the first `structured` follow their own rigid motion `other` exactly like the inliers
/// follow `t0` (A uniform in \[0,1\]³, B = A + N(0, σ²), source = other·A); the rest are the
/// paper's random outliers. Only the `inliers` pairs (first) are marked as inliers: a
/// registration should find them, the larger set, and not the structured outliers.
///
/// # Panics
/// If `structured > outliers`, or `noise_sigma` is negative or not finite.
pub fn structured_simulation(
    inliers: usize,
    outliers: usize,
    structured: usize,
    noise_sigma: f64,
    t0: &Matrix4<f64>,
    other: &Matrix4<f64>,
    seed: u64,
) -> Correspondences {
    assert!(
        structured <= outliers,
        "{structured} structured outliers of {outliers}"
    );
    let mut result = paper_simulation(inliers, outliers, noise_sigma, t0, seed);
    let noise = gaussian(noise_sigma);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x5747_5543_5455_5245);
    for k in inliers..inliers + structured {
        let a: Point = [0; 3].map(|_| rng.random::<f64>());
        result.target[k] = a.map(|c| c + noise.sample(&mut rng));
        result.source[k] = crate::geometry::transform_point(other, &a);
    }
    result
}

/// Two scans of one room for ICP tests, with ground truth.
#[derive(Clone, Debug, PartialEq)]
pub struct RoomScene {
    /// The room seen from the source pose, in the source frame.
    pub source: Vec<Point>,
    /// The room in the world frame, which is the target frame.
    pub target: Vec<Point>,
    /// Ground truth: p_target = T · p_source ([`ROOM_GT_ROTATION_DEGREES`] about
    /// [`ROOM_GT_AXIS`], translation [`ROOM_GT_TRANSLATION`]).
    pub t_target_source: Matrix4<f64>,
}

/// Ground-truth rotation of [`room_scene`]: angle (degrees) …
pub const ROOM_GT_ROTATION_DEGREES: f64 = 7.0;
/// … about this (not normalised) axis, mostly yaw with some tilt so all six degrees of freedom
/// are exercised …
pub const ROOM_GT_AXIS: [f64; 3] = [0.2, -0.3, 0.93];
/// … and translation (metres, |t| ≈ 0.2).
pub const ROOM_GT_TRANSLATION: [f64; 3] = [0.15, -0.1, 0.08];

/// Room interior in the world frame (metres): 6 × 5 × 3 centred on the sensor at the origin,
/// 1.2 m above the floor, so that normals oriented towards the origin face into the room.
pub const ROOM_MIN: [f64; 3] = [-3.0, -2.5, -1.2];
/// Far corner of the room (m); see [`ROOM_MIN`].
pub const ROOM_MAX: [f64; 3] = [3.0, 2.5, 1.8];

/// Width of the slab that only one scan sees: the target lacks x > 3 − w (with the +x wall),
/// the source lacks y > 2.5 − w (with the +y wall). About 18–20 % of each cloud has no
/// counterpart in the other, and both keep the −x and −y walls, floor and ceiling, so every
/// degree of freedom stays observable.
pub const ROOM_CROP_WIDTH: f64 = 0.5;

/// Share of each cloud that is uniform outliers in the room volume.
pub const ROOM_OUTLIER_FRACTION: f64 = 0.03;

/// Two noisy scans of a furnished room: floor, four walls and ceiling of a 6 × 5 × 3 m room
/// plus boxes (table, cabinet, crate), cylinders (bin, pillar) and spheres, sampled uniformly
/// by visible area (floor under furniture excluded).
///
/// Each cloud has `points` points: independent surface samples + N(0, σ²) per axis, plus
/// [`ROOM_OUTLIER_FRACTION`] uniform outliers in the room volume. The target is in the world
/// frame and lacks the +x slab; the source lacks the +y slab (see [`ROOM_CROP_WIDTH`]) and is
/// expressed in the source frame: source points = T⁻¹ · world points, with the fixed ground
/// truth T = `t_target_source`.
///
/// # Panics
/// If `noise_sigma` is negative or not finite.
pub fn room_scene(points: usize, noise_sigma: f64, seed: u64) -> RoomScene {
    let noise = gaussian(noise_sigma);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let room = Room::furnished();
    let ground_truth = room_ground_truth();
    let source_from_world = ground_truth.inverse().to_homogeneous();

    let x_limit = ROOM_MAX[0] - ROOM_CROP_WIDTH;
    let y_limit = ROOM_MAX[1] - ROOM_CROP_WIDTH;
    let target = room.scan(points, &noise, &mut rng, |p| p[0] <= x_limit);
    let source_world = room.scan(points, &noise, &mut rng, |p| p[1] <= y_limit);
    let source = source_world
        .iter()
        .map(|p| transform_point(&source_from_world, p))
        .collect();
    RoomScene {
        source,
        target,
        t_target_source: ground_truth.to_homogeneous(),
    }
}

/// A scanner moving through the furnished room of [`room_scene`]: its frames and true poses.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    /// Frame i: what the scanner saw, in its own (sensor) frame.
    pub frames: Vec<Vec<Point>>,
    /// T_world_sensor of frame i: p_world = `poses[i]` · p_sensor.
    pub poses: Vec<Matrix4<f64>>,
}

/// Height of the scanner's path above the floor (m): above the table, the crate and the balls.
const TRAJECTORY_HEIGHT: f64 = 1.5;

/// `frames` scans of the furnished room by a scanner that goes once around an ellipse (1.6 m by
/// 1.1 m about the room's centre, 1.5 m above the floor, bobbing by ±10 cm) looking along its
/// path with a little yaw, pitch and roll wobble: at 100 frames about 8.5 cm and 3.6° per
/// frame, a 10 Hz scanner carried at walking speed.
///
/// Each frame casts `points` rays in directions uniform on the sphere (fresh per frame) and
/// keeps the first surface each ray hits, so the scanner sees what its position lets it see:
/// furniture occludes the floor and the walls behind it, and the density falls with range as
/// for a real scanner. Range noise N(0, `range_noise`²) along each ray.
///
/// # Panics
/// If `range_noise` is negative or not finite.
pub fn room_trajectory(frames: usize, points: usize, range_noise: f64, seed: u64) -> Trajectory {
    let noise = gaussian(range_noise);
    let room = Room::furnished();
    let mut result = Trajectory {
        frames: Vec::with_capacity(frames),
        poses: Vec::with_capacity(frames),
    };
    for i in 0..frames {
        let pose = pose_on_loop(i, frames);
        let (position, orientation) = (pose.translation.vector, pose.rotation);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ splitmix(i as u64));
        let mut frame = Vec::with_capacity(points);
        while frame.len() < points {
            // Uniform on the sphere (Archimedes), in the sensor frame.
            let (z, azimuth) = (rng.random_range(-1.0..1.0f64), rng.random_range(0.0..TAU));
            let ring = (1.0 - z * z).sqrt();
            let direction = Vector3::new(ring * azimuth.cos(), ring * azimuth.sin(), z);
            let Some(range) = room.first_hit(&position, &(orientation * direction)) else {
                continue;
            };
            let measured = direction * (range + noise.sample(&mut rng));
            frame.push([measured.x, measured.y, measured.z]);
        }
        result.frames.push(frame);
        result.poses.push(pose.to_homogeneous());
    }
    result
}

/// Frame `i` of `frames` on [`room_trajectory`]'s loop: T_world_sensor, the sensor looking
/// along its x axis (z up).
fn pose_on_loop(i: usize, frames: usize) -> Isometry3<f64> {
    let angle = TAU * i as f64 / frames.max(1) as f64;
    let position = Vector3::new(
        1.6 * angle.cos(),
        1.1 * angle.sin(),
        ROOM_MIN[2] + TRAJECTORY_HEIGHT + 0.1 * (3.0 * angle).sin(),
    );
    // Heading along the ellipse's tangent (−1.6 sin, 1.1 cos).
    let heading = (1.1 * angle.cos()).atan2(-1.6 * angle.sin()) + 0.2 * (2.0 * angle).sin();
    let orientation =
        UnitQuaternion::from_euler_angles(0.05 * (4.0 * angle).cos(), 0.05 * (5.0 * angle).sin(), heading);
    Isometry3::from_parts(Translation3::from(position), orientation)
}

/// A depth camera's picture: pixels, field of view, working range and noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthCamera {
    /// Pixels across.
    pub width: usize,
    /// Pixels down.
    pub height: usize,
    /// Horizontal field of view (radians); the vertical one follows from square pixels.
    pub horizontal_fov: f64,
    /// Depths outside this range (m) are invalid pixels, left out of the frame.
    pub min_depth: f64,
    /// See `min_depth`.
    pub max_depth: f64,
    /// Standard deviation of the measured depth at 1 m (m): at depth z it is this times z²
    /// (structured light, the paper's §6 PrimeSense model).
    pub depth_noise_at_one_metre: f64,
}

impl DepthCamera {
    /// A Kinect-like camera at a quarter of its 640 × 480 resolution: 58.5° across, depths
    /// 0.5–4.5 m, 2 mm of depth noise at 1 m (8 mm at 2 m, 32 mm at 4 m).
    pub fn kinect_like() -> Self {
        DepthCamera {
            width: 160,
            height: 120,
            horizontal_fov: 58.5f64.to_radians(),
            min_depth: 0.5,
            max_depth: 4.5,
            depth_noise_at_one_metre: 0.002,
        }
    }
}

/// How far [`depth_camera_trajectory`]'s camera turns left of its path (radians).
const CAMERA_YAW_INWARDS: f64 = 1.2;
/// How far it looks down (radians).
const CAMERA_PITCH_DOWN: f64 = 0.6;

/// `frames` depth images of the furnished room taken by `camera` carried around
/// [`room_trajectory`]'s loop, looking into the room (69° left of the path) and down (34°).
/// Each frame holds the valid pixels' points in the camera's own frame (x right, y down, z
/// along the optical axis, so z is the depth as `NoiseModel::QuadraticDepth` reads it), in
/// pixel order; its pose is T_world_camera.
/// The depth of each pixel is the true one plus N(0, (`depth_noise_at_one_metre`·z²)²) (a pixel
/// whose true depth lies outside the working range is invalid whatever its noise).
///
/// # Panics
/// If the camera's noise is negative or not finite.
pub fn depth_camera_trajectory(frames: usize, camera: &DepthCamera, seed: u64) -> Trajectory {
    let noise_at_one_metre = gaussian(camera.depth_noise_at_one_metre);
    let room = Room::furnished();
    // Camera axes (x right, y down, z forward) in the sensor frame (x forward, y left, z up),
    // then turned towards the room's middle (left of the path) and down onto the floor and the
    // furniture: looking along the path at this height, the view holds a single wall.
    let sensor_from_camera = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), CAMERA_YAW_INWARDS)
        * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), CAMERA_PITCH_DOWN)
        * UnitQuaternion::from_matrix(&nalgebra::Matrix3::new(
            0.0, 0.0, 1.0, //
            -1.0, 0.0, 0.0, //
            0.0, -1.0, 0.0,
        ));
    let focal = (camera.width as f64 / 2.0) / (camera.horizontal_fov / 2.0).tan();
    let (cx, cy) = (camera.width as f64 / 2.0, camera.height as f64 / 2.0);
    let mut result = Trajectory {
        frames: Vec::with_capacity(frames),
        poses: Vec::with_capacity(frames),
    };
    for i in 0..frames {
        let sensor = pose_on_loop(i, frames);
        let pose = Isometry3::from_parts(sensor.translation, sensor.rotation * sensor_from_camera);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ splitmix(i as u64));
        let mut frame = Vec::with_capacity(camera.width * camera.height);
        for v in 0..camera.height {
            for u in 0..camera.width {
                // The ray through the pixel's centre, scaled to unit depth.
                let ray = Vector3::new((u as f64 + 0.5 - cx) / focal, (v as f64 + 0.5 - cy) / focal, 1.0);
                let noise = noise_at_one_metre.sample(&mut rng);
                let Some(range) =
                    room.first_hit(&pose.translation.vector, &(pose.rotation * ray.normalize()))
                else {
                    continue;
                };
                let depth = range / ray.norm();
                if !(camera.min_depth..=camera.max_depth).contains(&depth) {
                    continue;
                }
                let measured = ray * (depth + depth * depth * noise);
                frame.push([measured.x, measured.y, measured.z]);
            }
        }
        result.frames.push(frame);
        result.poses.push(pose.to_homogeneous());
    }
    result
}

/// A 64-bit mix of a frame index into the seed (frames get unrelated random streams).
fn splitmix(x: u64) -> u64 {
    crate::geometry::splitmix64(x.wrapping_add(0x9E37_79B9_7F4A_7C15))
}

/// The fixed ground truth of [`room_scene`].
fn room_ground_truth() -> Isometry3<f64> {
    let axis = Unit::new_normalize(Vector3::from(ROOM_GT_AXIS));
    let rotation = UnitQuaternion::from_axis_angle(&axis, ROOM_GT_ROTATION_DEGREES.to_radians());
    Isometry3::from_parts(Translation3::from(Vector3::from(ROOM_GT_TRANSLATION)), rotation)
}

fn gaussian(sigma: f64) -> Normal<f64> {
    assert!(
        sigma.is_finite() && sigma >= 0.0,
        "noise sigma must be finite and >= 0, got {sigma}"
    );
    Normal::new(0.0, sigma).unwrap_or_else(|_| unreachable!("checked above"))
}

fn transform_point(t: &Matrix4<f64>, p: &Point) -> Point {
    let q = t.transform_point(&Point3::from(*p));
    [q.x, q.y, q.z]
}

/// A surface piece that can be sampled uniformly by area.
enum Patch {
    /// origin + s·u + t·v for s, t ∈ [0, 1].
    Parallelogram {
        origin: Vector3<f64>,
        u: Vector3<f64>,
        v: Vector3<f64>,
    },
    /// Lateral surface of a vertical cylinder standing on `base` (centre of the bottom).
    CylinderSide {
        base: Vector3<f64>,
        radius: f64,
        height: f64,
    },
    /// Horizontal disc (a cylinder's top).
    Disc {
        centre: Vector3<f64>,
        radius: f64,
    },
    Sphere {
        centre: Vector3<f64>,
        radius: f64,
    },
}

impl Patch {
    fn area(&self) -> f64 {
        match self {
            Patch::Parallelogram { u, v, .. } => u.cross(v).norm(),
            Patch::CylinderSide { radius, height, .. } => TAU * radius * height,
            Patch::Disc { radius, .. } => 0.5 * TAU * radius * radius,
            Patch::Sphere { radius, .. } => 2.0 * TAU * radius * radius,
        }
    }

    /// Distance along the unit ray `origin + t·direction` to this surface (t > 1 mm), if hit.
    fn hit(&self, origin: &Vector3<f64>, direction: &Vector3<f64>) -> Option<f64> {
        const NEAR: f64 = 1e-3;
        // Smallest root above NEAR of a t² + b t + c = 0 that `keep` accepts.
        let quadratic = |a: f64, b: f64, c: f64, keep: &dyn Fn(f64) -> bool| -> Option<f64> {
            let discriminant = b * b - 4.0 * a * c;
            if a <= 0.0 || discriminant < 0.0 {
                return None;
            }
            let root = discriminant.sqrt();
            [(-b - root) / (2.0 * a), (-b + root) / (2.0 * a)]
                .into_iter()
                .find(|&t| t > NEAR && keep(t))
        };
        match self {
            Patch::Parallelogram { origin: corner, u, v } => {
                let normal = u.cross(v);
                let facing = direction.dot(&normal);
                if facing == 0.0 {
                    return None;
                }
                let t = (corner - origin).dot(&normal) / facing;
                let w = origin + direction * t - corner;
                let squared = normal.norm_squared();
                let (a, b) = (
                    w.cross(v).dot(&normal) / squared,
                    u.cross(&w).dot(&normal) / squared,
                );
                (t > NEAR && (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)).then_some(t)
            }
            Patch::CylinderSide { base, radius, height } => {
                let (dx, dy) = (origin.x - base.x, origin.y - base.y);
                let a = direction.x * direction.x + direction.y * direction.y;
                let b = 2.0 * (dx * direction.x + dy * direction.y);
                let c = dx * dx + dy * dy - radius * radius;
                let within = |t: f64| (0.0..=*height).contains(&(origin.z + t * direction.z - base.z));
                quadratic(a, b, c, &within)
            }
            Patch::Disc { centre, radius } => {
                if direction.z == 0.0 {
                    return None;
                }
                let t = (centre.z - origin.z) / direction.z;
                let p = origin + direction * t;
                (t > NEAR && (p.x - centre.x).powi(2) + (p.y - centre.y).powi(2) <= radius * radius)
                    .then_some(t)
            }
            Patch::Sphere { centre, radius } => {
                let d = origin - centre;
                quadratic(
                    1.0,
                    2.0 * d.dot(direction),
                    d.norm_squared() - radius * radius,
                    &|_| true,
                )
            }
        }
    }

    fn sample(&self, rng: &mut Xoshiro256PlusPlus) -> Vector3<f64> {
        match self {
            Patch::Parallelogram { origin, u, v } => {
                origin + u * rng.random::<f64>() + v * rng.random::<f64>()
            }
            Patch::CylinderSide { base, radius, height } => {
                let angle = rng.random_range(0.0..TAU);
                base + Vector3::new(
                    radius * angle.cos(),
                    radius * angle.sin(),
                    height * rng.random::<f64>(),
                )
            }
            Patch::Disc { centre, radius } => {
                // √u radius makes the density uniform over the disc.
                let (r, angle) = (radius * rng.random::<f64>().sqrt(), rng.random_range(0.0..TAU));
                centre + Vector3::new(r * angle.cos(), r * angle.sin(), 0.0)
            }
            Patch::Sphere { centre, radius } => {
                // Archimedes: z uniform in [−1, 1] gives a uniform point on the sphere.
                let (z, angle) = (rng.random_range(-1.0..1.0f64), rng.random_range(0.0..TAU));
                let ring = (1.0 - z * z).sqrt();
                centre + Vector3::new(ring * angle.cos(), ring * angle.sin(), z) * *radius
            }
        }
    }
}

/// Floor area hidden under furniture (no samples there).
enum Footprint {
    Rectangle { min: [f64; 2], max: [f64; 2] },
    Circle { centre: [f64; 2], radius: f64 },
}

impl Footprint {
    fn covers(&self, p: &Vector3<f64>) -> bool {
        match self {
            Footprint::Rectangle { min, max } => {
                (min[0]..=max[0]).contains(&p.x) && (min[1]..=max[1]).contains(&p.y)
            }
            Footprint::Circle { centre, radius } => {
                (p.x - centre[0]).powi(2) + (p.y - centre[1]).powi(2) <= radius * radius
            }
        }
    }
}

struct Room {
    patches: Vec<Patch>,
    /// Running sum of the patch areas, for picking a patch by area.
    cumulative_area: Vec<f64>,
    floor_index: usize,
    footprints: Vec<Footprint>,
}

impl Room {
    fn furnished() -> Room {
        let [x0, y0, floor] = ROOM_MIN;
        let [x1, y1, ceiling] = ROOM_MAX;
        let v = Vector3::new;
        let (dx, dy, dz) = (x1 - x0, y1 - y0, ceiling - floor);
        let mut patches = vec![
            Patch::Parallelogram {
                origin: v(x0, y0, floor),
                u: v(dx, 0.0, 0.0),
                v: v(0.0, dy, 0.0),
            },
            Patch::Parallelogram {
                origin: v(x0, y0, ceiling),
                u: v(dx, 0.0, 0.0),
                v: v(0.0, dy, 0.0),
            },
            Patch::Parallelogram {
                origin: v(x0, y0, floor),
                u: v(dx, 0.0, 0.0),
                v: v(0.0, 0.0, dz),
            },
            Patch::Parallelogram {
                origin: v(x0, y1, floor),
                u: v(dx, 0.0, 0.0),
                v: v(0.0, 0.0, dz),
            },
            Patch::Parallelogram {
                origin: v(x0, y0, floor),
                u: v(0.0, dy, 0.0),
                v: v(0.0, 0.0, dz),
            },
            Patch::Parallelogram {
                origin: v(x1, y0, floor),
                u: v(0.0, dy, 0.0),
                v: v(0.0, 0.0, dz),
            },
        ];
        let floor_index = 0;
        let mut footprints = Vec::new();
        // Boxes standing on the floor: (min corner x, y), (size x, y), height.
        let boxes = [
            ([0.4, 0.4], [1.2, 0.8], 0.75),    // table
            ([-2.0, 1.95], [0.6, 0.5], 1.8),   // cabinet, 5 cm off the +y wall
            ([-1.25, -1.4], [0.5, 0.4], 0.45), // crate
        ];
        for (min, size, height) in boxes {
            let origin = v(min[0], min[1], floor);
            let (sx, sy, sz) = (v(size[0], 0.0, 0.0), v(0.0, size[1], 0.0), v(0.0, 0.0, height));
            patches.extend([
                Patch::Parallelogram {
                    origin: origin + sz,
                    u: sx,
                    v: sy,
                },
                Patch::Parallelogram { origin, u: sx, v: sz },
                Patch::Parallelogram {
                    origin: origin + sy,
                    u: sx,
                    v: sz,
                },
                Patch::Parallelogram { origin, u: sy, v: sz },
                Patch::Parallelogram {
                    origin: origin + sx,
                    u: sy,
                    v: sz,
                },
            ]);
            footprints.push(Footprint::Rectangle {
                min,
                max: [min[0] + size[0], min[1] + size[1]],
            });
        }
        // Bin (closed top) and a floor-to-ceiling pillar.
        for (centre, radius, height) in [([2.0, -1.5], 0.25, 0.9), ([-2.2, -1.8], 0.15, dz)] {
            let base = v(centre[0], centre[1], floor);
            patches.push(Patch::CylinderSide { base, radius, height });
            if height < dz {
                patches.push(Patch::Disc {
                    centre: base + v(0.0, 0.0, height),
                    radius,
                });
            }
            footprints.push(Footprint::Circle { centre, radius });
        }
        // A ball on the floor and one on the table.
        patches.push(Patch::Sphere {
            centre: v(0.0, -0.5, floor + 0.35),
            radius: 0.35,
        });
        patches.push(Patch::Sphere {
            centre: v(1.2, 0.9, floor + 0.75 + 0.15),
            radius: 0.15,
        });

        let cumulative_area = patches
            .iter()
            .scan(0.0, |sum, patch| {
                *sum += patch.area();
                Some(*sum)
            })
            .collect();
        Room {
            patches,
            cumulative_area,
            floor_index,
            footprints,
        }
    }

    /// Distance to the first surface the unit ray from `origin` along `direction` hits.
    fn first_hit(&self, origin: &Vector3<f64>, direction: &Vector3<f64>) -> Option<f64> {
        self.patches
            .iter()
            .filter_map(|patch| patch.hit(origin, direction))
            .min_by(f64::total_cmp)
    }

    /// A visible surface point, uniform by area.
    fn sample_surface(&self, rng: &mut Xoshiro256PlusPlus) -> Vector3<f64> {
        let total = self.cumulative_area.last().copied().unwrap_or(0.0);
        loop {
            let pick = rng.random::<f64>() * total;
            let index = self
                .cumulative_area
                .partition_point(|&a| a <= pick)
                .min(self.patches.len() - 1);
            let p = self.patches[index].sample(rng);
            if index != self.floor_index || !self.footprints.iter().any(|f| f.covers(&p)) {
                return p;
            }
        }
    }

    /// `count` world points where `visible` holds: noisy surface samples plus outliers.
    fn scan(
        &self,
        count: usize,
        noise: &Normal<f64>,
        rng: &mut Xoshiro256PlusPlus,
        visible: impl Fn(&Point) -> bool,
    ) -> Vec<Point> {
        let outliers = (count as f64 * ROOM_OUTLIER_FRACTION).round() as usize;
        let mut cloud = Vec::with_capacity(count);
        while cloud.len() < count - outliers.min(count) {
            let p = self.sample_surface(rng);
            let p: Point = [p.x, p.y, p.z];
            if visible(&p) {
                cloud.push(p.map(|c| c + noise.sample(rng)));
            }
        }
        while cloud.len() < count {
            let p: Point = [0, 1, 2].map(|d| rng.random_range(ROOM_MIN[d]..ROOM_MAX[d]));
            if visible(&p) {
                cloud.push(p);
            }
        }
        cloud
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::NearestNeighbours;
    use crate::normals::estimate_normals;
    use crate::parallel::Workers;

    fn t0() -> Matrix4<f64> {
        let rotation = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.5);
        (Translation3::new(0.5, -0.3, 0.2) * rotation).to_homogeneous()
    }

    #[test]
    fn paper_simulation_follows_the_footnote() {
        let (inliers, outliers, sigma) = (20_000, 5_000, 0.01);
        let t0 = t0();
        let sim = paper_simulation(inliers, outliers, sigma, &t0, 42);
        assert_eq!(sim.source.len(), inliers + outliers);
        assert_eq!(sim.target.len(), inliers + outliers);
        assert!(sim.is_inlier[..inliers].iter().all(|&b| b));
        assert!(sim.is_inlier[inliers..].iter().all(|&b| !b));

        // T0⁻¹ undoes the source transform; the inlier residuals are then the noise.
        let inverse = t0.try_inverse().unwrap();
        let mut residuals = Vec::with_capacity(3 * inliers);
        for (source, target) in sim.source[..inliers].iter().zip(&sim.target) {
            let a = transform_point(&inverse, source);
            assert!(
                a.iter().all(|c| (-1e-12..=1.0 + 1e-12).contains(c)),
                "A outside [0,1]³: {a:?}"
            );
            residuals.extend((0..3).map(|d| target[d] - a[d]));
        }
        let n = residuals.len() as f64;
        let mean = residuals.iter().sum::<f64>() / n;
        let std = (residuals.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!(mean.abs() < 4.0 * sigma / n.sqrt(), "mean {mean}");
        assert!((std / sigma - 1.0).abs() < 0.02, "std {std}");

        for i in inliers..inliers + outliers {
            let (a, b) = (sim.source[i], sim.target[i]);
            assert!(a.iter().all(|c| (0.0..=1.0).contains(c)), "outlier A {a:?}");
            assert!(
                (0..3).all(|d| (b[d] - a[d]).abs() <= 1.0),
                "outlier B {b:?} for A {a:?}"
            );
        }
        // Outlier offsets really are spread over [−1, 1]: mean |b − a| ≈ 0.5 per axis.
        let spread: f64 = (inliers..inliers + outliers)
            .map(|i| (sim.target[i][0] - sim.source[i][0]).abs())
            .sum::<f64>()
            / outliers as f64;
        assert!((spread - 0.5).abs() < 0.02, "{spread}");
    }

    #[test]
    fn a_moving_scanner_sees_the_room_from_inside_with_occlusions() {
        let trajectory = room_trajectory(20, 3_000, 0.0, 5);
        assert_eq!(trajectory, room_trajectory(20, 3_000, 0.0, 5));
        assert_eq!((trajectory.frames.len(), trajectory.poses.len()), (20, 20));
        let mut under_table = 0;
        for (frame, pose) in trajectory.frames.iter().zip(&trajectory.poses) {
            assert_eq!(frame.len(), 3_000);
            for p in frame {
                let w = transform_point(pose, p);
                // Exact hits lie on the room's closed surfaces: inside its box, never inside furniture.
                assert!(
                    (0..3).all(|d| w[d] > ROOM_MIN[d] - 1e-9 && w[d] < ROOM_MAX[d] + 1e-9),
                    "{w:?}"
                );
                let in_table = w[0] > 0.41 && w[0] < 1.59 && w[1] > 0.41 && w[1] < 1.19 && w[2] < -0.46;
                assert!(!in_table, "a point inside the table: {w:?}");
                // The floor under the table is hidden by its top and sides.
                under_table += usize::from(w[2] < ROOM_MIN[2] + 1e-6 && in_table);
            }
        }
        assert_eq!(under_table, 0);
        // Consecutive poses: a few centimetres and degrees apart.
        for pair in trajectory.poses.windows(2) {
            let relative = pair[0].try_inverse().unwrap() * pair[1];
            let step = relative.fixed_view::<3, 1>(0, 3).norm();
            assert!(step > 0.2 && step < 0.6, "{step}");
        }
    }

    /// The camera's points lie in its field of view and working range, on the room's surfaces
    /// seen from the camera's pose; the same seed without noise gives the same pixels, and the
    /// depth differences grow as depth²: their RMS over depth², binned by depth, is the noise
    /// at 1 m in every bin.
    #[test]
    fn a_depth_camera_sees_the_room_with_noise_growing_as_depth_squared() {
        let camera = DepthCamera::kinect_like();
        let noisy = depth_camera_trajectory(6, &camera, 11);
        let exact = depth_camera_trajectory(
            6,
            &DepthCamera {
                depth_noise_at_one_metre: 0.0,
                ..camera
            },
            11,
        );
        assert_eq!(noisy, depth_camera_trajectory(6, &camera, 11));
        let half_fov = (camera.horizontal_fov / 2.0).tan() + 1e-9;
        // Squared depth errors over z⁴, in bins of 1 m of true depth: [sum, count].
        let mut bins = [[0.0f64; 2]; 5];
        for ((frame, truth), pose) in noisy.frames.iter().zip(&exact.frames).zip(&exact.poses) {
            assert_eq!(frame.len(), truth.len());
            assert!(frame.len() > camera.width * camera.height / 2, "{}", frame.len());
            for (p, q) in frame.iter().zip(truth) {
                let z = q[2];
                assert!((camera.min_depth..=camera.max_depth).contains(&z), "{z}");
                assert!(q[0].abs() <= half_fov * z, "{q:?} outside the field of view");
                let w = transform_point(pose, q);
                assert!(
                    (0..3).all(|d| w[d] > ROOM_MIN[d] - 1e-9 && w[d] < ROOM_MAX[d] + 1e-9),
                    "{w:?}"
                );
                // Noise only along the pixel's ray.
                let along = p[2] / z;
                assert!((0..2).all(|d| (p[d] - along * q[d]).abs() < 1e-12), "{p:?} {q:?}");
                let bin = &mut bins[z.floor() as usize];
                bin[0] += ((p[2] - z) / (z * z)).powi(2);
                bin[1] += 1.0;
            }
        }
        let filled: Vec<f64> = bins
            .iter()
            .filter(|[_, n]| *n > 500.0)
            .map(|[sum, n]| (sum / n).sqrt())
            .collect();
        assert!(filled.len() >= 3, "{bins:?}");
        for at_one_metre in filled {
            assert!(
                (at_one_metre / camera.depth_noise_at_one_metre - 1.0).abs() < 0.1,
                "{at_one_metre} against {}",
                camera.depth_noise_at_one_metre
            );
        }
        // A loop of 6 frames: consecutive optical axes less than a quarter turn apart.
        for pair in noisy.poses.windows(2) {
            let relative = pair[0].try_inverse().unwrap() * pair[1];
            let axis_turn = relative[(2, 2)].clamp(-1.0, 1.0).acos().to_degrees();
            assert!(axis_turn < 90.0, "{axis_turn}");
        }
    }

    #[test]
    fn scenes_are_deterministic_per_seed() {
        let t0 = t0();
        assert_eq!(
            paper_simulation(50, 10, 0.1, &t0, 7),
            paper_simulation(50, 10, 0.1, &t0, 7)
        );
        assert_ne!(
            paper_simulation(50, 10, 0.1, &t0, 7),
            paper_simulation(50, 10, 0.1, &t0, 8)
        );
        assert_eq!(room_scene(500, 0.01, 3), room_scene(500, 0.01, 3));
        assert_ne!(room_scene(500, 0.01, 3).source, room_scene(500, 0.01, 4).source);
        // σ = 0 is exact: source maps onto the inliers' targets by T0⁻¹.
        let exact = paper_simulation(10, 0, 0.0, &t0, 1);
        let inverse = t0.try_inverse().unwrap();
        for (s, t) in exact.source.iter().zip(&exact.target) {
            let back = transform_point(&inverse, s);
            assert!((0..3).all(|d| (back[d] - t[d]).abs() < 1e-12));
        }
    }

    #[test]
    fn room_ground_truth_is_the_documented_rigid_motion() {
        let scene = room_scene(100, 0.0, 1);
        let t = scene.t_target_source;
        let r = t.fixed_view::<3, 3>(0, 0).into_owned();
        assert!((r.transpose() * r - nalgebra::Matrix3::identity()).abs().max() < 1e-12);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        let angle = ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
        assert!((angle - 7.0).abs() < 1e-9, "{angle}");
        let translation = t.fixed_view::<3, 1>(0, 3).norm();
        assert!((translation - 0.2).abs() < 0.01, "{translation}");
        assert_eq!(t.row(3), nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0));
    }

    /// Distance from each query point to the target surface: the plane through the centroid
    /// of its 10 nearest target points, with the PCA normal at the nearest one.
    fn distances_to_surface(target: &[Point], queries: &[Point]) -> Vec<f64> {
        let index = NearestNeighbours::new(target).unwrap();
        let normals = estimate_normals(target, &index, 10, &Workers::new(1).unwrap());
        let mut neighbours = Vec::new();
        queries
            .iter()
            .map(|q| {
                index.nearest_k(q, 10, &mut neighbours);
                let centroid = neighbours.iter().fold([0.0; 3], |c, &i| {
                    [0, 1, 2].map(|d| c[d] + target[i][d] / neighbours.len() as f64)
                });
                let n = normals[neighbours[0]];
                (0..3).map(|d| n[d] * (q[d] - centroid[d])).sum::<f64>().abs()
            })
            .collect()
    }

    #[test]
    fn room_scans_overlap_under_the_ground_truth() {
        let (points, sigma) = (30_000, 0.005);
        let scene = room_scene(points, sigma, 9);
        assert_eq!((scene.source.len(), scene.target.len()), (points, points));
        let x_limit = ROOM_MAX[0] - ROOM_CROP_WIDTH;
        let y_limit = ROOM_MAX[1] - ROOM_CROP_WIDTH;

        let in_world: Vec<Point> = scene
            .source
            .iter()
            .map(|p| transform_point(&scene.t_target_source, p))
            .collect();
        let only_in_source = in_world.iter().filter(|p| p[0] > x_limit).count() as f64 / points as f64;
        let only_in_target = scene.target.iter().filter(|p| p[1] > y_limit).count() as f64 / points as f64;
        for share in [only_in_source, only_in_target] {
            assert!((0.15..0.25).contains(&share), "non-overlapping share {share}");
        }
        let inside_room = in_world
            .iter()
            .filter(|p| (0..3).all(|d| p[d] > ROOM_MIN[d] - 5.0 * sigma && p[d] < ROOM_MAX[d] + 5.0 * sigma))
            .count();
        assert_eq!(inside_room, points, "GT does not map the source into the room");

        let overlap: Vec<Point> = in_world
            .iter()
            .filter(|p| p[0] < x_limit - 0.1 && p[1] < y_limit - 0.1)
            .copied()
            .collect();
        let close = |queries: &[Point]| {
            let d = distances_to_surface(&scene.target, queries);
            d.iter().filter(|&&d| d < 3.0 * sigma).count() as f64 / d.len() as f64
        };
        // Surface points (97 %) are within 3σ of the target surface, bar edges and corners.
        let aligned = close(&overlap);
        assert!(aligned > 0.85, "only {aligned} of the overlap within 3σ");
        // Without the ground truth they are not.
        let unaligned: Vec<Point> = scene
            .source
            .iter()
            .filter(|p| p[0] < x_limit - 0.5 && p[1] < y_limit - 0.5)
            .copied()
            .collect();
        let misaligned = close(&unaligned);
        assert!(misaligned < 0.3, "{misaligned} within 3σ at identity");
    }

    #[test]
    fn room_surface_sampling_is_uniform_by_area() {
        // Floor (30 m² minus ~1.9 m² of footprints) against the ceiling (30 m²).
        let room = Room::furnished();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let samples: Vec<Vector3<f64>> = (0..200_000).map(|_| room.sample_surface(&mut rng)).collect();
        let on = |z: f64| samples.iter().filter(|p| (p.z - z).abs() < 1e-12).count() as f64;
        let (floor, ceiling) = (on(ROOM_MIN[2]), on(ROOM_MAX[2]));
        let hidden = 0.96 + 0.3 + 0.2 + std::f64::consts::PI * (0.25f64.powi(2) + 0.15f64.powi(2));
        let expected = (30.0 - hidden) / 30.0;
        assert!(
            (floor / ceiling - expected).abs() < 0.02,
            "floor/ceiling {}",
            floor / ceiling
        );
        assert!(
            samples
                .iter()
                .all(|p| (0..3).all(|d| p[d] >= ROOM_MIN[d] - 1e-12 && p[d] <= ROOM_MAX[d] + 1e-12))
        );
    }
}
