//! Command-line arguments and their translation into a [`RegistrationConfig`].
//!
//! Defaults shown by `--help` are read from `RegistrationConfig::default()`, so the tool and
//! the library cannot drift apart.
use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, ValueEnum};
use nalgebra::{Matrix4, Rotation3, Translation3};
use sie::{CostFunction, HistogramMode, Metric, NoiseModel, NoiseShape, RegistrationConfig, SieOptions};

use super::{CliError, EXIT_CODES_HELP};

/// What `--max-correspondence-distance` (and its usual spellings) gets: ICP libraries need a
/// gate, sie does not have one, and the similarly named option is something else.
pub const DISTANCE_GATE_ANSWER: &str = "--max-correspondence-distance: sie has no \
correspondence distance gate, so there is nothing to set. SIE decides from each iteration's \
residual histogram which matches are inliers; drop the option. (--max-correspondences N is \
unrelated: it samples N source points per iteration.)";

/// Student-t degrees of freedom when `--cost-param` is not given (Kerl et al. 2013, as the C API).
const DEFAULT_STUDENT_T_DOF: f64 = 5.0;

#[derive(Parser)]
#[command(
    name = "sie",
    version,
    about = "Point-cloud registration with a self-tuning robust cost (Statistical Inlier Estimation)",
    after_help = EXIT_CODES_HELP
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Register SOURCE onto TARGET: T_target_source (p_target = T · p_source) on stdout, a summary on
    /// stderr.
    #[command(after_help = EXIT_CODES_HELP)]
    Register(Box<RegisterArgs>),
    /// Register a built-in synthetic room scene and print the error against the known transform.
    Demo(DemoArgs),
    /// Odometry over FRAME files in order: each frame's T_world_sensor on stdout (KITTI: the top
    /// three rows, 12 numbers a line; the first frame is the world), its status on stderr.
    #[command(after_help = ODOMETRY_EXIT_CODES_HELP)]
    Odometry(OdometryArgs),
}

/// Exit codes of `sie odometry`.
pub const ODOMETRY_EXIT_CODES_HELP: &str = "\
Each frame registers onto the last accepted frame from a constant-velocity guess; only a GOOD
registration moves the trajectory, or a loose one (GOOD but for a weakly fixed direction, once a
motion is measured). A frame set aside (not GOOD, a jump no tracking explains, a repeat, an
unreadable file or no usable point) still gets a line: the constant-velocity prediction.
Missing returns (NaN, 0 0 0) are dropped.

Exit codes:
  0    every frame was accepted or loose
  2    usage error, or an output that could not be written
  3    some frames were set aside (their lines hold the prediction; stderr says why)
  70   internal error (a bug; please report the message)";

#[derive(Args)]
pub struct OdometryArgs {
    /// Frame files (.pcd, .ply, .xyz, .txt), in time order, points in the sensor's frame.
    #[arg(required = true, num_args = 1..)]
    pub frames: Vec<PathBuf>,
    /// Residual metric.
    #[arg(long, value_enum, default_value_t = MetricArg::PointToPlane)]
    pub metric: MetricArg,
    /// Neighbours for the target normals of point-to-plane (3..=1000).
    #[arg(long, default_value_t = defaults().normal_neighbours)]
    pub normal_neighbours: usize,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0, value_parser = parse_threads, allow_negative_numbers = true)]
    pub threads: usize,
    /// Also write the poses (the stdout lines) to FILE.
    #[arg(short, long, value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// No per-frame status lines on stderr (errors still are).
    #[arg(short, long)]
    pub quiet: bool,
}

impl OdometryArgs {
    pub fn config(&self) -> RegistrationConfig {
        RegistrationConfig {
            metric: self.metric.into(),
            normal_neighbours: self.normal_neighbours,
            threads: self.threads,
            ..sie::Odometry::sensor_config()
        }
    }
}

fn defaults() -> RegistrationConfig {
    RegistrationConfig::default()
}

fn default_noise_shape() -> f64 {
    match SieOptions::default().noise_shape {
        NoiseShape::Fixed(p) => p,
        NoiseShape::Estimated => 0.0,
    }
}

#[derive(Args)]
pub struct RegisterArgs {
    /// Cloud to move: .pcd (ascii, binary, binary_compressed), .ply (ascii, binary) or .xyz/.txt
    /// (one "x y z" per line).
    pub source: PathBuf,
    /// Cloud to align to (same formats).
    pub target: PathBuf,

    /// Weight of each correspondence; `sie` needs no parameter, the baselines do (--cost-param).
    #[arg(long, value_enum, default_value_t = CostArg::Sie, help_heading = "Method")]
    pub cost: CostArg,
    /// The baseline's parameter: truncated-l2 threshold, lp exponent p in (0, 2], student-t
    /// degrees of freedom (default 5), huber / cauchy / geman-mcclure / tukey scale. In residual
    /// units: input units with `--noise constant`.
    #[arg(long, value_name = "X", help_heading = "Method")]
    pub cost_param: Option<f64>,
    /// Residual: distance to the target's tangent plane (normals estimated from
    /// --normal-neighbours neighbours) or to the nearest target point.
    #[arg(long, value_enum, default_value_t = MetricArg::PointToPlane, help_heading = "Method")]
    pub metric: MetricArg,
    /// Per-point noise: the same everywhere, or σ ∝ z² in each cloud's own frame (depth cameras);
    /// SIE's histogram is then of noise-normalised residuals.
    #[arg(long, value_enum, default_value_t = NoiseArg::Constant, help_heading = "Method")]
    pub noise: NoiseArg,
    /// Shape p of SIE's inlier model exp(-(|r|/σ)^p / p): 2 Gaussian, 1 Laplacian, 0 estimates it.
    #[arg(long, value_name = "P", default_value_t = default_noise_shape(), help_heading = "Method")]
    pub noise_shape: f64,
    /// SIE histograms: one of |r| over all residual components, or one signed per component.
    #[arg(long, value_enum, default_value_t = HistogramArg::Pooled, help_heading = "Method")]
    pub histogram: HistogramArg,
    /// SIE's starting regulariser β (residual units); 0 uses the RMS of the initial residuals.
    #[arg(long, value_name = "BETA", default_value_t = 0.0, help_heading = "Method")]
    pub beta0: f64,
    /// β is multiplied by this after each convergence, in (0, 1).
    #[arg(long, value_name = "FACTOR", default_value_t = defaults().beta_shrink, help_heading = "Method")]
    pub beta_shrink: f64,
    /// Where SIE starts: `automatic` runs SIE from the initial guess with the paper's β₀, with a
    /// narrow β₀ and after a scale-free (L1) lead, and keeps the most significant result;
    /// `initial-guess` runs the paper's method from the guess (faster; for good guesses, e.g.
    /// odometry), and once more from its result when it ended more than 10σ from the guess
    /// beyond a local correction (half the target's spread, every direction fixed), and if that
    /// far result is not GOOD, with a narrow β₀ from the guess too (a small overlap);
    /// `global` needs no guess: FPFH descriptor matches propose poses and SIE runs from each
    /// (slower: the descriptors and up to 5 runs; clouds too small or flat are refused).
    #[arg(long, value_enum, default_value_t = StartsArg::Automatic, help_heading = "Method")]
    pub starts: StartsArg,

    /// Initial guess of T_target_source from a file: 16 numbers (4×4 row-major) or 12 (the top
    /// 3×4 rows); the `-o` output of another run works. Default: identity.
    #[arg(
        long,
        value_name = "FILE",
        conflicts_with = "init_pose",
        help_heading = "Start and stop"
    )]
    pub init: Option<PathBuf>,
    /// Initial guess as translation (input units) and rotation (radians):
    /// R = Rz(YAW)·Ry(PITCH)·Rx(ROLL), i.e. roll about x first, then pitch about y, then yaw about z.
    #[arg(
        long,
        num_args = 6,
        value_names = ["TX", "TY", "TZ", "ROLL", "PITCH", "YAW"],
        allow_negative_numbers = true,
        help_heading = "Start and stop"
    )]
    pub init_pose: Option<Vec<f64>>,
    /// Cap on each start's IRLS updates (each one matches, weighs and solves once); the summary's
    /// iterations count the updates of every start run (the automatic starts, a single start's
    /// rerun from its result, half and quarter turns, period shifts).
    #[arg(long, value_name = "N", default_value_t = defaults().max_iterations, help_heading = "Start and stop")]
    pub max_iterations: u32,
    /// Converged when an update moves the translation by less than this (input units) …
    #[arg(long, value_name = "DIST", default_value_t = defaults().translation_tolerance, help_heading = "Start and stop")]
    pub translation_tolerance: f64,
    /// … and rotates by less than this (radians).
    #[arg(long, value_name = "RAD", default_value_t = defaults().rotation_tolerance, help_heading = "Start and stop")]
    pub rotation_tolerance: f64,

    /// Use at most N randomly chosen source points per iteration (0 = all). A sampling cap, not
    /// a distance gate: sie has none.
    #[arg(long, value_name = "N", default_value_t = defaults().max_correspondences, help_heading = "Data")]
    pub max_correspondences: usize,
    /// Not an option of sie: PCL's correspondence distance gate, accepted only to answer it with
    /// DISTANCE_GATE_ANSWER.
    #[arg(
        long,
        value_name = "DIST",
        hide = true,
        alias = "max-distance",
        alias = "max-corr-dist",
        alias = "distance-threshold",
        allow_negative_numbers = true
    )]
    pub max_correspondence_distance: Option<String>,
    /// Neighbours for the target normals of point-to-plane (3..=1000).
    #[arg(long, value_name = "K", default_value_t = defaults().normal_neighbours, help_heading = "Data")]
    pub normal_neighbours: usize,
    /// Use the target file's normals (normal_x/y/z or nx/ny/nz) instead of estimating them.
    #[arg(long, help_heading = "Data")]
    pub file_normals: bool,
    /// Drop points with a NaN or infinite coordinate (PCL's marker of invalid points) instead of
    /// failing.
    #[arg(long, help_heading = "Data")]
    pub skip_invalid: bool,
    /// Drop points at exactly 0 0 0, as depth sensors mark invalid pixels (they are not
    /// measurements; point-to-point would match them to each other).
    #[arg(long, help_heading = "Data")]
    pub skip_origin: bool,
    /// Worker threads (0 = all cores).
    #[arg(
        long,
        value_name = "N",
        default_value_t = defaults().threads,
        value_parser = parse_threads,
        allow_negative_numbers = true,
        help_heading = "Data"
    )]
    pub threads: usize,
    /// Seed of the correspondence sampling (equal seeds, equal results).
    #[arg(long, default_value_t = defaults().seed, help_heading = "Data")]
    pub seed: u64,

    /// Also write the 4×4 transform to FILE (same text as stdout).
    #[arg(short, long, value_name = "FILE", help_heading = "Output")]
    pub output: Option<PathBuf>,
    /// Print a JSON report on stdout instead of the bare transform.
    #[arg(long, help_heading = "Output")]
    pub json: bool,
    /// Known T_target_source (same file format as --init): report the rotation and translation
    /// error of the result.
    #[arg(long, value_name = "FILE", help_heading = "Output")]
    pub ground_truth: Option<PathBuf>,
    /// Write the source cloud moved into the target frame: .pcd (float32 x y z, and normals when
    /// the source file has them, binary like PCL's own files; pcl::io::loadPCDFile reads it) or
    /// .xyz/.txt (full precision).
    #[arg(long, value_name = "FILE", help_heading = "Output")]
    pub aligned: Option<PathBuf>,
    /// Write the --aligned .pcd as ascii instead of binary.
    #[arg(long, requires = "aligned", help_heading = "Output")]
    pub aligned_ascii: bool,
    /// Draw the final residual histogram, the fitted inlier model and P(inlier | r) (.png or .svg).
    #[arg(long, value_name = "FILE", help_heading = "Output")]
    pub plot: Option<PathBuf>,
    /// Print σ, β, k, inlier fraction, RMSE and the update size of every iteration (stderr; in
    /// the JSON report with --json).
    #[arg(long, help_heading = "Output")]
    pub trace: bool,
    /// No progress line and no summary on stderr (errors still are).
    #[arg(short, long, help_heading = "Output")]
    pub quiet: bool,
}

#[derive(Args)]
pub struct DemoArgs {
    /// Points per cloud.
    #[arg(long, default_value_t = 50_000)]
    pub points: usize,
    /// Sensor noise σ in metres.
    #[arg(long, default_value_t = 0.01)]
    pub noise: f64,
    /// Scene seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Residual metric.
    #[arg(long, value_enum, default_value_t = MetricArg::PointToPlane)]
    pub metric: MetricArg,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0, value_parser = parse_threads, allow_negative_numbers = true)]
    pub threads: usize,
}

/// `--threads`: a negative count is taken as a value (not as an unknown option, which got
/// clap's tip to write `-- -1`) and refused with the values allowed; the library checks the
/// upper bound.
fn parse_threads(text: &str) -> Result<usize, String> {
    text.parse()
        .map_err(|_| "expected 0 (one per core) or a count of threads".to_string())
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CostArg {
    Sie,
    L2,
    TruncatedL2,
    Lp,
    StudentT,
    Huber,
    Cauchy,
    GemanMcclure,
    Tukey,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum MetricArg {
    #[value(alias = "plane")]
    PointToPlane,
    #[value(alias = "point")]
    PointToPoint,
}

impl From<MetricArg> for Metric {
    fn from(m: MetricArg) -> Self {
        match m {
            MetricArg::PointToPlane => Metric::PointToPlane,
            MetricArg::PointToPoint => Metric::PointToPoint,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
pub enum NoiseArg {
    Constant,
    QuadraticDepth,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum StartsArg {
    Automatic,
    InitialGuess,
    Global,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum HistogramArg {
    Pooled,
    PerColumn,
}

impl CostArg {
    /// The cost with its parameter; a missing or superfluous `--cost-param` is a usage error.
    fn cost_function(self, parameter: Option<f64>) -> Result<CostFunction, CliError> {
        let needed = |what: &str| {
            parameter
                .ok_or_else(|| CliError::new(format!("--cost {} needs --cost-param ({what})", self.name())))
        };
        let cost = match self {
            CostArg::Sie | CostArg::L2 => {
                if parameter.is_some() {
                    return Err(CliError::new(format!(
                        "--cost {} takes no --cost-param",
                        self.name()
                    )));
                }
                if self == CostArg::Sie {
                    CostFunction::Sie
                } else {
                    CostFunction::L2
                }
            }
            CostArg::TruncatedL2 => CostFunction::TruncatedL2 {
                threshold: needed("the residual threshold")?,
            },
            CostArg::Lp => CostFunction::Lp {
                p: needed("the exponent p in (0, 2]")?,
            },
            CostArg::StudentT => CostFunction::StudentT {
                dof: parameter.unwrap_or(DEFAULT_STUDENT_T_DOF),
            },
            CostArg::Huber => CostFunction::Huber {
                scale: needed("the scale")?,
            },
            CostArg::Cauchy => CostFunction::Cauchy {
                scale: needed("the scale")?,
            },
            CostArg::GemanMcclure => CostFunction::GemanMcClure {
                scale: needed("the scale")?,
            },
            CostArg::Tukey => CostFunction::Tukey {
                scale: needed("the scale")?,
            },
        };
        Ok(cost)
    }

    /// The value as typed on the command line.
    pub fn name(self) -> String {
        self.to_possible_value()
            .map(|v| v.get_name().to_string())
            .unwrap_or_default()
    }
}

impl RegisterArgs {
    /// The registration settings these arguments ask for, validated by the library.
    pub fn config(&self) -> Result<RegistrationConfig, CliError> {
        if self.max_correspondence_distance.is_some() {
            return Err(CliError::new(DISTANCE_GATE_ANSWER));
        }
        let mut config = RegistrationConfig {
            cost: self.cost.cost_function(self.cost_param)?,
            metric: self.metric.into(),
            max_iterations: self.max_iterations,
            translation_tolerance: self.translation_tolerance,
            rotation_tolerance: self.rotation_tolerance,
            noise: match self.noise {
                NoiseArg::Constant => NoiseModel::Constant,
                NoiseArg::QuadraticDepth => NoiseModel::QuadraticDepth,
            },
            initial_beta: (self.beta0 != 0.0).then_some(self.beta0),
            beta_shrink: self.beta_shrink,
            starts: match self.starts {
                StartsArg::Automatic => sie::Starts::Automatic,
                StartsArg::InitialGuess => sie::Starts::InitialGuess,
                StartsArg::Global => sie::Starts::Global,
            },
            max_correspondences: self.max_correspondences,
            normal_neighbours: self.normal_neighbours,
            threads: self.threads,
            seed: self.seed,
            record_trace: self.trace,
            skip_origin: self.skip_origin,
            ..RegistrationConfig::default()
        };
        config.sie.noise_shape = if self.noise_shape == 0.0 {
            NoiseShape::Estimated
        } else {
            NoiseShape::Fixed(self.noise_shape)
        };
        config.sie.histogram = match self.histogram {
            HistogramArg::Pooled => HistogramMode::Pooled,
            HistogramArg::PerColumn => HistogramMode::PerColumn,
        };
        config.validate().map_err(CliError::new)?;
        Ok(config)
    }
}

/// T from `--init-pose TX TY TZ ROLL PITCH YAW`: R = Rz(yaw)·Ry(pitch)·Rx(roll).
pub fn pose_matrix(values: &[f64]) -> Result<Matrix4<f64>, CliError> {
    let &[tx, ty, tz, roll, pitch, yaw] = values else {
        return Err(CliError::new(format!(
            "--init-pose needs 6 numbers (TX TY TZ ROLL PITCH YAW), got {}",
            values.len()
        )));
    };
    if let Some(bad) = values.iter().find(|v| !v.is_finite()) {
        return Err(CliError::new(format!(
            "--init-pose: {bad} is not a finite number"
        )));
    }
    let rotation = Rotation3::from_euler_angles(roll, pitch, yaw);
    Ok(Translation3::new(tx, ty, tz).to_homogeneous() * rotation.to_homogeneous())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector3, Vector4};

    #[test]
    fn init_pose_is_yaw_pitch_roll_about_fixed_axes() {
        let t = pose_matrix(&[1.0, 2.0, 3.0, 0.1, -0.2, 0.3]).unwrap();
        let expected = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.3)
            * Rotation3::from_axis_angle(&Vector3::y_axis(), -0.2)
            * Rotation3::from_axis_angle(&Vector3::x_axis(), 0.1);
        assert!((t.fixed_view::<3, 3>(0, 0) - expected.matrix()).abs().max() < 1e-15);
        assert_eq!(t.column(3), Vector4::new(1.0, 2.0, 3.0, 1.0));
        assert!(pose_matrix(&[0.0; 5]).is_err());
        assert!(pose_matrix(&[0.0, 0.0, f64::NAN, 0.0, 0.0, 0.0]).is_err());
    }

    #[test]
    fn cost_parameters_are_required_exactly_when_used() {
        assert_eq!(CostArg::Sie.cost_function(None).unwrap(), CostFunction::Sie);
        assert!(CostArg::Sie.cost_function(Some(1.0)).is_err());
        assert!(CostArg::Cauchy.cost_function(None).is_err());
        assert_eq!(
            CostArg::StudentT.cost_function(None).unwrap(),
            CostFunction::StudentT { dof: 5.0 }
        );
        assert_eq!(CostArg::TruncatedL2.name(), "truncated-l2");
    }
}
