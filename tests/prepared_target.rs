//! A prepared target gives the results of `register_clouds` bit for bit: alone, reused by many
//! registrations, and shared by several threads at once.
mod common;

use std::sync::Arc;

use nalgebra::Matrix4;
use sie::synthetic::room_scene;
use sie::{
    CostFunction, Error, Hooks, Metric, Point, PrepareOptions, PreparedTarget, RegistrationConfig,
    RegistrationResult, register_clouds, register_clouds_to,
};

/// Everything but the wall times must be equal, floats compared by their bits.
fn assert_same(a: &RegistrationResult, b: &RegistrationResult, what: &str) {
    let bits = |m: &Matrix4<f64>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.transform), bits(&b.transform), "{what}: transform");
    let mut a = a.clone();
    let mut b = b.clone();
    a.times = Default::default();
    b.times = Default::default();
    // PartialEq on f64 would accept 0.0 == -0.0; the Debug text tells them apart.
    // The texts run to megabytes: name where they first differ.
    let (a, b) = (format!("{a:?}"), format!("{b:?}"));
    if let Some(at) = a
        .bytes()
        .zip(b.bytes())
        .position(|(x, y)| x != y)
        .or((a.len() != b.len()).then_some(0))
    {
        let around = |text: &str| {
            text.get(at.saturating_sub(200)..(at + 200).min(text.len()))
                .unwrap_or(text)
                .to_owned()
        };
        panic!(
            "{what}: results differ at byte {at}:\n{}\n<>\n{}",
            around(&a),
            around(&b)
        );
    }
}

fn configs() -> Vec<(&'static str, RegistrationConfig)> {
    vec![
        ("SIE point-to-plane", RegistrationConfig::default()),
        (
            "SIE point-to-point, 2 threads, trace",
            RegistrationConfig {
                metric: Metric::PointToPoint,
                threads: 2,
                record_trace: true,
                ..RegistrationConfig::default()
            },
        ),
        (
            "Huber, sampled",
            RegistrationConfig {
                cost: CostFunction::Huber { scale: 0.05 },
                max_correspondences: 2_000,
                ..RegistrationConfig::default()
            },
        ),
    ]
}

#[test]
fn prepared_equals_unprepared_bit_for_bit() {
    let scene = room_scene(6_000, 0.01, 21);
    let init = Matrix4::identity();
    for (what, config) in configs() {
        let direct = register_clouds(
            &scene.source,
            &scene.target,
            None,
            Some(&init),
            &config,
            Hooks::default(),
        )
        .expect(what);
        let (rotation, translation) = common::pose_error(&direct.transform, &scene.t_target_source);
        assert!(
            rotation < 0.5 && translation < 0.02,
            "{what}: {rotation} deg {translation} m"
        );
        let prepared =
            PreparedTarget::new(&scene.target, None, &PrepareOptions::from_config(&config)).unwrap();
        // Twice: the second call reuses the normals the first estimated.
        for round in 0..2 {
            let again = register_clouds_to(&scene.source, &prepared, Some(&init), &config, Hooks::default())
                .expect(what);
            assert_same(&direct, &again, &format!("{what}, round {round}"));
            assert_eq!(again.times.index, 0.0, "a prepared target is not rebuilt");
        }
    }
}

#[test]
fn a_target_reused_by_other_sources_first_gives_the_same_results() {
    // Normals estimated for one source's matches are kept; the next source must not notice.
    let scene = room_scene(5_000, 0.01, 22);
    let other = room_scene(5_000, 0.02, 23);
    let config = RegistrationConfig::default();
    let prepared = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
    register_clouds_to(&other.source, &prepared, None, &config, Hooks::default()).unwrap();
    let reused = register_clouds_to(&scene.source, &prepared, None, &config, Hooks::default()).unwrap();
    let direct = common::icp(&scene.source, &scene.target, &config);
    assert_same(&direct, &reused, "after another source");
    // All normals estimated up front: the same again.
    let eager = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
    eager.estimate_all_normals(2).unwrap();
    let from_eager = register_clouds_to(&scene.source, &eager, None, &config, Hooks::default()).unwrap();
    assert_same(&direct, &from_eager, "normals estimated up front");
}

#[test]
fn one_target_shared_by_threads_gives_the_serial_results() {
    let scene = room_scene(4_000, 0.01, 24);
    // Different sources: the scene's own and the source moved by a few small offsets.
    let sources: Vec<Vec<Point>> = (0..6)
        .map(|k| {
            let shift = 0.01 * k as f64;
            scene
                .source
                .iter()
                .map(|p| [p[0] + shift, p[1] - shift, p[2]])
                .collect()
        })
        .collect();
    let config = RegistrationConfig {
        threads: 1,
        ..RegistrationConfig::default()
    };
    let serial: Vec<RegistrationResult> = sources
        .iter()
        .map(|source| common::icp(source, &scene.target, &config))
        .collect();
    for round in 0..3 {
        // A fresh target each round, so the threads race on estimating its normals.
        let shared = Arc::new(PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap());
        let handles: Vec<_> = sources
            .iter()
            .cloned()
            .map(|source| {
                let (shared, config) = (Arc::clone(&shared), config.clone());
                std::thread::spawn(move || {
                    register_clouds_to(&source, &shared, None, &config, Hooks::default())
                })
            })
            .collect();
        for (k, handle) in handles.into_iter().enumerate() {
            let result = handle.join().expect("no panic").expect("registration");
            assert_same(&serial[k], &result, &format!("round {round}, source {k}"));
        }
    }
}

#[test]
fn given_normals_and_skipped_points_map_back_to_the_callers_indices() {
    let scene = room_scene(4_000, 0.005, 25);
    let normals = sie::normals::estimate_normals(
        &scene.target,
        &sie::nn::NearestNeighbours::new(&scene.target).unwrap(),
        10,
        &sie::parallel::Workers::new(1).unwrap(),
    );
    let config = RegistrationConfig {
        non_finite: sie::NonFinite::Skip,
        ..RegistrationConfig::default()
    };
    let mut target = scene.target.clone();
    let mut target_normals = normals.clone();
    let mut source = scene.source.clone();
    for i in [0, 17, 999] {
        target[i] = [f64::NAN, 0.0, 0.0];
        target_normals[i] = [0.0, f64::INFINITY, 0.0];
        source[i + 1] = [0.0, 0.0, f64::NEG_INFINITY];
    }
    let direct = register_clouds(
        &source,
        &target,
        Some(&target_normals),
        None,
        &config,
        Hooks::default(),
    )
    .unwrap();
    let prepared = PreparedTarget::new(
        &target,
        Some(&target_normals),
        &PrepareOptions::from_config(&config),
    )
    .unwrap();
    assert_eq!((prepared.len(), prepared.indexed_len()), (4_000, 3_997));
    let reused = register_clouds_to(&source, &prepared, None, &config, Hooks::default()).unwrap();
    assert_same(&direct, &reused, "skipped points, given normals");
    assert_eq!(reused.correspondences.len(), source.len());
    assert_eq!(reused.correspondences[1], -1);
    assert!(
        reused
            .correspondences
            .iter()
            .all(|&t| t < 0 || ![0, 17, 999].contains(&t))
    );
    // Correspondences name the caller's target points: each is a nearest finite target of the
    // transformed source point (brute force on a subset).
    let distance = |p: &Point, q: &Point| (0..3).map(|d| (p[d] - q[d]).powi(2)).sum::<f64>();
    let mut checked = 0;
    for (s, &t) in reused.correspondences.iter().enumerate().step_by(20) {
        if t < 0 {
            continue;
        }
        let p = sie::geometry::transform_point(&reused.transform, &source[s]);
        let nearest = target
            .iter()
            .filter(|q| q.iter().all(|v| v.is_finite()))
            .map(|q| distance(&p, q))
            .fold(f64::INFINITY, f64::min);
        assert_eq!(distance(&p, &target[t as usize]), nearest, "source {s}");
        checked += 1;
    }
    assert!(checked > 100, "{checked}");
}

#[test]
fn a_config_that_does_not_fit_the_prepared_normals_is_refused() {
    let scene = room_scene(2_000, 0.01, 26);
    let prepared = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
    let config = RegistrationConfig {
        normal_neighbours: 20,
        ..RegistrationConfig::default()
    };
    match register_clouds_to(&scene.source, &prepared, None, &config, Hooks::default()) {
        Err(Error::InvalidArgument(message)) => assert!(message.contains("20"), "{message}"),
        other => panic!("{other:?}"),
    }
    // Point-to-point does not use normals: any count is fine.
    let point_to_point = RegistrationConfig {
        metric: Metric::PointToPoint,
        ..config
    };
    register_clouds_to(&scene.source, &prepared, None, &point_to_point, Hooks::default()).unwrap();
    let zero_normals = vec![[0.0; 3]; scene.target.len()];
    let without =
        PreparedTarget::new(&scene.target, Some(&zero_normals), &PrepareOptions::default()).unwrap();
    assert!(matches!(
        register_clouds_to(
            &scene.source,
            &without,
            None,
            &RegistrationConfig::default(),
            Hooks::default()
        ),
        Err(Error::InvalidArgument(_))
    ));
    let few = [[0.0; 3]; 2];
    assert!(matches!(
        register_clouds_to(
            &few,
            &prepared,
            None,
            &RegistrationConfig::default(),
            Hooks::default()
        ),
        Err(Error::TooFewPoints(_))
    ));
}

/// The surface of a 2 × 1 × 0.6 box sampled on a 5 cm lattice: every neighbourhood has many
/// target points at exactly the same distance, so a k-nearest query may keep any of the tied ones.
fn lattice_box() -> Vec<Point> {
    let (nx, ny, nz) = (40, 20, 12);
    let mut points = Vec::new();
    for i in 0..=nx {
        for j in 0..=ny {
            for k in 0..=nz {
                if i == 0 || i == nx || j == 0 || j == ny || k == 0 || k == nz {
                    points.push([0.05 * i as f64, 0.05 * j as f64, 0.05 * k as f64]);
                }
            }
        }
    }
    points
}

#[test]
fn a_point_to_point_registration_after_a_point_to_plane_one_gives_the_fresh_result_on_a_lattice() {
    // The point-to-plane run keeps the normals it estimated; the point-to-point run's surface
    // checks then read them where a fresh run estimates its own: they must be the same normals,
    // bit for bit, even where tied neighbours could be taken in another order.
    let target = lattice_box();
    let turn = nalgebra::Rotation3::from_euler_angles(0.03, -0.02, 0.05).to_homogeneous();
    let source: Vec<Point> = target
        .iter()
        .map(|p| {
            let q = sie::geometry::transform_point(&turn, p);
            [q[0] + 0.02, q[1] - 0.01, q[2] + 0.015]
        })
        .collect();
    for first in [Metric::PointToPlane, Metric::PointToPoint] {
        for metric in [Metric::PointToPoint, Metric::PointToPlane] {
            let config = RegistrationConfig {
                metric,
                ..RegistrationConfig::default()
            };
            let direct = common::icp(&source, &target, &config);
            let prepared = PreparedTarget::new(&target, None, &PrepareOptions::from_config(&config)).unwrap();
            let before = RegistrationConfig {
                metric: first,
                ..RegistrationConfig::default()
            };
            register_clouds_to(&source, &prepared, None, &before, Hooks::default()).unwrap();
            let after = register_clouds_to(&source, &prepared, None, &config, Hooks::default()).unwrap();
            assert_same(&direct, &after, &format!("{metric:?} after {first:?}"));
        }
    }
}
