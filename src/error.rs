//! Why a call could not run: one error type for every layer (the C ABI maps it to a status).

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
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Error::InvalidArgument(m) | Error::NonFinite(m) | Error::TooFewPoints(m) | Error::Callback(m) => {
                f.write_str(m)
            }
        }
    }
}

impl std::error::Error for Error {}
