//! Reading caller memory into owned Rust values (checked first, copied, never aliased with
//! outputs) and writing results back only once everything has succeeded.

use core::mem::{align_of, size_of};

use nalgebra::Matrix4;

use super::CEnum;
use super::boundary::FfiError;
use super::{sie_status, sie_summary, sie_verdict};
use crate::WarmStart;
use crate::geometry::{Rigid, is_finite};
use crate::memory::try_vec;
use crate::{NonFinite, Point};

/// The scalar types point arrays come in.
pub(crate) trait Coordinate: Copy {
    const C_NAME: &'static str;
    fn to_f64(self) -> f64;
}

impl Coordinate for f32 {
    const C_NAME: &'static str = "float";
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
}

impl Coordinate for f64 {
    const C_NAME: &'static str = "double";
    fn to_f64(self) -> f64 {
        self
    }
}

fn check_non_null<T>(ptr: *const T, name: &str) -> Result<(), FfiError> {
    if ptr.is_null() {
        Err(FfiError::null(name))
    } else {
        Ok(())
    }
}

fn check_aligned<T>(ptr: *const T, name: &str) -> Result<(), FfiError> {
    if ptr.is_aligned() {
        Ok(())
    } else {
        Err(FfiError::invalid(format!(
            "{name} ({ptr:p}) is not aligned to {} bytes",
            align_of::<T>()
        )))
    }
}

/// Rust may only address objects of at most isize::MAX bytes.
fn check_extent(bytes: Option<usize>, name: &str) -> Result<(), FfiError> {
    match bytes {
        Some(b) if b <= isize::MAX as usize => Ok(()),
        _ => Err(FfiError::invalid(format!(
            "{name} is larger than the address space"
        ))),
    }
}

/// Checks an output pointer before anything is computed, so a bad one fails without side effects.
pub(crate) fn check_output<T>(ptr: *mut T, name: &str) -> Result<(), FfiError> {
    check_non_null(ptr.cast_const(), name)?;
    check_aligned(ptr.cast_const(), name)
}

/// A nullable output pointer: NULL is fine, a misaligned one is not.
pub(crate) fn check_optional_output<T>(ptr: *mut T, name: &str) -> Result<(), FfiError> {
    if ptr.is_null() {
        Ok(())
    } else {
        check_aligned(ptr.cast_const(), name)
    }
}

/// Copies `values` to `out`.
///
/// # Safety
/// `out` passed `check_output` and is valid for `values.len()` writes.
pub(crate) unsafe fn write_output<T: Copy>(out: *mut T, values: &[T]) {
    // SAFETY: per the contract; `values` is Rust-owned, so the two cannot overlap.
    unsafe { core::ptr::copy_nonoverlapping(values.as_ptr(), out, values.len()) }
}

/// Copies `len` values of type `T` from caller memory.
///
/// # Safety
/// `ptr` is NULL or valid for `len` reads of `T`.
pub(crate) unsafe fn read_array<T: Copy>(ptr: *const T, len: usize, name: &str) -> Result<Vec<T>, FfiError> {
    check_non_null(ptr, name)?;
    check_aligned(ptr, name)?;
    check_extent(len.checked_mul(size_of::<T>()), name)?;
    let mut copy = try_vec(len, name)?;
    // SAFETY: non-NULL, aligned, within isize::MAX bytes, and readable per the contract.
    copy.extend_from_slice(unsafe { core::slice::from_raw_parts(ptr, len) });
    Ok(copy)
}

/// The noise model of a summary a registration filled (`sie_context_set_warm_start`), `None`
/// when its verdict is DOUBTFUL or UNSUPPORTED (as `WarmStart::of`: that frame's successor
/// runs cold; NONE, a summary filled by hand, is taken as given). Reads
/// only its number fields (a `bool` with another bit pattern would be undefined behaviour to
/// copy).
///
/// # Safety
/// `ptr` is valid for reading one `sie_summary` (NULL and misalignment are reported).
pub(crate) unsafe fn read_warm_start(
    ptr: *const sie_summary,
    name: &str,
) -> Result<Option<WarmStart>, FfiError> {
    check_non_null(ptr, name)?;
    check_aligned(ptr, name)?;
    // SAFETY: non-NULL, aligned and readable per the contract; each field is read by value
    // through a raw place, f64 and u32 have no invalid bit patterns.
    let (sigma, penalty, noise_shape, inlier_fraction, histogram_count, verdict) = unsafe {
        (
            core::ptr::addr_of!((*ptr).sigma).read(),
            core::ptr::addr_of!((*ptr).penalty).read(),
            core::ptr::addr_of!((*ptr).noise_shape).read(),
            core::ptr::addr_of!((*ptr).inlier_fraction).read(),
            core::ptr::addr_of!((*ptr).histogram_count).read(),
            core::ptr::addr_of!((*ptr).verdict).read(),
        )
    };
    if !(1..=3).contains(&histogram_count) {
        return Err(FfiError::invalid(format!(
            "{name} holds no SIE noise model (histogram_count is {histogram_count}; a baseline cost's \
             summary, or not one a registration filled)"
        )));
    }
    let verdict = sie_verdict::decode(verdict, &format!("{name}->verdict"))?;
    let warm = WarmStart::from_fit(
        &sigma[..histogram_count as usize],
        penalty,
        noise_shape,
        inlier_fraction,
    )
    .map_err(|message| FfiError::invalid(format!("{name}: {message}")))?;
    let held = matches!(verdict, sie_verdict::Good | sie_verdict::None);
    Ok(held.then_some(warm))
}

/// Reads `count` points of three `T`s, point i starting `i * stride_bytes` bytes after `ptr`
/// (0 = packed), rejecting bad strides, misalignment and (with [`NonFinite::Reject`])
/// non-finite coordinates.
///
/// # Safety
/// `ptr` is NULL or valid for reading `count` points at that stride.
pub(crate) unsafe fn read_points<T: Coordinate>(
    ptr: *const T,
    count: usize,
    stride_bytes: usize,
    name: &str,
    non_finite: NonFinite,
) -> Result<Vec<Point>, FfiError> {
    check_non_null(ptr, name)?;
    let scalar = size_of::<T>();
    let stride = if stride_bytes == 0 {
        3 * scalar
    } else {
        stride_bytes
    };
    if stride < 3 * scalar || stride % scalar != 0 {
        return Err(FfiError::invalid(format!(
            "{name}: stride of {stride_bytes} bytes is invalid for {} points; use 0 (packed) or a \
             multiple of {scalar} that is at least {}",
            T::C_NAME,
            3 * scalar
        )));
    }
    check_aligned(ptr, name)?;
    let extent = count
        .checked_sub(1)
        .map_or(Some(0), |last| last.checked_mul(stride)?.checked_add(3 * scalar));
    check_extent(extent, name)?;

    // The copy holds f64 (24 bytes a point), more than a float array's 12: a count that fits
    // the caller's memory may still not fit here.
    let mut points = try_vec(count, &format!("{name} ({count} points)"))?;
    for i in 0..count {
        // SAFETY: inside the extent checked above, aligned because the base is aligned and the
        // stride is a multiple of the scalar size; readable per the contract.
        let point = unsafe {
            let first = ptr.byte_add(i * stride);
            [first.read(), first.add(1).read(), first.add(2).read()]
        };
        let point = point.map(Coordinate::to_f64);
        if non_finite == NonFinite::Reject && !is_finite(&point) {
            let axis = point.iter().position(|v| !v.is_finite()).unwrap_or(0);
            return Err(FfiError::new(
                sie_status::NonFiniteInput,
                format!(
                    "{name}[{i}] is {} ({} coordinate); remove non-finite points first or enable \
                     sie_context_set_skip_non_finite",
                    point[axis],
                    ["x", "y", "z"][axis]
                ),
            ));
        }
        points.push(point);
    }
    Ok(points)
}

/// Reads an optional row-major 4x4 rigid transform (`geometry::make_rigid`: rotation block
/// within 1e-3 of orthonormal, made exact); NULL means identity (`None`).
///
/// # Safety
/// `ptr` is NULL or valid for 16 reads of f64.
pub(crate) unsafe fn read_transform(ptr: *const f64, name: &str) -> Result<Option<Rigid>, FfiError> {
    if ptr.is_null() {
        return Ok(None);
    }
    // SAFETY: forwarded contract.
    let values = unsafe { read_array(ptr, 16, name) }?;
    let matrix = Matrix4::from_row_slice(&values);
    let rigid = crate::geometry::make_rigid(&matrix, name).map_err(FfiError::invalid)?;
    Ok(Some(rigid))
}

/// Row-major copy of a 4x4 matrix (nalgebra stores column-major).
pub(crate) fn row_major(matrix: &Matrix4<f64>) -> [f64; 16] {
    let mut out = [0.0; 16];
    for (index, value) in out.iter_mut().enumerate() {
        *value = matrix[(index / 4, index % 4)];
    }
    out
}

/// Writes a result array into a caller buffer of `capacity` elements, or answers a size query.
///
/// * `out` NULL, `capacity` 0 and `out_len` given: only the required length is written.
/// * `capacity` below `values.len()`: BUFFER_TOO_SMALL, nothing written.
/// * Otherwise all values are copied and `out_len` (nullable) receives the count.
///
/// # Safety
/// `out` is NULL or valid for `capacity` writes; `out_len` is NULL or valid for one write.
pub(crate) unsafe fn write_buffer<T: Copy>(
    out: *mut T,
    capacity: usize,
    out_len: *mut usize,
    values: &[T],
    what: &str,
) -> Result<(), FfiError> {
    check_optional_output(out_len, "out_len")?;
    if out.is_null() {
        if capacity != 0 || out_len.is_null() {
            return Err(FfiError::new(
                sie_status::NullArgument,
                "out is NULL (allowed only with capacity 0 and a non-NULL out_len, to query the length)",
            ));
        }
        // SAFETY: checked non-NULL and aligned; writable per the contract.
        unsafe { out_len.write(values.len()) };
        return Ok(());
    }
    check_aligned(out.cast_const(), "out")?;
    if capacity < values.len() {
        return Err(FfiError::new(
            sie_status::BufferTooSmall,
            format!("capacity {capacity} is smaller than the {} {what}", values.len()),
        ));
    }
    // SAFETY: `out` is aligned and holds `capacity >= values.len()` elements per the contract;
    // `out_len` was checked above.
    unsafe {
        write_output(out, values);
        if !out_len.is_null() {
            out_len.write(values.len());
        }
    }
    Ok(())
}
