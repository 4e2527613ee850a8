//! Where registrations start: `sie_context_set_starts`, `sie_context_set_regularizer` (a fixed
//! initial beta is one run), initial guesses (rigid ones at any magnitude must be accepted,
//! others refused) and `sie_context_set_warm_start` from a fuzzed summary (only its sigma,
//! penalty, noise_shape, inlier_fraction, histogram_count and verdict are read; bad ones
//! refused, a DOUBTFUL or UNSUPPORTED one clears the setting) or a real one; then clouds
//! (`sie_context_register_d`, or onto a prepared target) or correspondences
//! (`sie_context_register_correspondences_d`). The summary must report a search these settings
//! allow.
#![no_main]
use std::ptr::null;

use libfuzzer_sys::fuzz_target;
use sie::ffi::*;

mod common;
use common::*;

const SUMMARY_BYTES: usize = 53;

/// A summary with fuzzed number fields: raw bits, or values near the edges of their ranges.
/// The fields the library must not read hold NaN (or the maximum of their type).
fn summary_from(bytes: &[u8; SUMMARY_BYTES], raw: bool) -> sie_summary {
    let f = |k: usize| f64::from_le_bytes(bytes[8 * k..8 * k + 8].try_into().unwrap());
    let b = |k: usize| bytes[k];
    let mut s = sie_summary {
        beta: [f64::NAN; 3],
        rmse: f64::NAN,
        init_correction: f64::NAN,
        significance: f64::NAN,
        conditioning: f64::NAN,
        sigma_to_spacing: f64::NAN,
        margin: f64::NAN,
        runner_up_significance: f64::NAN,
        source_count: u64::MAX,
        iterations: u32::MAX,
        stop_reason: u32::MAX,
        // NONE, GOOD, DOUBTFUL, UNSUPPORTED, or a value that is none of them.
        verdict: match bytes[52] % 6 {
            v @ 0..=3 => u32::from(v),
            4 => 4,
            _ => u32::MAX,
        },
        start: u32::MAX,
        converged: bytes[51] & 1 != 0,
        ..sie_summary::default()
    };
    if raw {
        s.sigma = [f(0), f(1), f(2)];
        (s.penalty, s.noise_shape, s.inlier_fraction) = (f(3), f(4), f(5));
        s.histogram_count = u32::from_le_bytes(bytes[48..52].try_into().unwrap());
    } else {
        // 2^(4·exponent) times (1 + mantissa/256), 0 for exponent -128.
        let sigma = |k: usize| {
            let exponent = b(2 * k + 1) as i8;
            if exponent == i8::MIN {
                0.0
            } else {
                (1.0 + f64::from(b(2 * k)) / 256.0) * 2f64.powi(4 * i32::from(exponent))
            }
        };
        s.sigma = [sigma(0), sigma(1), sigma(2)];
        s.penalty = 0.5 + f64::from(b(6)) / 16.0;
        s.noise_shape = f64::from(b(7)) / 32.0;
        s.inlier_fraction = f64::from(b(8)) / 200.0;
        s.histogram_count = u32::from(b(9) % 5);
    }
    s
}

fuzz_target!(|data: &[u8]| {
    let Some((&[settings, mode, warm, magnitude, split, regularizer], rest)) = data.split_first_chunk::<6>()
    else {
        return;
    };
    let Some((guess, rest)) = rest.split_first_chunk::<GUESS_BYTES>() else {
        return;
    };
    let guess = Guess::from_bytes(guess);
    let Some((summary_bytes, rest)) = rest.split_first_chunk::<SUMMARY_BYTES>() else {
        return;
    };
    let all = points(rest, magnitude);

    let metric = u32::from(settings & 1);
    let starts = u32::from((settings >> 1) & 1);
    let cost = [0u32, 0, 1, 5][usize::from((settings >> 2) & 3)];
    let histogram_mode = u32::from((settings >> 4) & 1);
    let skip_non_finite = settings & 32 != 0;
    let max_iterations = 1 + u32::from(settings >> 6) * 8;
    // 0: clouds, 1: clouds onto a prepared target, 2 and 3: correspondences.
    let entry = mode & 3;
    let correspondences = entry >= 2;
    let bad_starts = mode & 4 != 0;
    let threads = 1 + u32::from((mode >> 3) & 1);
    let sie = cost == 0;

    // Correspondences pair consecutive points; clouds split them.
    let (source, target): (Vec<[f64; 3]>, Vec<[f64; 3]>) = if correspondences {
        (
            all.iter().step_by(2).copied().collect(),
            all.iter().skip(1).step_by(2).copied().collect(),
        )
    } else {
        let cut = (split as usize * all.len() / 255).clamp(1.min(all.len()), all.len());
        (all[..cut].to_vec(), all[cut..].to_vec())
    };
    let pairs = source.len().min(target.len());

    // SAFETY (the whole block): arrays hold their counts of packed points, outputs are sized
    // for their calls, the context and target are live until freed.
    unsafe {
        let ctx = sie_context_new();
        for status in [
            sie_context_set_metric(ctx, metric),
            sie_context_set_cost_function(ctx, cost, 0.05),
            sie_context_set_histogram_mode(ctx, histogram_mode),
            sie_context_set_skip_non_finite(ctx, skip_non_finite),
            sie_context_set_max_iterations(ctx, max_iterations),
            sie_context_set_threads(ctx, threads),
        ] {
            assert_eq!(status, sie_status::Ok);
        }
        if bad_starts {
            assert_eq!(
                sie_context_set_starts(ctx, 3 + u32::from(split)),
                sie_status::InvalidArgument
            );
            assert!(!last_error(ctx).is_empty());
        }
        assert_eq!(sie_context_set_starts(ctx, starts), sie_status::Ok);

        // A fixed initial beta (one run), or a refused value that leaves the setting alone.
        let mut fixed_beta = false;
        if regularizer != 0 {
            let mut beta =
                [0.0, 1e-3, 0.05, 1.0, 1e3, -1.0, f64::NAN, f64::INFINITY][usize::from(regularizer & 7)];
            if regularizer & 64 != 0 {
                beta *= scale(magnitude);
            }
            let shrink =
                [0.5, 0.9, 0.1, 1e-300, 0.0, 1.0, f64::NAN, 2.0][usize::from((regularizer >> 3) & 7)];
            let valid = beta.is_finite() && beta >= 0.0 && shrink > 0.0 && shrink < 1.0;
            let status = sie_context_set_regularizer(ctx, beta, shrink);
            assert_eq!(
                status == sie_status::Ok,
                valid,
                "beta {beta}, shrink {shrink}: {status:?}"
            );
            if valid {
                fixed_beta = beta != 0.0;
            } else {
                assert_eq!(status, sie_status::InvalidArgument);
                assert!(!last_error(ctx).is_empty());
            }
        }
        let searches = sie && starts == 0 && !fixed_beta;

        // The cloud entries register onto a target prepared by this context (its skips and
        // normal_neighbours), or the clouds themselves.
        let mut prepared = std::ptr::null_mut();
        if entry == 1 {
            let status = sie_context_prepare_target_d(
                ctx,
                target.as_ptr().cast(),
                target.len(),
                0,
                null(),
                0,
                &mut prepared,
            );
            if status != sie_status::Ok {
                assert!(is_registration_error(status), "prepare: {status:?}");
                assert!(prepared.is_null());
                sie_context_free(ctx);
                return;
            }
        }
        let register = |guess: &Guess, warm_applies: bool| {
            let mut out = [UNTOUCHED; 16];
            let status = match entry {
                0 => sie_context_register_d(
                    ctx,
                    source.as_ptr().cast(),
                    source.len(),
                    0,
                    target.as_ptr().cast(),
                    target.len(),
                    0,
                    guess.as_ptr(),
                    out.as_mut_ptr(),
                ),
                1 => sie_context_register_to_d(
                    ctx,
                    source.as_ptr().cast(),
                    source.len(),
                    0,
                    prepared,
                    guess.as_ptr(),
                    out.as_mut_ptr(),
                ),
                _ => sie_context_register_correspondences_d(
                    ctx,
                    source.as_ptr().cast(),
                    0,
                    target.as_ptr().cast(),
                    0,
                    pairs,
                    guess.as_ptr(),
                    out.as_mut_ptr(),
                ),
            };
            let message = last_error(ctx);
            let (n, read) = match entry {
                0 => (
                    source.len(),
                    !source.is_empty()
                        && !target.is_empty()
                        && (skip_non_finite || (finite(&source) && finite(&target))),
                ),
                1 => (
                    source.len(),
                    !source.is_empty() && (skip_non_finite || finite(&source)),
                ),
                _ => (
                    pairs,
                    pairs > 0 && (skip_non_finite || (finite(&source[..pairs]) && finite(&target[..pairs]))),
                ),
            };
            check_guess(guess, status, &message, read);
            if status == sie_status::Ok {
                let expect = Expect {
                    correspondences,
                    searches,
                    warm: warm_applies && !correspondences && sie && !fixed_beta,
                    sie,
                    guess: !matches!(guess, Guess::None),
                    source_count: n,
                    target_count: target.len(),
                };
                Some(check_ok(ctx, &out, &expect))
            } else {
                assert!(is_registration_error(status), "{status:?}: {message}");
                assert!(out.iter().all(|&v| v == UNTOUCHED), "outputs written on error");
                None
            }
        };

        // The warm start: from a real registration's summary and/or a fuzzed one.
        let mut warm_set = false;
        if warm & 2 != 0 {
            if let Some(previous) = register(&Guess::None, false) {
                let status = sie_context_set_warm_start(ctx, &previous);
                // A summary an SIE registration filled is a warm start when its model is in
                // range (a degenerate fit's sigma of 0 is not); a baseline's never.
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
        }
        if warm & 1 != 0 {
            let fuzzed = summary_from(summary_bytes, warm & 4 != 0);
            let status = sie_context_set_warm_start(ctx, &fuzzed);
            let message = last_error(ctx);
            if warm_start_valid(&fuzzed) {
                assert_eq!(status, sie_status::Ok, "{fuzzed:?}: {message}");
                warm_set = warm_start_taken(&fuzzed);
            } else {
                // Refused, saying why; a refused one leaves the previous setting.
                assert_eq!(status, sie_status::InvalidArgument, "{fuzzed:?}");
                assert!(!message.is_empty());
                let read = [fuzzed.penalty, fuzzed.noise_shape, fuzzed.inlier_fraction];
                let read = fuzzed.sigma.iter().chain(&read);
                if message.contains("got inf") || message.contains("got -inf") {
                    assert!(read.clone().any(|v| v.is_infinite()), "{fuzzed:?}: {message}");
                }
                if message.contains("got NaN") {
                    assert!(read.clone().any(|v| v.is_nan()), "{fuzzed:?}: {message}");
                }
                if message.contains("verdict") {
                    assert!(
                        fuzzed.verdict > sie_verdict::Unsupported as u32,
                        "{fuzzed:?}: {message}"
                    );
                }
            }
        }
        if warm & 8 != 0 {
            assert_eq!(sie_context_set_warm_start(ctx, null()), sie_status::Ok);
            warm_set = false;
        }
        let r = register(&guess, warm_set);
        sie_context_free(ctx);
        sie_target_free(prepared);
    }
});
