//! `sie odometry FRAME...`: a sequence of frames through `sie::Odometry`, one KITTI pose line a
//! frame on stdout (a frame set aside gets the constant-velocity prediction), its status on
//! stderr.
use std::fmt::Write as _;
use std::fs;

use nalgebra::Matrix4;
use sie::io::read_cloud_with;
use sie::{FrameOutcome, FrameStatus, Hooks, NonFinite, Odometry};

use super::args::OdometryArgs;
use super::{CliError, exit};

pub fn run(args: &OdometryArgs) -> Result<u8, CliError> {
    let mut odometry = Odometry::new(args.config()).map_err(CliError::new)?;
    let mut lines = String::new();
    let mut set_aside = 0usize;
    for (index, path) in args.frames.iter().enumerate() {
        let (pose, status, used) = match read_cloud_with(path, NonFinite::Skip) {
            Ok(cloud) => {
                let outcome = odometry.register_frame(&cloud.points, Hooks::default());
                let used = matches!(
                    outcome.status,
                    FrameStatus::First | FrameStatus::Accepted | FrameStatus::Loose
                );
                (frame_pose(&outcome, &odometry), describe(&outcome), used)
            }
            Err(message) => {
                let predicted = odometry.predicted_pose().unwrap_or_else(|| odometry.pose());
                odometry.skip_frame();
                (predicted, format!("unreadable, set aside: {message}"), false)
            }
        };
        if !used {
            set_aside += 1;
        }
        if !args.quiet {
            eprintln!("frame {index} {}: {status}", path.display());
        }
        let line = kitti_line(&pose);
        println!("{line}");
        let _ = writeln!(lines, "{line}");
    }
    if let Some(path) = &args.output {
        fs::write(path, &lines).map_err(|e| CliError::new(format_args!("{}: {e}", path.display())))?;
    }
    if !args.quiet {
        eprintln!("{} frames, {set_aside} set aside", args.frames.len());
    }
    Ok(if set_aside == 0 {
        exit::CONVERGED
    } else {
        exit::NOT_GOOD
    })
}

/// The frame's pose, or the best estimate the odometry has for it when it was set aside.
fn frame_pose(outcome: &FrameOutcome, odometry: &Odometry) -> Matrix4<f64> {
    outcome
        .pose
        .or(outcome.predicted_pose)
        .unwrap_or_else(|| odometry.pose())
}

fn describe(outcome: &FrameOutcome) -> String {
    let verdict = || {
        outcome.result.as_ref().map_or(String::new(), |r| {
            format!(" (verdict {:?}, {} updates)", r.quality.verdict, r.iterations).to_lowercase()
        })
    };
    match outcome.status {
        FrameStatus::First => "first (the world frame)".into(),
        FrameStatus::Accepted => format!("accepted{}", verdict()),
        FrameStatus::Loose => format!("accepted, one direction loosely fixed{}", verdict()),
        FrameStatus::Repeated => "the last accepted frame again, set aside".into(),
        FrameStatus::NotGood => format!("not good, set aside{}", verdict()),
        FrameStatus::Jumped => format!("jumped further than tracking explains, set aside{}", verdict()),
        FrameStatus::InputRejected => format!(
            "refused, set aside: {}",
            outcome.error.as_ref().map_or(String::new(), ToString::to_string)
        ),
    }
}

/// The top three rows of a 4×4 pose, row-major (the KITTI poses format).
fn kitti_line(pose: &Matrix4<f64>) -> String {
    (0..3)
        .flat_map(|r| (0..4).map(move |c| (r, c)))
        .map(|(r, c)| format!("{:e}", pose[(r, c)]))
        .collect::<Vec<_>>()
        .join(" ")
}
