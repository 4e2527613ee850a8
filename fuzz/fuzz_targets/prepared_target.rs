//! Prepared targets (`sie_context_prepare_target[_d]`, `sie_target_*`,
//! `sie_context_register_to[_d]`): any points, optional normals at their own stride, prepared
//! with one context's settings (freed right after), registered onto twice by another context.
//! The second registration must be the one a fresh `sie_context_register_d` (or
//! `_with_normals`) gives on the same arrays, bit for bit, whatever the first did to the
//! target; a `normal_neighbours` other than the target's must be refused for point-to-plane.
#![no_main]
use std::ptr::{NonNull, null, null_mut};

use libfuzzer_sys::fuzz_target;
use sie::ffi::*;

mod common;
use common::*;

/// Unit normals from the points' directions (0 0 0 at the origin, NaN where not finite).
fn normals_of(points: &[[f64; 3]]) -> Vec<[f64; 3]> {
    points
        .iter()
        .map(|p| {
            // Scaled first: the squares of large coordinates overflow.
            let largest = p.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if largest == 0.0 {
                return [0.0; 3];
            }
            let q = p.map(|v| v / largest);
            let length = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            q.map(|v| v / length)
        })
        .collect()
}

fuzz_target!(|data: &[u8]| {
    let Some((&[prep, reg, order, magnitude, split, neighbours], rest)) = data.split_first_chunk::<6>()
    else {
        return;
    };
    let Some((guess, rest)) = rest.split_first_chunk::<GUESS_BYTES>() else {
        return;
    };
    let guess = Guess::from_bytes(guess);
    let all = points(rest, magnitude);
    let cut = (split as usize * all.len() / 255).clamp(1.min(all.len()), all.len());
    let (source, target) = all.split_at(cut);

    // The target's preparation.
    let target_f64 = prep & 1 != 0;
    let with_normals = prep & 2 != 0;
    let (skip_non_finite, skip_origin) = (prep & 4 != 0, prep & 8 != 0);
    let point_padding = usize::from((prep >> 4) & 3);
    let normal_padding = usize::from(prep >> 6);
    let prepare_neighbours = 3 + u32::from(neighbours & 31);
    // The registering context.
    let metric = u32::from(reg & 1);
    let source_f64 = reg & 2 != 0;
    // Skip settings other than the target's: allowed (the target's stay), not comparable.
    let other_skip = reg & 4 != 0;
    let threads = 1 + u32::from((reg >> 3) & 1);
    let cost = u32::from((reg >> 4) & 3);
    let starts = u32::from((reg >> 6) & 1);
    let mismatch = reg & 128 != 0;
    let register_neighbours = prepare_neighbours
        + if mismatch {
            1 + u32::from(neighbours >> 5)
        } else {
            0
        };
    // What happens between.
    let first_metric = metric ^ u32::from(order & 1);
    let first_half = order & 2 != 0;
    let estimate = order & 4 != 0;
    let warm = order & 8 != 0;
    let max_iterations = if order & 128 != 0 { 20 } else { 3 };

    // What the library reads.
    let target_seen = if target_f64 {
        target.to_vec()
    } else {
        as_f32(target)
    };
    // Rounded to float for either precision: `_with_normals` takes floats.
    let mut normals = as_f32(&normals_of(&target_seen));
    if order & 16 != 0 {
        normals.iter_mut().step_by(3).for_each(|n| *n = [0.0; 3]);
    }
    if order & 32 != 0 {
        if let Some(n) = normals.first_mut() {
            *n = n.map(|v| v * 0.5);
        }
    }
    if order & 64 != 0 {
        if let Some(n) = normals.last_mut() {
            n[1] = f64::NAN;
        }
    }
    let source_seen = if source_f64 {
        source.to_vec()
    } else {
        as_f32(source)
    };

    // Expected of the preparation, as documented.
    let kept = |p: &[f64; 3]| {
        (!skip_non_finite || p.iter().all(|v| v.is_finite())) && !(skip_origin && *p == [0.0; 3])
    };
    let kept_count = target_seen.iter().filter(|p| kept(p)).count();
    let normals_ok = !with_normals
        || normals.iter().all(|n| {
            let length = n.iter().map(|v| v * v).sum::<f64>().sqrt();
            if n.iter().all(|v| v.is_finite()) {
                length == 0.0 || (length - 1.0).abs() <= 1e-3
            } else {
                skip_non_finite
            }
        });
    let prepare_ok = kept_count >= 3 && (skip_non_finite || finite(&target_seen)) && normals_ok;
    // Point-to-plane has no normal to work with (the kept points' given normals are all 0 0 0).
    let no_normal = with_normals
        && target_seen
            .iter()
            .zip(&normals)
            .filter(|(p, _)| kept(p))
            .all(|(_, n)| *n == [0.0; 3] || !n.iter().all(|v| v.is_finite()));

    // SAFETY (the whole block): every array holds its count of points at its stride; outputs
    // are sized for their calls; contexts and the target are live until freed.
    unsafe {
        assert_eq!(sie_target_point_count(null()), 0);
        assert_eq!(sie_target_estimate_normals(null(), 1), sie_status::NullArgument);
        sie_target_free(null_mut());

        let preparing = sie_context_new();
        assert_eq!(
            sie_context_set_skip_non_finite(preparing, skip_non_finite),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_set_skip_origin(preparing, skip_origin),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_set_normal_neighbours(preparing, prepare_neighbours),
            sie_status::Ok
        );
        let untouched = NonNull::<sie_target>::dangling().as_ptr();
        let mut handle = untouched;
        let status = if target_f64 {
            let xyz = strided(&target_seen, point_padding, |v| v, f64::NAN);
            let n = strided(&normals, normal_padding, |v| v, f64::NAN);
            sie_context_prepare_target_d(
                preparing,
                xyz.as_ptr(),
                target.len(),
                stride_bytes::<f64>(point_padding),
                if with_normals { n.as_ptr() } else { null() },
                stride_bytes::<f64>(normal_padding),
                &mut handle,
            )
        } else {
            let xyz = strided(&target_seen, point_padding, |v| v as f32, f32::NAN);
            let n = strided(&normals, normal_padding, |v| v as f32, f32::NAN);
            sie_context_prepare_target(
                preparing,
                xyz.as_ptr(),
                target.len(),
                stride_bytes::<f32>(point_padding),
                if with_normals { n.as_ptr() } else { null() },
                stride_bytes::<f32>(normal_padding),
                &mut handle,
            )
        };
        // The arrays are gone (the target holds a copy); so is the context that lent its settings.
        let message = last_error(preparing);
        sie_context_free(preparing);
        if status != sie_status::Ok {
            assert!(is_registration_error(status), "prepare: {status:?}");
            assert_eq!(handle, untouched, "out_target written on error");
            assert!(
                !prepare_ok,
                "prepare refused a valid target: {status:?} {message}"
            );
            return;
        }
        assert!(prepare_ok, "prepare accepted an invalid target");
        assert!(!handle.is_null() && handle != untouched);
        assert_eq!(sie_target_point_count(handle), target.len());

        let ctx = sie_context_new();
        let configure = |ctx: *mut sie_context, skip: bool| {
            assert_eq!(
                sie_context_set_skip_non_finite(ctx, skip_non_finite ^ skip),
                sie_status::Ok
            );
            assert_eq!(sie_context_set_skip_origin(ctx, skip_origin), sie_status::Ok);
            assert_eq!(
                sie_context_set_normal_neighbours(ctx, register_neighbours),
                sie_status::Ok
            );
            assert_eq!(sie_context_set_threads(ctx, threads), sie_status::Ok);
            assert_eq!(sie_context_set_cost_function(ctx, cost, 0.05), sie_status::Ok);
            assert_eq!(sie_context_set_starts(ctx, starts), sie_status::Ok);
            assert_eq!(
                sie_context_set_max_iterations(ctx, max_iterations),
                sie_status::Ok
            );
        };
        configure(ctx, other_skip);
        let register_skips_non_finite = skip_non_finite ^ other_skip;
        let sie = cost == 0;
        let mut warm_set = false;
        // One registration onto the target, checked; returns its status and transform.
        let register = |source: &[[f64; 3]], metric: u32, guess: &Guess, warm: bool| {
            assert_eq!(sie_context_set_metric(ctx, metric), sie_status::Ok);
            let mut out = [UNTOUCHED; 16];
            let status = if source_f64 {
                let xyz = strided(source, point_padding, |v| v, f64::NAN);
                let stride = stride_bytes::<f64>(point_padding);
                sie_context_register_to_d(
                    ctx,
                    xyz.as_ptr(),
                    source.len(),
                    stride,
                    handle,
                    guess.as_ptr(),
                    out.as_mut_ptr(),
                )
            } else {
                let xyz = strided(source, point_padding, |v| v as f32, f32::NAN);
                let stride = stride_bytes::<f32>(point_padding);
                sie_context_register_to(
                    ctx,
                    xyz.as_ptr(),
                    source.len(),
                    stride,
                    handle,
                    guess.as_ptr(),
                    out.as_mut_ptr(),
                )
            };
            let message = last_error(ctx);
            let source_read = !source.is_empty() && (register_skips_non_finite || finite(source));
            check_guess(guess, status, &message, source_read);
            let plane = metric == 1;
            if plane && no_normal {
                assert_ne!(status, sie_status::Ok, "point-to-plane without a normal");
            }
            if plane && mismatch && !with_normals {
                assert_ne!(status, sie_status::Ok, "normal_neighbours mismatch accepted");
                if source_read && !matches!(guess, Guess::NotRigid(_) | Guess::Any(_)) {
                    assert_eq!(status, sie_status::InvalidArgument, "{message}");
                    assert!(message.contains("normal_neighbours"), "{message}");
                }
            }
            if status == sie_status::Ok {
                let expect = Expect {
                    correspondences: false,
                    searches: sie && starts == 0,
                    warm: warm && sie,
                    sie,
                    guess: !matches!(guess, Guess::None),
                    source_count: source.len(),
                    target_count: target.len(),
                };
                check_ok(ctx, &out, &expect);
            } else {
                assert!(is_registration_error(status), "{status:?}: {message}");
                assert!(out.iter().all(|&v| v == UNTOUCHED), "outputs written on error");
            }
            (status, out)
        };

        let first_source = if first_half {
            &source_seen[..source_seen.len() / 2]
        } else {
            &source_seen[..]
        };
        let (first, _) = register(first_source, first_metric, &Guess::None, false);
        let mut previous = sie_summary::default();
        if first == sie_status::Ok && warm {
            assert_eq!(sie_context_get_summary(ctx, &mut previous), sie_status::Ok);
            // A summary an SIE registration filled is a warm start when its model is in range
            // (a degenerate fit's sigma of 0 is not); a baseline's never.
            let status = sie_context_set_warm_start(ctx, &previous);
            let valid = sie && warm_start_valid(&previous);
            assert_eq!(
                status,
                if valid {
                    sie_status::Ok
                } else {
                    sie_status::InvalidArgument
                },
                "{previous:?}"
            );
            warm_set = status == sie_status::Ok && warm_start_taken(&previous);
        }
        if estimate {
            assert_eq!(sie_target_estimate_normals(handle, threads), sie_status::Ok);
            assert_eq!(
                sie_target_estimate_normals(handle, 1025),
                sie_status::InvalidArgument
            );
        }
        let (second, out) = register(&source_seen, metric, &guess, warm_set);
        let second_fingerprint = (second == sie_status::Ok).then(|| fingerprint(ctx, &out, source.len()));
        sie_context_free(ctx);

        // The same registration without the target: on the same context settings (the target's
        // skips), the same arrays as the library read them.
        let comparable = !other_skip
            && if with_normals {
                in_f32(&source_seen) && in_f32(&target_seen)
            } else {
                !(mismatch && metric == 1)
            };
        if comparable {
            let fresh = sie_context_new();
            configure(fresh, false);
            assert_eq!(sie_context_set_metric(fresh, metric), sie_status::Ok);
            if warm_set {
                assert_eq!(sie_context_set_warm_start(fresh, &previous), sie_status::Ok);
            }
            let mut again = [UNTOUCHED; 16];
            let status = if with_normals {
                let to_f32 = |points: &[[f64; 3]]| strided(points, 0, |v| v as f32, f32::NAN);
                let (s, t, n) = (to_f32(&source_seen), to_f32(&target_seen), to_f32(&normals));
                sie_context_register_with_normals(
                    fresh,
                    s.as_ptr(),
                    source.len(),
                    0,
                    t.as_ptr(),
                    target.len(),
                    0,
                    n.as_ptr(),
                    0,
                    guess.as_ptr(),
                    again.as_mut_ptr(),
                )
            } else {
                sie_context_register_d(
                    fresh,
                    source_seen.as_ptr().cast(),
                    source.len(),
                    0,
                    target_seen.as_ptr().cast(),
                    target.len(),
                    0,
                    guess.as_ptr(),
                    again.as_mut_ptr(),
                )
            };
            // Errors may come in another order; success may not differ.
            assert_eq!(
                status == sie_status::Ok,
                second == sie_status::Ok,
                "prepared {second:?}, fresh {status:?}"
            );
            if let Some(expected) = second_fingerprint {
                assert_eq!(
                    fingerprint(fresh, &again, source.len()),
                    expected,
                    "not the fresh registration's result"
                );
            }
            sie_context_free(fresh);
        }
        sie_target_free(handle);
    }
});
