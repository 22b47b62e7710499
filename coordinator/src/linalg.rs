//! Small linear-algebra helpers: rank-revealing pseudo-inverse (DESIGN.md §4), SO(3) maps.

use nalgebra::{DMatrix, Matrix3, Rotation3, UnitQuaternion, Vector3};

/// Relative tolerance of the pseudo-inverses: singular values below `RANK_TOL * sigma_max`
/// are treated as zero. `J_c,ee` has rank `6(B-1)` (not `6B`), so this matters.
pub const RANK_TOL: f64 = 1e-9;

/// Moore-Penrose pseudo-inverse by SVD with a relative rank tolerance; also returns the rank.
/// `None` when the SVD fails to converge or the input is not finite.
pub fn pinv(a: &DMatrix<f64>, rel_tol: f64) -> Option<(DMatrix<f64>, usize)> {
    let (r, c) = a.shape();
    if r == 0 || c == 0 {
        return Some((DMatrix::zeros(c, r), 0));
    }
    if !a.iter().all(|x| x.is_finite()) {
        return None;
    }
    let svd = a.clone().try_svd(true, true, 1e-14, 500)?;
    let smax = svd.singular_values.iter().cloned().fold(0.0, f64::max);
    let eps = (rel_tol * smax).max(1e-300);
    let rank = svd.singular_values.iter().filter(|s| **s > eps).count();
    let pinv = svd.pseudo_inverse(eps).ok()?;
    Some((pinv, rank))
}

/// Cross-product matrix: `skew(a) b = a x b`.
pub fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

/// Row-major 3x3 (protocol) to a rotation.
pub fn rotation_from_row_major(r: &[f64; 9]) -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(r))
}

/// Orientation error as a world-frame rotation vector: `log(R R_d^T)` (zero when `R = R_d`).
pub fn rotation_error(r: &Rotation3<f64>, r_d: &Rotation3<f64>) -> Vector3<f64> {
    (r * r_d.inverse()).scaled_axis()
}

/// Quaternion `(w, x, y, z)` of a rotation.
pub fn quat_wxyz(r: &Rotation3<f64>) -> [f64; 4] {
    let q = UnitQuaternion::from_rotation_matrix(r);
    [q.w, q.i, q.j, q.k]
}

/// Rotation of a quaternion `(w, x, y, z)` (normalised first).
pub fn rotation_from_wxyz(q: &[f64; 4]) -> Rotation3<f64> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3])).to_rotation_matrix()
}
