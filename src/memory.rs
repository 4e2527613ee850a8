//! Memory for work sized by the input, asked for fallibly: a request the process cannot satisfy
//! (an address-space limit, `vm.overcommit_memory = 2`, or a count no machine could hold) is an
//! error the caller reports, never an abort of the host process.
//!
//! Two tools: [`try_vec`] for buffers this crate allocates itself, and [`ensure_available`]
//! before work whose allocations cannot all be made fallible (the kd-tree crate, nalgebra and
//! the standard library allocate infallibly): it asks for the work's measured peak at once, so
//! a limit is met up front instead of part-way through. The peaks are upper bounds measured by
//! `tests/peak_memory.rs` (a counting allocator), which fails when the code outgrows them.
use std::collections::TryReserveError;
use std::fmt;

/// Why memory for some input could not be had.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MemoryError {
    /// More bytes than the address space holds (`isize::MAX`): the count is impossible.
    TooLarge {
        /// What the memory was for (names the input).
        what: String,
    },
    /// The allocator refused: not enough memory (or address space) left for this input.
    OutOfMemory {
        /// What the memory was for (names the input).
        what: String,
        /// How many bytes were asked for.
        bytes: usize,
    },
}

impl fmt::Display for MemoryError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MemoryError::TooLarge { what } => {
                write!(f, "{what} needs more bytes than the address space holds")
            }
            MemoryError::OutOfMemory { what, bytes } => write!(
                f,
                "out of memory: {what} needs {} more ({bytes} bytes) than the process can allocate now",
                human_bytes(*bytes)
            ),
        }
    }
}

impl std::error::Error for MemoryError {}

/// An empty `Vec` with room for `count` elements; `what` names the buffer in the error.
pub fn try_vec<T>(count: usize, what: &str) -> Result<Vec<T>, MemoryError> {
    let mut v = Vec::new();
    v.try_reserve_exact(count)
        .map_err(|e| classify(e, what, count.saturating_mul(size_of::<T>())))?;
    Ok(v)
}

/// Checks that `bytes` can be allocated now, by allocating (not touching) and freeing them.
pub fn ensure_available(bytes: usize, what: &str) -> Result<(), MemoryError> {
    let mut probe: Vec<u8> = Vec::new();
    probe
        .try_reserve_exact(bytes)
        .map_err(|e| classify(e, what, bytes))?;
    // The pointer escapes, so the allocation cannot be optimised away.
    std::hint::black_box(probe.as_mut_ptr());
    Ok(())
}

/// `TryReserveErrorKind` is unstable; a request beyond isize::MAX bytes is what fails as a
/// capacity overflow (before the allocator is asked), anything else the allocator refused.
fn classify(_error: TryReserveError, what: &str, bytes: usize) -> MemoryError {
    if bytes > isize::MAX as usize || bytes == usize::MAX {
        MemoryError::TooLarge {
            what: what.to_string(),
        }
    } else {
        MemoryError::OutOfMemory {
            what: what.to_string(),
            bytes,
        }
    }
}

/// `n × per_item + fixed`, saturating (a saturated request fails as too large).
fn linear(n: usize, per_item: usize, fixed: usize) -> usize {
    n.saturating_mul(per_item).saturating_add(fixed)
}

/// Allocator bookkeeping, small buffers and fragmentation on top of the measured peaks.
const OVERHEAD: usize = 8 << 20;
/// The same for ICP, whose fixed part (the starts' small buffers) is measured at ~0.5 MB.
const CLOUD_OVERHEAD: usize = 2 << 20;

/// Peak heap of `register_clouds` (ICP) beyond its inputs. Measured (tests/peak_memory.rs, 6 k
/// to 60 k points, per-point noise scales, non-finite points skipped): at most 118 B per
/// source and 124 B per target point (point-to-point or point-to-plane) and 0.5 MB fixed,
/// bounded here with ~25 % margin.
pub fn cloud_registration_bytes(source: usize, target: usize) -> usize {
    linear(source, 150, CLOUD_OVERHEAD).saturating_add(target.saturating_mul(155))
}

/// Peak heap of `register_clouds_to` beyond its source and the prepared target: the source
/// part as [`cloud_registration_bytes`]; per target point, among others the normals a first
/// point-to-plane registration estimates and, with per-point noise, the target's σ and a copy
/// of its points in the caller's order. Measured (tests/peak_memory.rs) at most 62 B per target
/// point, bounded here with ~25 % margin.
pub fn prepared_registration_bytes(source: usize, target: usize) -> usize {
    linear(source, 150, CLOUD_OVERHEAD).saturating_add(target.saturating_mul(PREPARED_TARGET_BYTES))
}

/// See [`prepared_registration_bytes`].
const PREPARED_TARGET_BYTES: usize = 80;

/// Peak heap of `PreparedTarget::new` beyond its input: the curve order, the sorted copy and
/// the kd-tree, with `with_normals` the normals in curve order. Measured (tests/peak_memory.rs)
/// at most 80 B a point and 29 B more with normals, when non-finite points are skipped, some
/// are duplicates and all are beyond the safe range (a copy each), 69 and 24 B otherwise;
/// bounded here with ~25 % margin.
pub fn prepared_target_bytes(points: usize, with_normals: bool) -> usize {
    let per_point = if with_normals {
        TARGET_POINT_BYTES + TARGET_NORMAL_BYTES
    } else {
        TARGET_POINT_BYTES
    };
    linear(points, per_point, TARGET_OVERHEAD)
}

/// See [`prepared_target_bytes`].
const TARGET_POINT_BYTES: usize = 98;
const TARGET_NORMAL_BYTES: usize = 36;
/// The fixed part of [`prepared_target_bytes`] (measured at a few kB).
const TARGET_OVERHEAD: usize = 1 << 20;

/// Peak heap of `PreparedTarget::estimate_all_normals` on a target whose normals are not set
/// up yet (0 points: once they are). Per point the normals (12 B) and the thinned copy and
/// kd-tree a dense noisy target takes its neighbourhoods from: measured (tests/peak_memory.rs)
/// at most 29 B, when a quarter of the points is kept. Fixed: one block of normals being
/// estimated, measured at 3.4 MB. Both bounded here with ~25 % margin.
pub fn target_normals_bytes(points: usize) -> usize {
    linear(points, 36, 4 << 20)
}

/// Peak heap of `register_correspondences` beyond its inputs (measured at most 165 B a pair).
pub fn correspondence_registration_bytes(pairs: usize) -> usize {
    linear(pairs, 184, OVERHEAD)
}

/// Peak heap of the global stage (`Starts::Global`) beyond the registration's, for `points`
/// points in both clouds together and descriptors of `descriptor_bytes`: per point a kd-tree
/// (the point copied, its index) and the voxel table a first, fine voxel size may fill;
/// estimated from the sizes of those structures (not measured by tests/peak_memory.rs).
pub fn global_stage_bytes(points: usize, descriptor_bytes: usize) -> usize {
    linear(points, 120, descriptor_bytes.saturating_add(OVERHEAD))
}

/// Peak heap of `estimate_inliers` beyond its input (measured at most 12 B a residual value).
pub fn estimate_bytes(values: usize) -> usize {
    linear(values, 16, OVERHEAD)
}

fn human_bytes(bytes: usize) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn impossible_sizes_are_errors_not_aborts() {
        let error = try_vec::<[f64; 3]>(0x0aaa_aaaa_aaaa_aaa9, "source_xyz").unwrap_err();
        assert_eq!(
            error,
            MemoryError::TooLarge {
                what: "source_xyz".into()
            }
        );
        assert!(error.to_string().contains("address space"), "{error}");
        assert!(matches!(
            ensure_available(usize::MAX, "everything"),
            Err(MemoryError::TooLarge { .. })
        ));
        assert_eq!(try_vec::<u8>(16, "small").unwrap().capacity(), 16);
        assert_eq!(ensure_available(1 << 20, "a little"), Ok(()));
        assert_eq!(human_bytes(3 << 30), "3.0 GiB");
        assert_eq!(human_bytes(100), "100 B");
    }
}
