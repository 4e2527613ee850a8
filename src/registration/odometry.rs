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
//! A frame set aside right after the keyframe whose result failed GOOD only for its
//! conditioning, a rival start or its settling, its own start having won, can be bridged over:
//! the next frame that does not register onto the keyframe registers onto that nearer frame,
//! and is taken when that result is GOOD or loose and its motion agrees with the set-aside
//! frame's (constant velocity). Without it, a first motion with a rival left no motion
//! measured and the keyframe behind for good (a depth camera at 12° a frame: 29 of 29 frames
//! set aside). Before any motion is measured, the keyframe's guess is the identity, so the
//! set-aside frame is tried first; and a first motion the identity does not give is looked for
//! by the global stage (`Starts::Global`, once, under the default `Starts::Automatic`), whose
//! result is taken when GOOD and set aside for a bridge when it fails GOOD only for its
//! conditioning or settling (a depth camera at 18° a frame registers wrong from the identity).
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
use crate::registration::config::{RegistrationConfig, Starts};
use crate::registration::hooks::Hooks;
use crate::registration::irls::searches_starts;
use crate::registration::result::{Quality, RegistrationResult, StartKind, StopReason, Verdict};
use crate::registration::target::{PrepareOptions, PreparedTarget};
use crate::registration::thinning::ThinnedFrame;
use crate::registration::verdict::{MIN_CONDITIONING, verdict_if_settled, verdict_with};

/// What became of one frame given to [`Odometry::register_frame`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameStatus {
    /// The first usable frame: it fixes the world frame (its pose is the odometry's start).
    First,
    /// Registered onto the last accepted frame with a GOOD verdict, or bridged over the frame
    /// set aside just before it (see `NotGood`) with a GOOD verdict there; its pose is the new
    /// one.
    Accepted,
    /// Bit for bit the last accepted frame again (a driver that sent it twice): ignored.
    Repeated,
    /// Refused as input (`FrameOutcome::error` says why: no point left after dropping
    /// invalid ones, a non-finite coordinate the config rejects, a frame in other units than
    /// the last accepted one, memory): ignored.
    InputRejected,
    /// Registered, but the verdict is not GOOD (`FrameOutcome::result` has it) and the frame
    /// is not `Loose`: the pose is not trusted and the frame is ignored (a jump, a frame from
    /// elsewhere, a close call between two poses, a run that did not settle). When it is the
    /// frame after the last accepted one and failed GOOD only for its conditioning, a rival
    /// start or its settling (the start from the guess won), the next frame may bridge over it:
    /// if that frame does not register onto the last accepted one, it registers onto this
    /// one, and is taken (`Accepted` or `Loose`, its pose through this frame's) when that
    /// result is GOOD or loose with no rival and its motion agrees with this frame's to half
    /// a frame's motion (a bridge that agrees but slid to its cap runs once more from where it
    /// stopped; capped again, it passes the turn to the frame after). With no motion measured
    /// yet, the bridge goes first (its result is then this status's when it passes the turn),
    /// and a first motion the guess did not give is looked for by the global stage under
    /// `Starts::Automatic` (its result is this status's when it may be bridged over: GOOD but
    /// for its conditioning or settling).
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
    /// measured (or, for a bridge over a `NotGood` frame, that frame's motion agreeing with
    /// it) and the result within tracking's reach as `Jumped` measures it: the data fix
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
    /// and `Jumped`), or, for a frame taken by a bridge (or a `NotGood` one whose bridge passed
    /// the turn), onto the frame set aside before it; for a first motion found by the global
    /// stage, that registration. Its `probabilities` and `correspondences` have one entry per
    /// frame point, also when the frame was registered thinned (a point left out takes those of
    /// the point kept in its voxel; a skipped point 0 and -1); `inlier_fraction` and the trace
    /// count the points registered.
    pub result: Option<RegistrationResult>,
    /// Why an `InputRejected` frame was refused.
    pub error: Option<Error>,
}

/// A bridge over a set-aside frame needs the next motion within this fraction of the set-aside
/// frame's own motion from it (each as `Keyframe::displacement` measures it). On a depth
/// camera's loop at 12° a frame right consecutive motions differ by 0.17 of one; a set-aside
/// pose off by more than half a frame's motion makes the next motion disagree.
const BRIDGE_AGREEMENT: f64 = 0.5;

/// The frame just set aside, when its registration was right in every check the odometry
/// makes but its conditioning, its margin over a rival start and its settling (`bridgeable`),
/// from the start at its guess: the next frame, if it does not register onto the keyframe, may
/// register onto this nearer frame instead (`Odometry::bridge`).
struct SetAside {
    frame: Keyframe,
    /// Where its registrations put it, T_keyframe_frame (doubtful, not yet taken).
    motion: Matrix4<f64>,
    /// Its own one frame's motion (the last link of `motion`): the next frame's guess, and
    /// what the next motion must agree with.
    step: Matrix4<f64>,
}

impl SetAside {
    /// Whether the next frame's motion from this one (a bridge's result) agrees with this
    /// frame's own motion, within [`BRIDGE_AGREEMENT`].
    fn agrees(&self, next: &RegistrationResult) -> bool {
        self.frame.displacement(&next.transform, &self.step)
            <= BRIDGE_AGREEMENT * self.frame.displacement(&self.step, &Matrix4::identity())
    }
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
    /// The frame before this one, when it was set aside but may be bridged over.
    set_aside: Option<SetAside>,
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
            set_aside: None,
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
        self.set_aside = None;
        if self.keyframe.is_some() {
            self.frames_since_accepted = self.frames_since_accepted.saturating_add(1);
        }
    }

    /// Registers the next frame (points in its sensor's frame). Input the registration refuses
    /// is a status, not an error: the odometry goes on as if the frame had not come.
    pub fn register_frame(&mut self, frame: &[Point], mut hooks: Hooks<'_>) -> FrameOutcome {
        let fingerprint = fingerprint_of(frame);
        let Some(keyframe) = &self.keyframe else {
            return self.start(frame, fingerprint);
        };
        if keyframe.fingerprint == fingerprint {
            return outcome(FrameStatus::Repeated, None, Some(self.pose), None, None);
        }
        let set_aside = self.set_aside.take();
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
        // With no motion measured, the keyframe's guess is the identity, two frames' motion
        // away by the set-aside frame's own result: the nearer frame goes first, and a bridge
        // whose motion agrees is not undone by a registration from that far guess.
        let (set_aside_first, set_aside) = match set_aside {
            Some(over) if self.velocity.is_none() => (Some(over), None),
            other => (None, other),
        };
        if let Some(over) = set_aside_first {
            match self.bridge(
                over,
                frame,
                thinned.as_ref(),
                fingerprint,
                predicted,
                hooks.reborrow(),
            ) {
                BridgeTurn::Passed(again, result) => {
                    self.skip_frame();
                    self.set_aside = Some(*again);
                    return outcome(FrameStatus::NotGood, None, predicted, Some(*result), None);
                }
                BridgeTurn::Broken => {}
                BridgeTurn::Over(done) => return *done,
            }
        }
        // A bridge that did not take the frame left the keyframe as it was.
        let Some(keyframe) = &self.keyframe else {
            return self.start(frame, fingerprint);
        };
        let result = match register_frame_onto(
            frame,
            thinned.as_ref(),
            &keyframe.target,
            &guess,
            &self.config,
            hooks.reborrow(),
        ) {
            Ok(result) => result,
            Err(error) => {
                self.skip_frame();
                return outcome(FrameStatus::InputRejected, None, predicted, None, Some(error));
            }
        };
        if let Some(thinned) = &thinned {
            self.thinning_voxel = Some(thinned.voxel);
        }
        let taken_as = match result.quality.verdict {
            Verdict::Good => Some(FrameStatus::Accepted),
            _ if self.velocity.is_some() && loose_only(&result) => Some(FrameStatus::Loose),
            _ => None,
        };
        let within_reach = self.velocity.is_none()
            || keyframe.displacement(&result.transform, &guess) <= keyframe.median_range;
        let status = match taken_as {
            Some(status) if within_reach => {
                // The motion over a gap of several frames is no per-frame velocity.
                let velocity = first_since_accepted.then_some(result.transform);
                let taken = Taken {
                    status,
                    motion: result.transform,
                    result,
                };
                return self.accept(frame, fingerprint, taken, velocity, predicted);
            }
            Some(_) => FrameStatus::Jumped,
            None => FrameStatus::NotGood,
        };
        // With no motion measured, a first motion the guess (the identity) did not give and
        // that cannot be bridged over is looked for with no guess: the global stage.
        let global_search = status == FrameStatus::NotGood
            && first_since_accepted
            && self.velocity.is_none()
            && self.config.starts == Starts::Automatic
            && searches_starts(&self.config)
            && result.stop_reason != StopReason::Cancelled
            && !bridgeable(&result);
        let found = global_search
            .then(|| {
                let config = RegistrationConfig {
                    starts: Starts::Global,
                    ..self.config.clone()
                };
                register_frame_onto(
                    frame,
                    thinned.as_ref(),
                    &keyframe.target,
                    &guess,
                    &config,
                    hooks.reborrow(),
                )
            })
            // The global stage refuses frames too plain to describe; the guess's result stands.
            .and_then(Result::ok);
        let (result, global_motion_loose) = match found {
            Some(found) if found.quality.verdict == Verdict::Good => {
                let velocity = Some(found.transform);
                let taken = Taken {
                    status: FrameStatus::Accepted,
                    motion: found.transform,
                    result: found,
                };
                return self.accept(frame, fingerprint, taken, velocity, predicted);
            }
            Some(found) if settled_but_loose(&found) => (found, true),
            Some(found) if found.stop_reason == StopReason::Cancelled => (found, false),
            _ => (result, false),
        };
        let mut next_set_aside = None;
        if let Some(over) = set_aside
            && result.stop_reason != StopReason::Cancelled
        {
            match self.bridge(over, frame, thinned.as_ref(), fingerprint, predicted, hooks) {
                BridgeTurn::Passed(again, _) => next_set_aside = Some(*again),
                BridgeTurn::Broken => {}
                BridgeTurn::Over(done) => return *done,
            }
        }
        self.skip_frame();
        if next_set_aside.is_none()
            && status == FrameStatus::NotGood
            && first_since_accepted
            && within_reach
            && (global_motion_loose || bridgeable(&result))
        {
            // A frame that cannot be prepared as a target is simply not bridged over.
            next_set_aside = Keyframe::new(frame, fingerprint, &self.options)
                .ok()
                .map(|frame| SetAside {
                    frame,
                    motion: result.transform,
                    step: result.transform,
                });
        }
        self.set_aside = next_set_aside;
        outcome(status, None, predicted, Some(result), None)
    }

    /// Makes `frame` the first keyframe.
    fn start(&mut self, frame: &[Point], fingerprint: u64) -> FrameOutcome {
        match Keyframe::new(frame, fingerprint, &self.options) {
            Ok(keyframe) => {
                self.keyframe = Some(keyframe);
                outcome(FrameStatus::First, Some(self.pose), None, None, None)
            }
            Err(error) => outcome(FrameStatus::InputRejected, None, None, None, Some(error)),
        }
    }

    /// Registers `frame` onto the frame just set aside (`over`), from the set-aside frame's own
    /// motion. The frame is taken when that registration is GOOD, or loose with no rival start,
    /// and its motion agrees with the set-aside one's (within [`BRIDGE_AGREEMENT`]): two
    /// consecutive motions then agree, and the set-aside pose is taken as the bridge's first
    /// half. A run that agrees but slid along the loose direction to its cap runs once more
    /// from where it stopped, and that run decides; one that agrees but is itself only
    /// `bridgeable` (capped again) makes this frame the next one to bridge over.
    fn bridge(
        &mut self,
        over: SetAside,
        frame: &[Point],
        thinned: Option<&ThinnedFrame>,
        fingerprint: u64,
        predicted: Option<Matrix4<f64>>,
        mut hooks: Hooks<'_>,
    ) -> BridgeTurn {
        let Ok(mut result) = register_frame_onto(
            frame,
            thinned,
            &over.frame.target,
            &over.step,
            &self.config,
            hooks.reborrow(),
        ) else {
            return BridgeTurn::Broken;
        };
        // A run that slid along the loose direction to its cap stopped short of showing where
        // the data hold it; from where it stopped, one more run settles or not.
        if result.stop_reason == StopReason::IterationLimit && bridgeable(&result) && over.agrees(&result) {
            let settled = register_frame_onto(
                frame,
                thinned,
                &over.frame.target,
                &result.transform,
                &self.config,
                hooks,
            );
            if let Ok(settled) = settled
                && settled.stop_reason != StopReason::IterationLimit
            {
                result = settled;
            }
        }
        if result.stop_reason == StopReason::Cancelled {
            self.skip_frame();
            let cancelled = outcome(FrameStatus::NotGood, None, predicted, Some(result), None);
            return BridgeTurn::Over(Box::new(cancelled));
        }
        if !over.agrees(&result) {
            return BridgeTurn::Broken;
        }
        let motion = orthonormalised(&(over.motion * result.transform));
        let taken_as = match result.quality.verdict {
            Verdict::Good => FrameStatus::Accepted,
            _ if loose_only(&result) => FrameStatus::Loose,
            _ if bridgeable(&result) => {
                let Ok(frame) = Keyframe::new(frame, fingerprint, &self.options) else {
                    return BridgeTurn::Broken;
                };
                if let Some(thinned) = thinned {
                    self.thinning_voxel = Some(thinned.voxel);
                }
                let again = SetAside {
                    frame,
                    motion,
                    step: result.transform,
                };
                return BridgeTurn::Passed(Box::new(again), Box::new(result));
            }
            _ => return BridgeTurn::Broken,
        };
        if let Some(thinned) = thinned {
            self.thinning_voxel = Some(thinned.voxel);
        }
        let velocity = Some(result.transform);
        let taken = Taken {
            status: taken_as,
            motion,
            result,
        };
        BridgeTurn::Over(Box::new(self.accept(
            frame,
            fingerprint,
            taken,
            velocity,
            predicted,
        )))
    }

    /// Takes the frame: its motion moves the pose, and it becomes the keyframe; `velocity` is
    /// its motion when that is one frame's (the next frames' guess), `None` to keep the last.
    fn accept(
        &mut self,
        frame: &[Point],
        fingerprint: u64,
        taken: Taken,
        velocity: Option<Matrix4<f64>>,
        predicted: Option<Matrix4<f64>>,
    ) -> FrameOutcome {
        let Taken {
            status,
            motion,
            result,
        } = taken;
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
        if velocity.is_some() {
            self.velocity = velocity;
        }
        self.frames_since_accepted = 0;
        self.pose = orthonormalised(&(self.pose * motion));
        outcome(status, Some(self.pose), predicted, Some(result), None)
    }
}

/// A frame to take: its status, its motion from the keyframe (T_keyframe_frame) and the
/// registration behind it.
struct Taken {
    status: FrameStatus,
    motion: Matrix4<f64>,
    result: RegistrationResult,
}

/// What a bridge over a set-aside frame leaves of the frame's turn.
enum BridgeTurn {
    /// The frame's outcome: the bridge took it, or the caller's observer stopped it.
    Over(Box<FrameOutcome>),
    /// Not taken: the frame may be bridged over next (its bridge's registration beside it).
    Passed(Box<SetAside>, Box<RegistrationResult>),
    /// The registration onto the keyframe decides.
    Broken,
}

/// Registers `frame` (its thinned points when it was thinned) onto `target` from `guess`; the
/// result names every frame point.
fn register_frame_onto(
    frame: &[Point],
    thinned: Option<&ThinnedFrame>,
    target: &PreparedTarget,
    guess: &Matrix4<f64>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let registered = thinned.map_or(frame, |t| &t.points);
    let mut result = register_clouds_to(registered, target, Some(guess), config, hooks)?;
    if let Some(thinned) = thinned {
        thinned.spread_to_frame(&mut result);
    }
    Ok(result)
}

/// Whether a result set aside may be bridged over by the next frame: the start from the
/// tracking's guess won (a rival that beat the guess is another pose, not a loosely fixed one)
/// and it would be GOOD but for its conditioning, a rival start and its settling (a run along a
/// loose direction may slide to its cap; a cancelled or degenerate run is not bridged over).
fn bridgeable(result: &RegistrationResult) -> bool {
    let no_rival = Quality {
        margin: f64::INFINITY,
        ..conditioning_met(&result.quality)
    };
    matches!(
        result.search.start,
        StartKind::InitialGuess | StartKind::WarmStart
    ) && good_but_for_settling(result, &no_rival)
}

/// Whether a first motion the global stage found may be bridged over by the next frame: it
/// would be GOOD but for its conditioning and its settling, its rivals included (its starts
/// are poses from descriptor matches, not a guess to fall back on).
fn settled_but_loose(result: &RegistrationResult) -> bool {
    good_but_for_settling(result, &conditioning_met(&result.quality))
}

/// Whether a converged or capped run would be GOOD with `quality` as its evidence.
fn good_but_for_settling(result: &RegistrationResult, quality: &Quality) -> bool {
    matches!(
        result.stop_reason,
        StopReason::Converged | StopReason::IterationLimit
    ) && verdict_if_settled(result, quality) == Verdict::Good
}

/// Whether `result` would be GOOD but for its conditioning, with no start ended elsewhere (see
/// [`FrameStatus::Loose`]).
fn loose_only(result: &RegistrationResult) -> bool {
    let quality = &result.quality;
    quality.conditioning < MIN_CONDITIONING
        && quality.margin == f64::INFINITY
        && verdict_with(result, &conditioning_met(quality)) == Verdict::Good
}

/// `quality` with its conditioning raised to the verdict's minimum where it falls short.
fn conditioning_met(quality: &Quality) -> Quality {
    Quality {
        conditioning: quality.conditioning.max(MIN_CONDITIONING),
        ..*quality
    }
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
