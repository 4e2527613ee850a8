//! Why a call could not run: one error type for every layer (the C ABI maps it to a status).

use crate::memory::MemoryError;

/// Why a registration or an estimate could not run. Nothing is returned with an error.
#[derive(Clone, Debug, PartialEq)]
pub enum Error {
    /// An argument is out of range or inconsistent (a setting, a transform, counts that do not
    /// match, a normal that is not a unit vector); the message names it.
    InvalidArgument(String),
    /// A NaN or infinite coordinate or value; the message names the array and first index.
    NonFinite(String),
    /// Not enough points (or residual rows) to run; the message says how many are needed.
    TooFewPoints(String),
    /// The noise callback failed or returned bad scales.
    Callback(String),
    /// The memory this input needs (asked for before the work starts) could not be had; the
    /// message says how much. The process is unharmed.
    OutOfMemory(String),
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Error::InvalidArgument(m)
            | Error::NonFinite(m)
            | Error::TooFewPoints(m)
            | Error::Callback(m)
            | Error::OutOfMemory(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for Error {}

impl From<MemoryError> for Error {
    /// A count no address space holds is a bad argument; a refused allocation is out of memory.
    fn from(error: MemoryError) -> Self {
        match error {
            MemoryError::TooLarge { .. } => Error::InvalidArgument(error.to_string()),
            MemoryError::OutOfMemory { .. } => Error::OutOfMemory(error.to_string()),
        }
    }
}
