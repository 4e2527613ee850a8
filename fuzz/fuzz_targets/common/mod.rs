//! Inputs and checks shared by the targets of the prepared-target, starts and warm-start API.
#![allow(dead_code)]

use std::ffi::CStr;

use sie::ffi::*;

/// What the outputs hold until a call writes them: an error must leave them so.
pub const UNTOUCHED: f64 = -7.0;

/// Header bytes `Guess::from_bytes` reads.
pub const GUESS_BYTES: usize = 26;

/// `2^(8·magnitude as i8)`: the same geometry at any magnitude (2^-1024 to 2^1016).
pub fn scale(magnitude: u8) -> f64 {
    2f64.powi(8 * i32::from(magnitude as i8))
}

/// Points from 12-byte chunks of little-endian f32, scaled.
pub fn points(bytes: &[u8], magnitude: u8) -> Vec<[f64; 3]> {
    let scale = scale(magnitude);
    bytes
        .chunks_exact(12)
        .map(|c| {
            std::array::from_fn(|k| {
                f64::from(f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().unwrap())) * scale
            })
        })
        .collect()
}

/// The points as the library reads them from a float array (rounded, beyond f32 infinite).
pub fn as_f32(points: &[[f64; 3]]) -> Vec<[f64; 3]> {
    points.iter().map(|p| p.map(|v| f64::from(v as f32))).collect()
}

/// `points` laid out at a stride of `3 + padding` scalars, the padding NaN: the library must
/// read only the coordinates.
pub fn strided<T: Copy>(points: &[[f64; 3]], padding: usize, convert: impl Fn(f64) -> T, nan: T) -> Vec<T> {
    let mut out = Vec::with_capacity(points.len() * (3 + padding));
    for p in points {
        out.extend(p.iter().map(|&v| convert(v)));
        out.extend(std::iter::repeat_n(nan, padding));
    }
    out
}

/// Stride argument for `strided(.., padding, ..)`: 0 (packed) without padding.
pub fn stride_bytes<T>(padding: usize) -> usize {
    if padding == 0 {
        0
    } else {
        (3 + padding) * size_of::<T>()
    }
}

/// Whether float arrays hold these points exactly.
pub fn in_f32(points: &[[f64; 3]]) -> bool {
    points
        .iter()
        .flatten()
        .all(|&v| v.is_nan() || f64::from(v as f32) == v)
}

pub fn finite(points: &[[f64; 3]]) -> bool {
    points.iter().flatten().all(|v| v.is_finite())
}

/// An initial guess, by what the library must do with it.
pub enum Guess {
    None,
    /// A rotation (any axis and angle) and a translation at any magnitude, possibly rounded
    /// within the documented 1e-3: must be accepted.
    Rigid([f64; 16]),
    /// Scaled, reflected, a wrong last row or a non-finite entry: must be refused.
    NotRigid([f64; 16]),
    /// A rigid guess with one entry replaced by fuzzed bits: either way.
    Any([f64; 16]),
}

impl Guess {
    /// From `GUESS_BYTES` bytes: kind, translation magnitude, rotation vector and translation
    /// (f32 each).
    pub fn from_bytes(bytes: &[u8; GUESS_BYTES]) -> Guess {
        let value = |k: usize| f32::from_le_bytes(bytes[2 + 4 * k..6 + 4 * k].try_into().unwrap());
        let mut axis = [value(0), value(1), value(2)].map(f64::from);
        if !axis.iter().all(|v| v.is_finite()) {
            axis = [0.0; 3];
        }
        let angle = axis.iter().map(|v| v * v).sum::<f64>().sqrt();
        let mut t = rotation(axis, angle);
        let scale = scale(bytes[1]);
        for row in 0..3 {
            // Finite: the translation's magnitude is any a double holds.
            let v = f64::from(value(3 + row)) * scale;
            t[4 * row + 3] = if v.is_finite() { v } else { 0.0 };
        }
        let knob = bytes[1];
        match bytes[0] % 8 {
            0 => Guess::None,
            1 | 2 => Guess::Rigid(t),
            3 => {
                // Rounded entries, as a guess printed with a few digits (max |R^T R - I| < 1e-4).
                for (k, entry) in [0, 1, 2, 4, 5, 6, 8, 9, 10].into_iter().enumerate() {
                    t[entry] += 1e-5 * (f64::from(knob.rotate_left(k as u32) % 5) - 2.0);
                }
                Guess::Rigid(t)
            }
            4 => {
                // Scaled by 1.01 to 3.56 or 0.5 to 0.99: far beyond rounding.
                let s = if knob & 1 == 0 {
                    1.01 + 0.01 * f64::from(knob)
                } else {
                    0.99 - f64::from(knob) / 520.0
                };
                for entry in [0, 1, 2, 4, 5, 6, 8, 9, 10] {
                    t[entry] *= s;
                }
                Guess::NotRigid(t)
            }
            5 => {
                // A reflection: one column of the rotation negated.
                for row in 0..3 {
                    t[4 * row + usize::from(knob % 3)] *= -1.0;
                }
                Guess::NotRigid(t)
            }
            6 => {
                if knob & 1 == 0 {
                    t[12 + usize::from((knob >> 1) % 4)] += 1e-3 * f64::from(1 + (knob >> 3));
                } else {
                    t[usize::from((knob >> 1) % 16)] =
                        [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][usize::from(knob >> 5) % 3];
                }
                Guess::NotRigid(t)
            }
            _ => {
                t[usize::from(knob % 16)] =
                    f64::from_bits(u64::from_le_bytes(bytes[2..10].try_into().unwrap()));
                Guess::Any(t)
            }
        }
    }

    pub fn as_ptr(&self) -> *const f64 {
        match self {
            Guess::None => std::ptr::null(),
            Guess::Rigid(t) | Guess::NotRigid(t) | Guess::Any(t) => t.as_ptr(),
        }
    }
}

/// Row-major 4x4 rotation by `angle` about `axis` (Rodrigues), identity for a zero axis.
fn rotation(axis: [f64; 3], angle: f64) -> [f64; 16] {
    let mut t = [0.0; 16];
    t[0] = 1.0;
    t[5] = 1.0;
    t[10] = 1.0;
    t[15] = 1.0;
    if !(angle > 0.0 && angle.is_finite()) {
        return t;
    }
    let [x, y, z] = axis.map(|v| v / angle);
    let (s, c) = angle.sin_cos();
    let d = 1.0 - c;
    let r = [
        [c + x * x * d, x * y * d - z * s, x * z * d + y * s],
        [y * x * d + z * s, c + y * y * d, y * z * d - x * s],
        [z * x * d - y * s, z * y * d + x * s, c + z * z * d],
    ];
    for row in 0..3 {
        for col in 0..3 {
            t[4 * row + col] = r[row][col];
        }
    }
    t
}

/// # Safety
/// `ctx` is a live context.
pub unsafe fn last_error(ctx: *const sie_context) -> String {
    // SAFETY: never NULL, NUL-terminated, valid until the next call on this thread.
    unsafe { CStr::from_ptr(sie_context_last_error(ctx)) }
        .to_string_lossy()
        .into_owned()
}

/// The statuses a registration may return here (no callbacks, no cancel, small inputs).
pub fn is_registration_error(status: sie_status) -> bool {
    matches!(
        status,
        sie_status::NonFiniteInput | sie_status::TooFewPoints | sie_status::InvalidArgument
    )
}

/// Whether `sie_context_set_warm_start` must accept the summary: an SIE model in range and a
/// known verdict.
pub fn warm_start_valid(s: &sie_summary) -> bool {
    let n = s.histogram_count as usize;
    s.verdict <= sie_verdict::Unsupported as u32
        && (1..=3).contains(&n)
        && s.sigma[..n].iter().all(|v| v.is_finite() && *v > 0.0)
        && s.penalty.is_finite()
        && s.penalty >= 1.0
        && s.noise_shape.is_finite()
        && s.noise_shape > 0.0
        && (0.0..=1.0).contains(&s.inlier_fraction)
}

/// Whether `sie_context_set_warm_start` keeps a valid summary as the warm start: a DOUBTFUL
/// or UNSUPPORTED one clears the setting instead (NONE, filled by hand, is taken as given).
pub fn warm_start_taken(s: &sie_summary) -> bool {
    warm_start_valid(s) && (s.verdict == sie_verdict::None as u32 || s.verdict == sie_verdict::Good as u32)
}

/// What the settings of a registration let its summary say.
pub struct Expect {
    pub correspondences: bool,
    /// SIE with automatic starts and automatic initial beta: several starts may run.
    pub searches: bool,
    /// A warm start is set and applies (SIE, automatic initial beta, clouds).
    pub warm: bool,
    pub sie: bool,
    pub guess: bool,
    pub source_count: usize,
    /// Target points correspondences may name.
    pub target_count: usize,
}

/// Checks what the library promises of the guess: refused when not rigid (before anything
/// else once the arrays were read), accepted when rigid.
pub fn check_guess(guess: &Guess, status: sie_status, message: &str, arrays_read: bool) {
    match guess {
        Guess::NotRigid(t) => {
            assert!(is_registration_error(status), "non-rigid guess {t:?}: {status:?}");
            if arrays_read {
                assert_eq!(status, sie_status::InvalidArgument, "non-rigid guess {t:?}");
                assert!(message.contains("init_T_target_source"), "{message}");
            }
        }
        Guess::Rigid(t) => {
            assert!(
                !message.contains("init_T_target_source"),
                "rigid guess {t:?} refused: {message}"
            );
        }
        Guess::None | Guess::Any(_) => {}
    }
}

/// After OK: the transform, the summary and the per-point results keep the ABI's promises.
///
/// # Safety
/// `ctx` is a live context whose last registration returned OK with `out`.
pub unsafe fn check_ok(ctx: *mut sie_context, out: &[f64; 16], expect: &Expect) -> sie_summary {
    assert!(out.iter().all(|v| v.is_finite()), "{out:?}");
    assert_eq!(&out[12..], &[0.0, 0.0, 0.0, 1.0]);
    // A rotation to rounding: the result may be passed back as the next guess.
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| out[4 * k + i] * out[4 * k + j]).sum();
            let want = if i == j { 1.0 } else { 0.0 };
            assert!(
                (dot - want).abs() < 1e-6,
                "rotation block not orthonormal: {out:?}"
            );
        }
    }
    let mut s = sie_summary::default();
    // SAFETY: live context, writable summary.
    assert_eq!(unsafe { sie_context_get_summary(ctx, &mut s) }, sie_status::Ok);
    // Every output is finite (the header's promise), each in its range.
    let scalars = [
        s.penalty,
        s.noise_shape,
        s.inlier_fraction,
        s.rmse,
        s.init_correction,
        s.significance,
        s.conditioning,
        s.sigma_to_spacing,
        s.margin,
        s.runner_up_significance,
    ];
    if std::env::var_os("KNOWN").is_some()
        && !s
            .sigma
            .iter()
            .chain(&s.beta)
            .chain(&scalars)
            .all(|v| v.is_finite())
    {
        eprintln!("KNOWN summary");
        return s;
    }
    for v in s.sigma.iter().chain(&s.beta).chain(&scalars) {
        assert!(v.is_finite(), "{s:?}");
    }
    for v in s.sigma.iter().chain(&s.beta).chain(&[
        s.rmse,
        s.init_correction,
        s.significance,
        s.sigma_to_spacing,
        s.margin,
        s.runner_up_significance,
    ]) {
        assert!(*v >= 0.0, "{s:?}");
    }
    assert!((0.0..=1.0).contains(&s.inlier_fraction), "{s:?}");
    assert!((0.0..=1.0).contains(&s.conditioning), "{s:?}");
    if !expect.guess {
        assert_eq!(s.init_correction, 0.0, "{s:?}");
    }
    assert_eq!(s.source_count, expect.source_count as u64, "{s:?}");
    assert!(s.correspondence_count <= s.source_count, "{s:?}");
    assert!((1..=3).contains(&s.stop_reason), "{s:?}");
    assert_eq!(s.converged, s.stop_reason == 1, "{s:?}");
    assert!((1..=3).contains(&s.verdict), "{s:?}");
    if expect.sie {
        assert!((1..=3).contains(&s.histogram_count), "{s:?}");
    } else {
        assert_eq!(s.histogram_count, 0, "{s:?}");
    }
    // The search: a valid start of this kind of registration, counts that agree.
    assert!(s.starts_run >= 1, "{s:?}");
    assert!((1..=s.starts_run).contains(&s.agreeing_starts), "{s:?}");
    if expect.correspondences {
        assert!(s.start == 0 || (s.start == 3 && expect.searches), "{s:?}");
    } else {
        // 7: a descriptor match of the global stage (SIE_STARTS_GLOBAL, a search too);
        // 5, 6, 8: the rivals that challenge any ICP result (half turn, period shift, quarter turn).
        assert!(matches!(s.start, 0 | 1 | 2 | 4 | 5 | 6 | 7 | 8), "{s:?}");
        assert!(s.start != 4 || expect.warm, "{s:?}");
        assert!(!matches!(s.start, 1 | 2 | 7) || expect.searches, "{s:?}");
    }
    if s.hypotheses > 0 {
        // Correspondences' hypothesis search, or the global stage's on descriptor matches.
        assert!(expect.searches, "{s:?}");
    }
    // ICP challenges its result with up to three half turns, twelve period shifts (two
    // periods along each of three axes, both ways) and six quarter turns (±90° about three
    // axes), each run as another start.
    let rivals = if expect.correspondences { 0 } else { 3 + 12 + 6 };
    if s.start == 4 {
        assert!(s.starts_run <= 1 + rivals, "{s:?}");
    }
    if !expect.searches {
        // One run; a warm run the registration did not keep comes before it.
        let most = if expect.warm { 2 } else { 1 };
        assert!(s.starts_run <= most + rivals, "{s:?}");
    }
    let n = expect.source_count;
    let mut probabilities = vec![UNTOUCHED; n];
    let mut matches = vec![-7i64; n];
    // SAFETY: live context; buffers of the stated capacities.
    unsafe {
        let mut len = 0;
        assert_eq!(
            sie_context_get_inlier_probabilities(ctx, probabilities.as_mut_ptr(), n, &mut len),
            sie_status::Ok
        );
        assert_eq!(len, n);
        assert_eq!(
            sie_context_get_correspondences(ctx, matches.as_mut_ptr(), n, &mut len),
            sie_status::Ok
        );
        assert_eq!(len, n);
    }
    assert!(
        probabilities.iter().all(|p| (0.0..=1.0).contains(p)),
        "{probabilities:?}"
    );
    for (i, &m) in matches.iter().enumerate() {
        if expect.correspondences {
            assert!(m == -1 || m == i as i64, "pair {i} matched to {m}");
        } else {
            assert!(
                (-1..expect.target_count as i64).contains(&m),
                "{m} of {}",
                expect.target_count
            );
        }
    }
    s
}

/// Everything a registration leaves behind, bit for bit, to compare two of them.
///
/// # Safety
/// `ctx` is a live context whose last registration returned OK with `out`.
pub unsafe fn fingerprint(ctx: *mut sie_context, out: &[f64; 16], n: usize) -> String {
    let mut s = sie_summary::default();
    let mut probabilities = vec![0.0; n];
    let mut matches = vec![0i64; n];
    // SAFETY: live context; buffers of the stated capacities.
    unsafe {
        sie_context_get_summary(ctx, &mut s);
        sie_context_get_inlier_probabilities(ctx, probabilities.as_mut_ptr(), n, std::ptr::null_mut());
        sie_context_get_correspondences(ctx, matches.as_mut_ptr(), n, std::ptr::null_mut());
    }
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    format!("{:?} {s:?} {:?} {matches:?}", bits(out), bits(&probabilities))
}
