//! Numbers as the reports and the plot print them. Its own module so that the paper
//! reproduction (examples/experiments) compiles the plot with it.

/// About four significant digits, switching to exponent form where fixed decimals would not
/// show them.
pub fn significant(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let magnitude = x.abs().log10().floor();
    if !(-4.0..6.0).contains(&magnitude) {
        return format!("{x:.3e}");
    }
    let decimals = (3.0 - magnitude).max(0.0) as usize;
    format!("{x:.decimals$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn significant_digits() {
        assert_eq!(significant(0.0143217), "0.01432");
        assert_eq!(significant(12.345678), "12.35");
        assert_eq!(significant(1234.5), "1234");
        assert_eq!(significant(2.5e-7), "2.500e-7");
        assert_eq!(significant(0.0), "0");
    }
}
