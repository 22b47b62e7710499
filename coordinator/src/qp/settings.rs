//! [`QpSettings`]: how the QP is solved (which solver first, iterations, tolerances, the
//! fallback's price), apart from what is solved ([`super::problem`]). Clarabel's
//! `DefaultSettings` plays the same part for Clarabel; [`super::clarabel`] builds it from these.

/// Relative tolerance of [`super::DenseIpm`] on the QP (residuals and complementarity). At 1e-8
/// the dual residual stalled at round-off on 12 % of S1's ticks (the normal equations'
/// condition grows as complementarity vanishes) and Clarabel had to finish them; 1e-7 is a
/// torque error of about 1e-5 N m.
pub const DENSE_TOL: f64 = 1e-7;

/// Tolerance of [`super::DualActiveSet`]: a row counts as violated when `a_i F - b_i` exceeds
/// it times `1 + |b_i|`, and the answer is refused when a row or a multiplier misses by more.
/// The method's answer is exact on its active set (to round-off), so this is far below
/// [`DENSE_TOL`].
pub const ACTIVE_SET_TOL: f64 = 1e-9;

/// Iteration limit of [`super::DualActiveSet`] (a row entering or leaving is one): a cold
/// start of the eight-robot QP takes about 30, a hot start none to a few.
pub const ACTIVE_SET_MAX_ITER: u32 = 1000;

/// How many times [`super::BlockHotStart`] may mend the last tick's active rows (one row in or
/// out each time) before the team-sized QP is built: one or two rows change on most ticks
/// where the active set changes at all.
pub const BLOCK_REPAIRS: u32 = 3;

/// Relative tolerance of a reduced-accuracy (AlmostSolved) answer of [`super::DenseIpm`].
pub const REDUCED_TOL: f64 = 1e-5;

/// Price of a violated row in [`super::solve_least_violation`] (per N^2 of violation, against
/// the torque objective in (N m)^2).
pub const VIOLATION_WEIGHT: f64 = 1e6;

/// How much more a violated stance-foot row or torque limit costs than a violated hand row in
/// [`super::solve_least_violation`]: when not every contact force can be kept, the grasp
/// gives way before the footing and the joints.
pub const HARD_ROW_FACTOR: f64 = 1e3;

/// Fewest active-set iterations [`super::solve_least_violation`] may take, whatever
/// `max_iter` says.
pub const LEAST_VIOLATION_MIN_ITER: u32 = 30;

/// How the contact-force QP is solved.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QpSettings {
    /// Iteration limit of each solver (the least-violation fallback takes at least
    /// [`QpSettings::least_violation_min_iter`]).
    pub max_iter: u32,
    /// Try [`super::DenseIpm`] first (Clarabel if it does not converge); Clarabel alone if false.
    pub dense_first: bool,
    /// With `dense_first`: try [`super::DualActiveSet`] (hot-started from the last tick) before
    /// [`super::DenseIpm`].
    pub active_set_first: bool,
    /// [`ACTIVE_SET_TOL`].
    pub active_set_tol: f64,
    /// [`ACTIVE_SET_MAX_ITER`].
    pub active_set_max_iter: u32,
    /// [`DENSE_TOL`].
    pub dense_tol: f64,
    /// [`REDUCED_TOL`].
    pub reduced_tol: f64,
    /// [`VIOLATION_WEIGHT`].
    pub violation_weight: f64,
    /// [`HARD_ROW_FACTOR`].
    pub hard_row_factor: f64,
    /// [`LEAST_VIOLATION_MIN_ITER`].
    pub least_violation_min_iter: u32,
}

impl QpSettings {
    /// The defaults with the controller's two choices (`PidcConfig::qp_max_iter`,
    /// `PidcConfig::dense_qp`).
    pub fn new(max_iter: u32, dense_first: bool) -> Self {
        QpSettings { max_iter, dense_first, ..QpSettings::default() }
    }
}

impl Default for QpSettings {
    fn default() -> Self {
        QpSettings {
            max_iter: 50,
            dense_first: true,
            active_set_first: true,
            active_set_tol: ACTIVE_SET_TOL,
            active_set_max_iter: ACTIVE_SET_MAX_ITER,
            dense_tol: DENSE_TOL,
            reduced_tol: REDUCED_TOL,
            violation_weight: VIOLATION_WEIGHT,
            hard_row_factor: HARD_ROW_FACTOR,
            least_violation_min_iter: LEAST_VIOLATION_MIN_ITER,
        }
    }
}
