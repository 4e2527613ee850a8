//! The panic/error boundary every exported function runs its body in, and the error type the
//! bodies return.

use std::any::Any;
use std::ffi::CStr;
use std::panic::{AssertUnwindSafe, catch_unwind};

use super::{sie_context, sie_status};
use crate::error::Error;

/// Why a call failed: the status returned to C and the message stored in `last_error`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct FfiError {
    pub(crate) status: sie_status,
    pub(crate) message: String,
}

impl FfiError {
    pub(crate) fn new(status: sie_status, message: impl Into<String>) -> Self {
        FfiError {
            status,
            message: message.into(),
        }
    }

    pub(crate) fn null(argument: &str) -> Self {
        Self::new(sie_status::NullArgument, format!("{argument} is NULL"))
    }

    pub(crate) fn invalid(message: impl Into<String>) -> Self {
        Self::new(sie_status::InvalidArgument, message)
    }

    pub(crate) fn busy() -> Self {
        Self::new(
            sie_status::Busy,
            "the context is busy: a registration on it is still running (call from inside its noise callback?)",
        )
    }
}

impl From<Error> for FfiError {
    fn from(error: Error) -> Self {
        let status = match &error {
            Error::InvalidArgument(_) => sie_status::InvalidArgument,
            Error::NonFinite(_) => sie_status::NonFiniteInput,
            Error::TooFewPoints(_) => sie_status::TooFewPoints,
            Error::Callback(_) => sie_status::CallbackFailed,
        };
        FfiError::new(status, error.to_string())
    }
}

/// Runs `body` on a context: no context -> NULL_ARGUMENT; a panic -> PANIC with its message, and
/// the stored result dropped (it may be half-updated); an error -> its status and message;
/// success clears the message.
pub(crate) fn boundary(
    context: Option<&sie_context>,
    body: impl FnOnce(&sie_context) -> Result<(), FfiError>,
) -> sie_status {
    let Some(context) = context else {
        return sie_status::NullArgument;
    };
    match catch_unwind(AssertUnwindSafe(|| body(context))) {
        Ok(Ok(())) => {
            context.set_last_error("");
            sie_status::Ok
        }
        Ok(Err(error)) => {
            context.set_last_error(&error.message);
            error.status
        }
        Err(payload) => {
            // Unwinding released the body's borrows, so this succeeds unless the panic came
            // from a re-entrant call while an outer registration holds the state.
            context.clear_result();
            context.set_last_error(&format!("internal panic: {}", panic_message(&*payload)));
            sie_status::Panic
        }
    }
}

/// Runs a body that has no context to report to; a panic returns `fallback`.
pub(crate) fn without_context<T>(fallback: T, body: impl FnOnce() -> T) -> T {
    catch_unwind(AssertUnwindSafe(body)).unwrap_or(fallback)
}

fn panic_message(payload: &(dyn Any + Send)) -> &str {
    if let Some(text) = payload.downcast_ref::<&str>() {
        text
    } else if let Some(text) = payload.downcast_ref::<String>() {
        text
    } else {
        "(no message)"
    }
}

/// A static C string from bytes known to end in their only NUL (checked at compile time).
pub(crate) const fn static_c_str(bytes: &'static [u8]) -> &'static CStr {
    match CStr::from_bytes_with_nul(bytes) {
        Ok(text) => text,
        Err(_) => panic!("static C string must end in its only NUL"),
    }
}
