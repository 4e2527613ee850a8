//! Odometry: a sensor's frames registered one after another, each onto the last frame whose
//! registration was GOOD, from a constant-velocity guess.
//!
//! A bad frame (no usable point, input a registration refuses, the same frame sent again, a
//! result not called GOOD) gets its own status and changes nothing: the next frame registers
//! onto the last accepted one, from the last accepted pose, as if the bad frame had not come.
//! The one DOUBTFUL result that is taken is a loose one (`FrameStatus::Loose`): every check of
//! GOOD passed but the conditioning. Such a view stays loose in the next frames (a depth
//! camera whose yaw rests on far, noisy walls), and setting them aside would register each
//! next frame further from its keyframe until none registers.
//!
//! A frame of more than twice `thinning::THINNED_POINTS` valid points (a LiDAR sweep) is
//! registered on about that many of them, one per voxel of a size chosen from the frame; its
//! target is still the whole last accepted frame, and its result names every frame point, each
//! with the probability and match of the point kept in its voxel.

use std::hash::{DefaultHasher, Hash, Hasher};

use nalgebra::Matrix4;

use crate::error::Error;
use crate::geometry::{is_finite, length, orthonormalised, rotation_angle, rotation_part, translation_part};
use crate::median::median;
use crate::point::{NonFinite, Point};
use crate::registration::clouds::register_clouds_to;
use crate::registration::config::RegistrationConfig;
use crate::registration::hooks::Hooks;
use crate::registration::result::{Quality, RegistrationResult, Verdict};
use crate::registration::target::{PrepareOptions, PreparedTarget};
use crate::registration::thinning::ThinnedFrame;
use crate::registration::verdict::{MIN_CONDITIONING, verdict_with};

/// What became of one frame given to [`Odometry::register_frame`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameStatus {
    /// The first usable frame: it fixes the world frame (its pose is the odometry's start).
    First,
    /// Registered onto the last accepted frame with a GOOD verdict; its pose is the new one.
    Accepted,
    /// Bit for bit the last accepted frame again (a driver that sent it twice): ignored.
    Repeated,
    /// Refused as input (`FrameOutcome::error` says why: no point left after dropping
    /// invalid ones, a non-finite coordinate the config rejects, a frame in other units than
    /// the last accepted one, memory): ignored.
    InputRejected,
    /// Registered, but the verdict is not GOOD (`FrameOutcome::result` has it) and the frame
    /// is not `Loose`: the pose is not trusted and the frame is ignored (a jump, a frame from
    /// elsewhere, a close call between two poses, a run that did not settle).
    NotGood,
    /// Registered GOOD (or `Loose`), but, once a motion has been measured, further from the
    /// constant-velocity guess than the frame's points are from its sensor (median range):
    /// tracking cannot explain such a jump (a frame from elsewhere, a clock or driver fault),
    /// so it is ignored.
    Jumped,
    /// Registered DOUBTFUL for its conditioning alone (below [`MIN_CONDITIONING`]; every other
    /// check of GOOD passed: an inlier peak, a settled run, σ within the target's spacing; the
    /// scaled-source fit is tried on GOOD results only, so not on these), no
    /// start of its search ended elsewhere (`Quality::margin` infinite), a motion already
    /// measured and the result within tracking's reach as `Jumped` measures it: the data fix
    /// some direction of the pose weakly (`Quality::loose_direction` names it when the
    /// surfaces do). Accepted as `Accepted` is (the pose is the best the frame gives; the next
    /// frames see the same view), and said apart so the caller can weigh it. A loose result
    /// with a rival anywhere, or before tracking has a motion to check it against, is
    /// `NotGood`: on a depth camera's loop at 12° to 30° a frame, such results ended 0.85–3.6
    /// m and 41–88° off.
    Loose,
}

/// One frame's status, its pose when it has one, and the registration behind it.
#[derive(Clone, Debug)]
pub struct FrameOutcome {
    /// What became of the frame.
    pub status: FrameStatus,
    /// T_world_sensor of this frame: for `First`, `Accepted` and `Loose` only.
    pub pose: Option<Matrix4<f64>>,
    /// T_world_sensor the constant-velocity model predicts for this frame (the last accepted
    /// pose moved by the last accepted motion once per frame since): where the registration
    /// started, and the frame's best estimate when it was set aside; for a repeat, the last
    /// accepted pose. `None` for the first frame and frames refused before it.
    pub predicted_pose: Option<Matrix4<f64>>,
    /// The frame's registration onto the last accepted frame (`Accepted`, `Loose`, `NotGood`
    /// and `Jumped`). Its `probabilities` and `correspondences` have one entry per frame point,
    /// also when the frame was registered thinned (a point left out takes those of the point
    /// kept in its voxel; a skipped point 0 and -1); `inlier_fraction` and the trace count the
    /// points registered.
    pub result: Option<RegistrationResult>,
    /// Why an `InputRejected` frame was refused.
    pub error: Option<Error>,
}

/// The last accepted frame, prepared as the next frame's target.
struct Keyframe {
    target: PreparedTarget,
    fingerprint: u64,
    /// Median distance of its points from its sensor.
    median_range: f64,
}

impl Keyframe {
    fn new(frame: &[Point], fingerprint: u64, options: &PrepareOptions) -> Result<Self, Error> {
        let target = PreparedTarget::new(frame, None, options)?;
        let mut ranges: Vec<f64> = frame
            .iter()
            .filter(|p| p.iter().all(|c| c.is_finite()) && **p != [0.0; 3])
            .map(length)
            .collect();
        Ok(Keyframe {
            target,
            fingerprint,
            median_range: median(&mut ranges).unwrap_or(0.0),
        })
    }

    /// How far `transform` moves this frame's points from where `guess` puts them, at the
    /// median range: the sensor's shift plus the turn's arc.
    fn displacement(&self, transform: &Matrix4<f64>, guess: &Matrix4<f64>) -> f64 {
        let change = guess.try_inverse().unwrap_or_else(Matrix4::identity) * transform;
        translation_part(&change).norm() + rotation_angle(&rotation_part(&change)) * self.median_range
    }
}

/// Frame-to-frame odometry with SIE: no threshold, and a frame whose registration is not GOOD
/// never moves the trajectory.
///
/// Each frame registers onto the last accepted frame from a constant-velocity guess (the last
/// accepted motion, once per frame since; no motion before one is measured). Poses are
/// T_world_sensor with the first usable frame's sensor as the world.
pub struct Odometry {
    config: RegistrationConfig,
    options: PrepareOptions,
    keyframe: Option<Keyframe>,
    /// T_world_sensor of the last accepted frame.
    pose: Matrix4<f64>,
    /// The last accepted frame-to-frame motion, T_previous_current (`None` before one).
    velocity: Option<Matrix4<f64>>,
    /// Frames since the last accepted one that were not repeats (the guess's steps).
    frames_since_accepted: u32,
    /// The voxel the last thinned frame was thinned at (the next frame's first try).
    thinning_voxel: Option<f64>,
}

impl Odometry {
    /// Odometry registering with `config` (checked now). Sensor frames mark missing returns
    /// with NaN or 0 0 0: set `config.non_finite` and `config.skip_origin` to drop them
    /// ([`Odometry::sensor_config`] does).
    pub fn new(config: RegistrationConfig) -> Result<Self, Error> {
        config.validate()?;
        Ok(Odometry {
            options: PrepareOptions::from_config(&config),
            config,
            keyframe: None,
            pose: Matrix4::identity(),
            velocity: None,
            frames_since_accepted: 0,
            thinning_voxel: None,
        })
    }

    /// The default registration, dropping the points sensors write for missing returns (NaN
    /// or infinite coordinates, and 0 0 0).
    pub fn sensor_config() -> RegistrationConfig {
        RegistrationConfig {
            non_finite: crate::point::NonFinite::Skip,
            skip_origin: true,
            ..RegistrationConfig::default()
        }
    }

    /// T_world_sensor of the last accepted frame (the identity before the first).
    pub fn pose(&self) -> Matrix4<f64> {
        self.pose
    }

    /// T_world_sensor the constant-velocity model predicts for the next frame: the last accepted
    /// pose moved by the last accepted motion once per frame since (`None` before the first).
    pub fn predicted_pose(&self) -> Option<Matrix4<f64>> {
        self.keyframe.as_ref()?;
        Some(orthonormalised(&(self.pose * self.guess())))
    }

    /// The motion from the last accepted frame the next frame is registered from.
    fn guess(&self) -> Matrix4<f64> {
        let velocity = self.velocity.unwrap_or_else(Matrix4::identity);
        (0..=self.frames_since_accepted).fold(Matrix4::identity(), |m, _| orthonormalised(&(m * velocity)))
    }

    /// The registration settings every frame uses.
    pub fn config(&self) -> &RegistrationConfig {
        &self.config
    }

    /// A frame that never reached [`Odometry::register_frame`] (the driver dropped it, or its
    /// input could not be read): the next frame's guess moves one frame further.
    pub fn skip_frame(&mut self) {
        if self.keyframe.is_some() {
            self.frames_since_accepted = self.frames_since_accepted.saturating_add(1);
        }
    }

    /// Registers the next frame (points in its sensor's frame). Input the registration refuses
    /// is a status, not an error: the odometry goes on as if the frame had not come.
    pub fn register_frame(&mut self, frame: &[Point], hooks: Hooks<'_>) -> FrameOutcome {
        let fingerprint = fingerprint_of(frame);
        let Some(keyframe) = &self.keyframe else {
            return match Keyframe::new(frame, fingerprint, &self.options) {
                Ok(keyframe) => {
                    self.keyframe = Some(keyframe);
                    outcome(FrameStatus::First, Some(self.pose), None, None, None)
                }
                Err(error) => outcome(FrameStatus::InputRejected, None, None, None, Some(error)),
            };
        };
        if keyframe.fingerprint == fingerprint {
            return outcome(FrameStatus::Repeated, None, Some(self.pose), None, None);
        }
        let first_since_accepted = self.frames_since_accepted == 0;
        let guess = self.guess();
        let predicted = self.predicted_pose();
        // A frame the config refuses for a non-finite point is registered whole, so that the
        // error names the frame's own index.
        let refused_as_given =
            self.config.non_finite == NonFinite::Reject && frame.iter().any(|p| !is_finite(p));
        let thinned = (!refused_as_given)
            .then(|| ThinnedFrame::of(frame, self.config.skip_origin, self.thinning_voxel))
            .flatten();
        let registered = thinned.as_ref().map_or(frame, |t| &t.points);
        let result = match register_clouds_to(registered, &keyframe.target, Some(&guess), &self.config, hooks)
        {
            Ok(mut result) => {
                if let Some(thinned) = &thinned {
                    self.thinning_voxel = Some(thinned.voxel);
                    thinned.spread_to_frame(&mut result);
                }
                result
            }
            Err(error) => {
                self.skip_frame();
                return outcome(FrameStatus::InputRejected, None, predicted, None, Some(error));
            }
        };
        let accepted_as = match result.quality.verdict {
            Verdict::Good => FrameStatus::Accepted,
            _ if self.velocity.is_some() && loose_only(&result) => FrameStatus::Loose,
            _ => {
                self.skip_frame();
                return outcome(FrameStatus::NotGood, None, predicted, Some(result), None);
            }
        };
        if self.velocity.is_some() && keyframe.displacement(&result.transform, &guess) > keyframe.median_range
        {
            self.skip_frame();
            return outcome(FrameStatus::Jumped, None, predicted, Some(result), None);
        }
        // The frame passed its registration, so it has points a target can be built on; a
        // refusal here is memory, and the frame is then not accepted either.
        let next = match Keyframe::new(frame, fingerprint, &self.options) {
            Ok(next) => next,
            Err(error) => {
                self.skip_frame();
                return outcome(
                    FrameStatus::InputRejected,
                    None,
                    predicted,
                    Some(result),
                    Some(error),
                );
            }
        };
        self.keyframe = Some(next);
        // The motion over a gap of several frames is no per-frame velocity: keep the last one.
        if first_since_accepted {
            self.velocity = Some(result.transform);
        }
        self.frames_since_accepted = 0;
        self.pose = orthonormalised(&(self.pose * result.transform));
        outcome(accepted_as, Some(self.pose), predicted, Some(result), None)
    }
}

/// Whether `result` would be GOOD but for its conditioning, with no start ended elsewhere (see
/// [`FrameStatus::Loose`]).
fn loose_only(result: &RegistrationResult) -> bool {
    let quality = &result.quality;
    quality.conditioning < MIN_CONDITIONING
        && quality.margin == f64::INFINITY
        && verdict_with(
            result,
            &Quality {
                conditioning: MIN_CONDITIONING,
                ..*quality
            },
        ) == Verdict::Good
}

fn outcome(
    status: FrameStatus,
    pose: Option<Matrix4<f64>>,
    predicted_pose: Option<Matrix4<f64>>,
    result: Option<RegistrationResult>,
    error: Option<Error>,
) -> FrameOutcome {
    FrameOutcome {
        status,
        pose,
        predicted_pose,
        result,
        error,
    }
}

/// A hash of the frame's exact coordinates (−0.0 and 0.0 apart: a resent frame is bit for bit
/// the same).
fn fingerprint_of(frame: &[Point]) -> u64 {
    let mut hasher = DefaultHasher::new();
    frame.len().hash(&mut hasher);
    for p in frame {
        for c in p {
            c.to_bits().hash(&mut hasher);
        }
    }
    hasher.finish()
}
