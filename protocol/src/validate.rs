//! Validation shared by every message.

use crate::ProtocolError;

/// A message that can check itself: dimensions consistent with each other, numbers finite,
/// identifiers well formed. Decoding calls it; senders may call it before publishing.
pub trait Validate {
    fn validate(&self) -> Result<(), ProtocolError>;
}

/// Maximum length of a team or robot identifier.
pub const MAX_ID_LEN: usize = 64;

/// Identifiers are `[A-Za-z0-9_-]{1,64}` so that they are single, wildcard-free key chunks.
pub fn validate_id(what: &'static str, id: &str) -> Result<(), ProtocolError> {
    let bad = |reason| Err(ProtocolError::BadId { what, value: id.chars().take(80).collect(), reason });
    if id.is_empty() {
        return bad("empty");
    }
    if id.len() > MAX_ID_LEN {
        return bad("longer than 64 bytes");
    }
    if !id.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-') {
        return bad("only ASCII letters, digits, '_' and '-' are allowed");
    }
    Ok(())
}

/// Every entry finite.
pub fn check_finite(field: &str, xs: &[f64]) -> Result<(), ProtocolError> {
    match xs.iter().position(|x| !x.is_finite()) {
        Some(index) => Err(ProtocolError::NonFinite { field: field.to_string(), index, value: xs[index] }),
        None => Ok(()),
    }
}

/// Exactly `n` entries.
pub fn check_len(field: &str, xs: &[f64], n: usize) -> Result<(), ProtocolError> {
    if xs.len() != n {
        return Err(ProtocolError::dim(field, n, xs.len()));
    }
    Ok(())
}

/// A unit quaternion within a loose tolerance (senders normalise; this catches garbage).
pub fn check_unit_quaternion(field: &str, q: &[f64; 4]) -> Result<(), ProtocolError> {
    check_finite(field, q)?;
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if (n - 1.0).abs() > 1e-3 {
        return Err(ProtocolError::invalid(field, format!("quaternion norm {n} is not 1")));
    }
    Ok(())
}

/// A row-major rotation matrix that is orthonormal within a loose tolerance.
pub fn check_rotation(field: &str, r: &[f64; 9]) -> Result<(), ProtocolError> {
    check_finite(field, r)?;
    let m = nalgebra::Matrix3::from_row_slice(r);
    let err = (m.transpose() * m - nalgebra::Matrix3::identity()).amax();
    if err > 1e-6 || m.determinant() < 0.0 {
        return Err(ProtocolError::invalid(field, "not a rotation matrix"));
    }
    Ok(())
}
