//! Caller code a registration calls back into: per-point noise scales and the observer of
//! every update, and the wrappers that show the observer the caller's units and shares.

use std::ops::ControlFlow;

use super::result::TraceEntry;
use super::units::Units;
use crate::noise::NoiseScales;

/// Caller code a registration calls back into. `Hooks::default()` uses none.
#[derive(Default)]
pub struct Hooks<'a> {
    /// Per-point noise σ of both clouds (§4.4), called once per cloud; overrides
    /// `RegistrationConfig::noise`.
    pub noise: Option<&'a mut dyn NoiseScales>,
    /// Called after every update with that iteration's trace entry (also when `record_trace`
    /// is off). Returning `ControlFlow::Break(())` stops the registration with
    /// `StopReason::Cancelled` and the transform reached so far.
    pub observer: Option<&'a mut Observer<'a>>,
}

/// Per-iteration callback: `ControlFlow::Break(())` cancels the registration.
pub type Observer<'a> = dyn FnMut(&TraceEntry) -> ControlFlow<()> + 'a;

impl<'a> Hooks<'a> {
    /// Only a noise callback.
    pub fn noise(noise: Option<&'a mut dyn NoiseScales>) -> Self {
        Hooks {
            noise,
            observer: None,
        }
    }

    /// The same callbacks, lent for one more registration.
    pub(crate) fn reborrow(&mut self) -> Hooks<'_> {
        Hooks {
            noise: self.noise.as_deref_mut().map(|n| n as &mut dyn NoiseScales),
            observer: self.observer.as_deref_mut().map(|o| o as &mut Observer<'_>),
        }
    }
}

/// Runs `register` in changed units with an observer that sees every trace entry in the
/// caller's units.
pub(crate) fn in_units<R>(
    units: &Units,
    observer: Option<&mut Observer<'_>>,
    register: impl FnOnce(Option<&mut Observer<'_>>) -> R,
) -> R {
    let Some(outer) = observer else {
        return register(None);
    };
    let mut converted = |entry: &TraceEntry| {
        let mut entry = entry.clone();
        units.entry_out(&mut entry);
        outer(&entry)
    };
    register(Some(&mut converted))
}

/// Runs `register` with `hooks` whose observer sees inlier fractions scaled by `share` (kept
/// / given source points): dropped points count 0, as in the result.
pub(crate) fn with_share<R>(hooks: Hooks<'_>, share: f64, register: impl FnOnce(Hooks<'_>) -> R) -> R {
    let Hooks { noise, observer } = hooks;
    // Coerced to the shorter lifetime of the wrapper below.
    let noise = noise.map(|n| n as &mut dyn NoiseScales);
    let Some(outer) = observer else {
        return register(Hooks {
            noise,
            observer: None,
        });
    };
    let mut scaled = |entry: &TraceEntry| {
        let mut entry = entry.clone();
        entry.inlier_fraction *= share;
        outer(&entry)
    };
    register(Hooks {
        noise,
        observer: Some(&mut scaled),
    })
}
