//! The value tables of the C enums, derived from their declarations.
//!
//! cbindgen reads the declarations (and their doc comments) to write the header but expands no
//! macros, so each enum stays a plain `#[repr(u32)]` item and `#[macro_rules_derive(CEnum!)]`
//! implements [`CEnum`] from its tokens: a variant added to a declaration is in every table.

use super::boundary::FfiError;

/// A C enum, passed as `uint32_t`: every variant, and decoding a number into one.
pub(crate) trait CEnum: Copy + 'static {
    /// Every variant, in declaration order.
    const ALL: &'static [Self];

    /// The variant's numeric value in C.
    fn code(self) -> u32;

    /// The variant with this numeric value, `None` for values that are not one.
    fn from_u32(value: u32) -> Option<Self> {
        Self::ALL.iter().copied().find(|variant| variant.code() == value)
    }

    /// Decodes an argument, rejecting unknown values with an INVALID_ARGUMENT naming it.
    fn decode(value: u32, argument: &str) -> Result<Self, FfiError> {
        Self::from_u32(value).ok_or_else(|| {
            let last = Self::ALL.iter().map(|e| e.code()).max().unwrap_or(0);
            FfiError::invalid(format!(
                "{argument} = {value} is not a known value (valid: 0..={last})"
            ))
        })
    }
}

/// Implements [`CEnum`] for the enum it is applied to (`#[macro_rules_derive(CEnum!)]`). Every
/// variant needs an explicit value: they are the ABI.
macro_rules! CEnum {
    (
        $(#[$attribute:meta])*
        $visibility:vis enum $name:ident {
            $(
                $(#[$variant_attribute:meta])*
                $variant:ident = $value:literal
            ),+ $(,)?
        }
    ) => {
        impl $crate::ffi::c_enum::CEnum for $name {
            const ALL: &'static [Self] = &[$(Self::$variant),+];

            fn code(self) -> u32 {
                self as u32
            }
        }
    };
}
