//! [`QpSettings`]: how the QP is solved (where the solve starts, [`QpPath`]; iterations,
//! tolerances, the fallback's price, the time it may take), apart from what is solved
//! ([`super::problem`]).
//! Clarabel's `DefaultSettings` plays the same part for Clarabel; [`super::clarabel`] builds
//! it from these.

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

use std::time::{Duration, Instant};

/// Where the contact-force QP's solve starts. Each path falls back down the chain
/// `ByBlocks -> ActiveSet -> DenseIpm -> Clarabel`: a method that does not answer hands the
/// tick to the next one, and Clarabel (which also certifies infeasibility) ends every chain.
/// In TOML (`qp_path = ...`) the names are kebab-case: `"by-blocks"`, `"active-set"`,
/// `"dense-ipm"`, `"clarabel"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum QpPath {
    /// The last tick's active rows by the robots' blocks first ([`super::BlockHotStart`], the
    /// QP in the wrenches' change `z = rho F`, before `Y`, `rho` and the team-sized QP are
    /// built; run by the controller), then the team-sized QP from [`QpPath::ActiveSet`] on.
    /// The default: the same torques to the solvers' tolerance (`tests/qp_by_blocks.rs`).
    #[default]
    ByBlocks,
    /// The dual active-set method ([`super::DualActiveSet`], hot-started from the last tick's
    /// active rows) on the team-sized QP, then [`QpPath::DenseIpm`]: the same forces to the
    /// interior point's tolerance, 7 times faster for eight robots.
    ActiveSet,
    /// The dense interior-point method ([`super::DenseIpm`]), then Clarabel.
    DenseIpm,
    /// Clarabel alone ([`super::Clarabel`]).
    Clarabel,
}

impl QpPath {
    /// Every path with its name in files, in the chain's order.
    pub const NAMES: [(QpPath, &'static str); 4] = [
        (QpPath::ByBlocks, "by-blocks"),
        (QpPath::ActiveSet, "active-set"),
        (QpPath::DenseIpm, "dense-ipm"),
        (QpPath::Clarabel, "clarabel"),
    ];

    /// The path's name in files (`qp_path = "by-blocks"`).
    pub fn name(self) -> &'static str {
        Self::NAMES.iter().find(|(p, _)| *p == self).map_or("", |(_, n)| n)
    }

    /// Whether the hot start by the robots' blocks is tried first.
    pub fn tries_blocks(self) -> bool {
        self == QpPath::ByBlocks
    }

    /// Whether the dual active-set method is tried on the team-sized QP.
    pub fn tries_active_set(self) -> bool {
        matches!(self, QpPath::ByBlocks | QpPath::ActiveSet)
    }

    /// Whether the dense interior-point method is tried before Clarabel.
    pub fn tries_dense_ipm(self) -> bool {
        !matches!(self, QpPath::Clarabel)
    }
}

impl std::str::FromStr for QpPath {
    type Err = String;

    /// A path by its name in files (`"by-blocks"`, ...); the error lists the names.
    fn from_str(s: &str) -> Result<Self, String> {
        match Self::NAMES.iter().find(|(_, n)| *n == s) {
            Some((p, _)) => Ok(*p),
            None => Err(format!(
                "unknown QP path `{s}` (one of: {})",
                Self::NAMES.map(|(_, n)| n).join(", ")
            )),
        }
    }
}

/// How the contact-force QP is solved.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QpSettings {
    /// Iteration limit of each solver (the least-violation fallback takes at least
    /// [`QpSettings::least_violation_min_iter`]).
    pub max_iter: u32,
    /// Where the solve starts, and the chain it falls back down ([`QpPath`]).
    pub path: QpPath,
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
    /// Whether the dual active-set method's own proof of infeasibility ends the solve (no
    /// step can satisfy a violated row: Goldfarb and Idnani's test) instead of handing the QP
    /// down the chain for Clarabel to certify. Off for a tick's QP; on for the many QPs of a
    /// yield's bisection ([`crate::pidc::stages::yielding`]), where each infeasible try would
    /// otherwise cost Clarabel's milliseconds.
    pub active_set_refuses: bool,
    /// When the chain must have answered (a real-time tick's budget): past it no further
    /// solver of the chain is started (the outcome is the last one's: the active set's proof
    /// of infeasibility, or the iterations it ran out of), and Clarabel, when it runs, stops at
    /// it (`MaxIterations`). `None`: the chain runs to its end (lockstep).
    pub deadline: Option<Instant>,
}

impl QpSettings {
    /// The defaults with the controller's two choices (`PidcConfig::qp_max_iter`,
    /// `PidcConfig::qp_path`).
    pub fn new(max_iter: u32, path: QpPath) -> Self {
        QpSettings { max_iter, path, ..QpSettings::default() }
    }
}

impl Default for QpSettings {
    fn default() -> Self {
        QpSettings {
            max_iter: 50,
            path: QpPath::default(),
            active_set_tol: ACTIVE_SET_TOL,
            active_set_max_iter: ACTIVE_SET_MAX_ITER,
            dense_tol: DENSE_TOL,
            reduced_tol: REDUCED_TOL,
            violation_weight: VIOLATION_WEIGHT,
            hard_row_factor: HARD_ROW_FACTOR,
            least_violation_min_iter: LEAST_VIOLATION_MIN_ITER,
            active_set_refuses: false,
            deadline: None,
        }
    }
}

/// Whether `deadline` has passed (never without one): a real-time tick's budget spent.
pub fn passed(deadline: Option<Instant>) -> bool {
    deadline.is_some_and(|d| Instant::now() >= d)
}

impl QpSettings {
    /// Whether the deadline has passed (never without one).
    pub fn out_of_time(&self) -> bool {
        passed(self.deadline)
    }

    /// The time left before the deadline (`None` without one; zero once it passed).
    pub fn time_left(&self) -> Option<Duration> {
        self.deadline.map(|d| d.saturating_duration_since(Instant::now()))
    }
}
