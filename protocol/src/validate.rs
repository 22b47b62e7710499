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
    let bad =
        |reason| Err(ProtocolError::BadId { what, value: id.chars().take(80).collect(), reason });
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
        Some(index) => {
            Err(ProtocolError::NonFinite { field: field.to_string(), index, value: xs[index] })
        }
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

/// Tolerance on a quaternion's norm in messages: senders normalise, this catches garbage.
pub const MESSAGE_QUATERNION_TOLERANCE: f64 = 1e-3;
/// Tolerance on a quaternion's norm in configuration files (scenes, scenarios): written by
/// people or tools that can normalise exactly.
pub const FILE_QUATERNION_TOLERANCE: f64 = 1e-6;

/// A unit quaternion within [`MESSAGE_QUATERNION_TOLERANCE`].
pub fn check_unit_quaternion(field: &str, q: &[f64; 4]) -> Result<(), ProtocolError> {
    check_unit_quaternion_within(field, q, MESSAGE_QUATERNION_TOLERANCE)
}

/// A finite quaternion whose norm is 1 within `tolerance`.
pub fn check_unit_quaternion_within(
    field: &str,
    q: &[f64; 4],
    tolerance: f64,
) -> Result<(), ProtocolError> {
    check_finite(field, q)?;
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if (n - 1.0).abs() > tolerance {
        return Err(ProtocolError::invalid(
            field,
            format!("quaternion norm {n} is not 1 (a unit quaternion w, x, y, z)"),
        ));
    }
    Ok(())
}

/// No name is listed twice (robots of a team, frames of a robot); the error names the first
/// repeated one and where it stands.
pub fn check_unique<'a>(
    field: &str,
    names: impl IntoIterator<Item = &'a str>,
) -> Result<(), ProtocolError> {
    let mut seen: Vec<&str> = Vec::new();
    for (i, name) in names.into_iter().enumerate() {
        if seen.contains(&name) {
            return Err(ProtocolError::invalid(
                format!("{field}[{i}]"),
                format!("{name:?} is listed twice"),
            ));
        }
        seen.push(name);
    }
    Ok(())
}

/// Largest number of physics steps per control tick that a scene may ask for.
pub const MAX_SUBSTEPS: u32 = 1000;

/// Physics steps per control tick: the physics rate must be a whole multiple (1 to
/// [`MAX_SUBSTEPS`]) of the control rate, both positive and finite. The one rule for scenario
/// files, scene files and the world builder.
pub fn substeps(control_hz: f64, physics_hz: f64) -> Result<u32, ProtocolError> {
    if !(control_hz.is_finite() && control_hz > 0.0 && physics_hz.is_finite() && physics_hz > 0.0) {
        return Err(ProtocolError::invalid(
            "rates",
            format!("rates must be positive: control {control_hz} Hz, physics {physics_hz} Hz"),
        ));
    }
    let n = physics_hz / control_hz;
    if (n - n.round()).abs() > 1e-9 || n.round() < 1.0 || n.round() > MAX_SUBSTEPS as f64 {
        return Err(ProtocolError::invalid(
            "rates",
            format!(
                "physics rate {physics_hz} Hz must be a whole multiple (1 to {MAX_SUBSTEPS}) of \
                 the control rate {control_hz} Hz"
            ),
        ));
    }
    Ok(n.round() as u32)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_must_be_a_whole_multiple() {
        assert_eq!(substeps(1000.0, 2000.0), Ok(2));
        assert_eq!(substeps(500.0, 500.0), Ok(1));
        for (c, p) in [
            (1000.0, 1500.0),
            (1000.0, 500.0),
            (0.0, 1000.0),
            (f64::NAN, 1000.0),
            (1.0, 2000.0),
            (1000.0, f64::INFINITY),
        ] {
            let e = substeps(c, p).unwrap_err().to_string();
            assert!(e.contains("rate"), "{c} {p}: {e}");
        }
    }

    #[test]
    fn repeated_names_are_named() {
        assert!(check_unique("robots", ["r1", "r2", "r3"]).is_ok());
        let e = check_unique("robots", ["r1", "r2", "r1"]).unwrap_err().to_string();
        assert!(e.contains("robots[2]") && e.contains("\"r1\" is listed twice"), "{e}");
    }

    #[test]
    fn quaternion_tolerances() {
        let q = [1.0 + 1e-4, 0.0, 0.0, 0.0];
        assert!(check_unit_quaternion("q", &q).is_ok());
        assert!(check_unit_quaternion_within("q", &q, FILE_QUATERNION_TOLERANCE).is_err());
        assert!(check_unit_quaternion("q", &[0.5, 0.0, 0.0, 0.0]).is_err());
        assert!(check_unit_quaternion("q", &[f64::NAN, 0.0, 0.0, 1.0]).is_err());
    }
}
