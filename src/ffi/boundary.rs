//! The panic/error boundary every exported function runs its body in, and the error type the
//! bodies return.

use std::any::Any;
use std::ffi::CStr;
use std::panic::{AssertUnwindSafe, catch_unwind};

use super::{ContextState, sie_context, sie_status};
use crate::Error;
use crate::memory::MemoryError;
use std::sync::atomic::AtomicBool;

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
}

impl From<MemoryError> for FfiError {
    fn from(error: MemoryError) -> Self {
        let status = match error {
            MemoryError::TooLarge { .. } => sie_status::InvalidArgument,
            MemoryError::OutOfMemory { .. } => sie_status::OutOfMemory,
        };
        FfiError::new(status, error.to_string())
    }
}

impl From<Error> for FfiError {
    fn from(error: Error) -> Self {
        let status = match &error {
            Error::InvalidArgument(_) => sie_status::InvalidArgument,
            Error::NonFinite(_) => sie_status::NonFiniteInput,
            Error::TooFewPoints(_) => sie_status::TooFewPoints,
            Error::Callback(_) => sie_status::CallbackFailed,
            Error::OutOfMemory(_) => sie_status::OutOfMemory,
        };
        FfiError::new(status, error.to_string())
    }
}

/// What a call's body may use of the context it has taken.
pub(crate) struct Call<'a> {
    pub(crate) state: &'a mut ContextState,
    pub(crate) cancel_requested: &'a AtomicBool,
}

/// Runs `body` on a context it takes for the call: no context -> NULL_ARGUMENT; taken by
/// another call -> BUSY, nothing touched (not even the error message); a panic -> PANIC with
/// its message and the stored result dropped (it may be half-updated); an error -> its status
/// and message; success clears the message. The context is given back when this returns, also
/// after a panic.
pub(crate) fn boundary(
    context: Option<&sie_context>,
    body: impl FnOnce(Call<'_>) -> Result<(), FfiError>,
) -> sie_status {
    let Some(context) = context else {
        return sie_status::NullArgument;
    };
    let Some(mut taken) = context.take() else {
        return sie_status::Busy;
    };
    let call = Call {
        state: &mut taken.state,
        cancel_requested: &context.cancel_requested,
    };
    match catch_unwind(AssertUnwindSafe(|| body(call))) {
        Ok(Ok(())) => {
            taken.set_last_error("");
            sie_status::Ok
        }
        Ok(Err(error)) => {
            taken.set_last_error(&error.message);
            error.status
        }
        Err(payload) => {
            taken.state.result = None;
            taken.set_last_error(&format!("internal panic: {}", panic_message(&*payload)));
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
