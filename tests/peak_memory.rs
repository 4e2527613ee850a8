//! The working-set bounds of `sie::memory` (asked for before a registration starts, so that a
//! memory limit gives OUT_OF_MEMORY instead of an abort part-way) against the peak heap the
//! registrations really reach, counted at the allocator.
//!
//! One test in this binary on purpose: the count covers every thread of the process.
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::Matrix4;
use sie::memory::{
    cloud_registration_bytes, correspondence_registration_bytes, estimate_bytes, prepared_registration_bytes,
    prepared_target_bytes, target_normals_bytes,
};
use sie::nn::NearestNeighbours;
use sie::normals::estimate_normals_at_data_scale;
use sie::parallel::Workers;
use sie::synthetic::{paper_simulation, room_scene};
use sie::{
    Hooks, Metric, NoiseModel, NonFinite, Point, PrepareOptions, PreparedTarget, RegistrationConfig,
    SieOptions, estimate_inliers, register_clouds, register_clouds_to, register_correspondences,
};

struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
/// The size of the up-front probe of the call being measured (`sie::memory::ensure_available`
/// asks for the whole bound at once and frees it): not the work's own memory, so not counted.
static PROBE: AtomicUsize = AtomicUsize::new(usize::MAX);

fn is_probe(layout: Layout) -> bool {
    layout.align() == 1 && layout.size() == PROBE.load(Ordering::Relaxed)
}

fn grew(bytes: usize) {
    let now = LIVE.fetch_add(bytes, Ordering::Relaxed) + bytes;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

// SAFETY: forwards to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let ptr = unsafe { System.alloc(layout) };
        if !ptr.is_null() && !is_probe(layout) {
            grew(layout.size());
        }
        ptr
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) };
        if !is_probe(layout) {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let new = unsafe { System.realloc(ptr, layout, new_size) };
        if !new.is_null() {
            // Both blocks exist while the contents move.
            grew(new_size);
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        new
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Heap bytes `work` allocates at its peak beyond what was live before it, but for its
/// up-front probe of `bound` bytes.
fn peak_of(bound: usize, work: impl FnOnce()) -> usize {
    PROBE.store(bound, Ordering::Relaxed);
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    work();
    PROBE.store(usize::MAX, Ordering::Relaxed);
    PEAK.load(Ordering::Relaxed) - base
}

/// A flat grid of points (a second shape next to the room: many unmatched points).
fn grid(n: usize, shift: f64) -> Vec<Point> {
    (0..n)
        .map(|i| [(i % 500) as f64 * 0.01 + shift, (i / 500) as f64 * 0.01, 0.0])
        .collect()
}

#[test]
fn working_set_bounds_cover_the_measured_peaks() {
    let scene = room_scene(60_000, 0.01, 1);
    let (grid_source, grid_target) = (grid(60_000, 0.002), grid(60_000, 0.0));
    let (mut worst, mut worst_prepared) = (0.0f64, 0.0f64);
    for (shape, source, target) in [
        ("room", &scene.source, &scene.target),
        ("grid", &grid_source, &grid_target),
    ] {
        for metric in [Metric::PointToPlane, Metric::PointToPoint] {
            // Skipping non-finite points copies the clouds once more: the larger case.
            for non_finite in [NonFinite::Skip] {
                // Per-point noise scales (the depth model here, a callback alike) add two
                // arrays of σ.
                let config = RegistrationConfig {
                    metric,
                    non_finite,
                    record_trace: true,
                    noise: NoiseModel::QuadraticDepth,
                    ..RegistrationConfig::default()
                };
                // Equal sizes, and each cloud ten times the other, so neither per-point
                // coefficient can hide behind the other.
                for (ns, nt) in [(60_000, 60_000), (60_000, 6_000), (6_000, 60_000)] {
                    let (source, target) = (&source[..ns], &target[..nt]);
                    let bound = cloud_registration_bytes(ns, nt);
                    let peak = peak_of(bound, || {
                        let result = register_clouds(source, target, None, None, &config, Hooks::default());
                        drop(result.unwrap());
                    });
                    let use_of_bound = peak as f64 / bound as f64;
                    println!(
                        "{shape} {metric:?} {non_finite:?}, {ns} + {nt} points: peak {peak} B, bound {bound} B ({:.0} %)",
                        100.0 * use_of_bound
                    );
                    assert!(peak <= bound, "{shape} {metric:?} {ns}+{nt}: {peak} > {bound}");
                    worst = worst.max(use_of_bound);

                    // Onto a target prepared beforehand (its normals not estimated yet): the
                    // registration's own peak, with point-to-plane the normals it sets up (12 B
                    // a target point) and those it estimates.
                    let prepared =
                        PreparedTarget::new(target, None, &PrepareOptions::from_config(&config)).unwrap();
                    let bound = prepared_registration_bytes(ns, nt);
                    let peak = peak_of(bound, || {
                        let result = register_clouds_to(source, &prepared, None, &config, Hooks::default());
                        drop(result.unwrap());
                    });
                    let use_of_bound = peak as f64 / bound as f64;
                    println!(
                        "  onto the prepared target: peak {peak} B, bound {bound} B ({:.0} %)",
                        100.0 * use_of_bound
                    );
                    assert!(
                        peak <= bound,
                        "prepared {shape} {metric:?} {ns}+{nt}: {peak} > {bound}"
                    );
                    worst_prepared = worst_prepared.max(use_of_bound);
                }
            }
        }
    }
    // Not so loose that it refuses registrations that would fit.
    assert!(
        worst > 0.6 && worst_prepared > 0.6,
        "the tightest case uses only {:.0} % of its bound ({:.0} % onto a prepared target)",
        100.0 * worst,
        100.0 * worst_prepared
    );

    let data = paper_simulation(50_000, 50_000, 0.01, &Matrix4::identity(), 1);
    let pairs = data.source.len();
    let peak = peak_of(correspondence_registration_bytes(pairs), || {
        let result = register_correspondences(
            &data.source,
            &data.target,
            None,
            &RegistrationConfig::default(),
            Hooks::default(),
        );
        drop(result.unwrap());
    });
    println!(
        "{pairs} pairs: peak {peak} B, bound {}",
        correspondence_registration_bytes(pairs)
    );
    assert!(peak <= correspondence_registration_bytes(pairs));
    assert!(peak as f64 > 0.5 * (correspondence_registration_bytes(pairs) - (8 << 20)) as f64);

    let residuals: Vec<f64> = (0..300_000)
        .map(|i| ((i * 7919) % 1000) as f64 * 1e-3 - 0.5)
        .collect();
    let peak = peak_of(estimate_bytes(residuals.len()), || {
        let estimate = estimate_inliers(&residuals, 3, None, 0.0, &SieOptions::default());
        drop(estimate.unwrap());
    });
    println!(
        "{} residuals: peak {peak} B, bound {}",
        residuals.len(),
        estimate_bytes(residuals.len())
    );
    assert!(peak <= estimate_bytes(residuals.len()));

    preparing_targets(&scene.target, &grid_target);
    estimating_all_normals();
}

/// `cloud` in the shape that costs `PreparedTarget::new` most: every 7th point NaN (skipped:
/// a copy of the kept points), every 5th an exact copy of the one before (the kd-tree's
/// duplicate table) and all of it beyond the safe range (a copy in other units); normals
/// [0, 0, 1], NaN at the NaN points.
fn costly_target(cloud: &[Point]) -> (Vec<Point>, Vec<Point>) {
    let mut points: Vec<Point> = cloud.iter().map(|p| p.map(|c| c * 1e40)).collect();
    let mut normals = vec![[0.0, 0.0, 1.0]; points.len()];
    for i in 1..points.len() {
        if i % 7 == 0 {
            points[i] = [f64::NAN; 3];
            normals[i] = [f64::NAN; 3];
        } else if i % 5 == 0 {
            points[i] = points[i - 1];
        }
    }
    (points, normals)
}

/// `prepared_target_bytes` against the peak of `PreparedTarget::new`, with and without given
/// normals, as given and in its costliest shape.
fn preparing_targets(room: &[Point], grid: &[Point]) {
    let mut worst = 0.0f64;
    for (shape, cloud) in [("room", room), ("grid", grid)] {
        let (costly, costly_normals) = costly_target(cloud);
        let plain_normals = vec![[0.0, 0.0, 1.0]; cloud.len()];
        for (variant, points, normals, non_finite) in [
            ("as given", cloud, &plain_normals, NonFinite::Reject),
            (
                "skipped, duplicated, far",
                &costly[..],
                &costly_normals,
                NonFinite::Skip,
            ),
        ] {
            for (n, with_normals) in [(6_000, false), (60_000, false), (6_000, true), (60_000, true)] {
                let (points, normals) = (&points[..n], &normals[..n]);
                let options = PrepareOptions {
                    non_finite,
                    ..PrepareOptions::default()
                };
                let given = with_normals.then_some(normals);
                let bound = prepared_target_bytes(points.len(), with_normals);
                let peak = peak_of(bound, || {
                    drop(PreparedTarget::new(points, given, &options).unwrap());
                });
                let use_of_bound = peak as f64 / bound as f64;
                println!(
                    "prepare {shape} {variant}, normals {with_normals}, {} points: peak {peak} B ({:.1} B a point), \
                     bound {bound} B ({:.0} %)",
                    points.len(),
                    peak as f64 / points.len() as f64,
                    100.0 * use_of_bound
                );
                assert!(
                    peak <= bound,
                    "prepare {shape} {variant} {n} {with_normals}: {peak} > {bound}"
                );
                worst = worst.max(use_of_bound);
            }
        }
    }
    assert!(
        worst > 0.6,
        "the tightest target uses only {:.0} % of its bound",
        100.0 * worst
    );
}

/// A 4 m × 4 m plane of `n` points with ±`noise` (hashed, uniform): dense enough for its normals
/// to come from a thinned copy.
fn noisy_plane(n: usize, noise: f64) -> Vec<Point> {
    // splitmix64's finaliser: a well-mixed hash of the index.
    let unit = |i: usize, salt: u64| {
        let mut x = (i as u64) ^ (salt << 40);
        x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        (x ^ (x >> 31)) as f64 / u64::MAX as f64
    };
    (0..n)
        .map(|i| {
            [
                4.0 * unit(i, 1),
                4.0 * unit(i, 2),
                noise * (2.0 * unit(i, 3) - 1.0),
            ]
        })
        .collect()
}

/// `target_normals_bytes` against the peak of `estimate_all_normals` on targets whose normals
/// are not set up yet, thinned (the room, the noisy plane) or not (the grid), each several
/// times the block the normals are estimated in.
fn estimating_all_normals() {
    const N: usize = 400_000;
    let room = room_scene(N, 0.01, 1).target;
    let (grid, plane, noisier) = (grid(N, 0.0), noisy_plane(N, 0.0035), noisy_plane(N, 0.02));
    let mut worst = 0.0f64;
    let mut thinned = false;
    for (shape, cloud) in [
        ("room", &room),
        ("grid", &grid),
        ("plane, 3.5 mm noise", &plane),
        ("plane, 2 cm noise", &noisier),
    ] {
        let workers = Workers::new(2).unwrap();
        let (_, factor) =
            estimate_normals_at_data_scale(cloud, &NearestNeighbours::new(cloud).unwrap(), 10, &workers);
        thinned |= factor > 1;
        let target = PreparedTarget::new(cloud, None, &PrepareOptions::default()).unwrap();
        let bound = target_normals_bytes(cloud.len());
        let peak = peak_of(bound, || {
            target.estimate_all_normals(2).unwrap();
        });
        let use_of_bound = peak as f64 / bound as f64;
        println!(
            "normals of {shape} ({} points, thinning 1 in {factor}): peak {peak} B ({:.1} B a point), bound {bound} B \
             ({:.0} %)",
            cloud.len(),
            peak as f64 / cloud.len() as f64,
            100.0 * use_of_bound
        );
        assert!(peak <= bound, "normals of {shape}: {peak} > {bound}");
        worst = worst.max(use_of_bound);
        // Once estimated, a second call asks for (and needs) no more than a block's memory.
        let again = peak_of(target_normals_bytes(0), || {
            target.estimate_all_normals(2).unwrap();
        });
        assert!(
            again <= target_normals_bytes(0),
            "normals of {shape} again: {again}"
        );
    }
    assert!(
        thinned,
        "no target was thinned: the thinned copies are not measured"
    );
    assert!(
        worst > 0.6,
        "the tightest normals use only {:.0} % of their bound",
        100.0 * worst
    );
}
