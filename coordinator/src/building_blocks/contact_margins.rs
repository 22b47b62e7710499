//! [`ContactMargins`]: how much of each contact the controllers and the capacity check may
//! use: the minimum normal forces and the shares of friction and of the palm's patch. PIDC,
//! MQP and the static team problem ([`crate::capacity`]) build the same contact rows from them
//! ([`super::contacts::contact_list`]).

use crate::ControllerError;

/// The contact parameters of a controller (its TOML keys are the controller's own:
/// `f_min_foot`, `f_min_hand`, `friction_margin`, `patch_margin`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactMargins {
    /// Minimum normal force of every stance foot, N.
    pub f_min_foot: f64,
    /// Minimum normal force of every hand (the least squeeze), N.
    pub f_min_hand: f64,
    /// Share of each contact's friction the rows may use (`mu` and `xi` are scaled by it).
    pub friction_margin: f64,
    /// Share of the palm's half-sizes the centre of pressure may use.
    pub patch_margin: f64,
}

impl Default for ContactMargins {
    /// The controllers' defaults: 5 N per foot, 30 N per hand, the inscribed friction pyramid
    /// (`1/sqrt(2)`), half the palm.
    fn default() -> Self {
        ContactMargins {
            f_min_foot: 5.0,
            f_min_hand: 30.0,
            friction_margin: std::f64::consts::FRAC_1_SQRT_2,
            patch_margin: 0.5,
        }
    }
}

/// The share of the palm's half-sizes the centre of pressure may use on the reserve (the
/// whole palm let a beam held still at its limit slide out within 0.7 s in MuJoCo; three
/// quarters held it).
pub const RESERVE_PATCH: f64 = 0.75;

impl ContactMargins {
    /// The margins' reserve, which a team holding an object uses only to hold it still when
    /// nothing is feasible within the margins (`crate::pidc::stages::yielding`): the centre of
    /// pressure may use [`RESERVE_PATCH`] of the palm and the squeeze may drop to half its
    /// minimum; the friction share and the feet's minimum stay (they are what keeps the contacts
    /// from sliding and the feet on the ground).
    pub fn reserve(&self) -> ContactMargins {
        ContactMargins {
            f_min_hand: 0.5 * self.f_min_hand,
            patch_margin: self.patch_margin.max(RESERVE_PATCH),
            ..*self
        }
    }

    /// Minimum forces finite and non-negative, margins in `(0, 1]` (the error names the field).
    pub fn check(&self) -> Result<(), ControllerError> {
        self.check_forces()?;
        self.check_margins()
    }

    /// `f_min_foot` and `f_min_hand` finite and non-negative.
    pub fn check_forces(&self) -> Result<(), ControllerError> {
        for (what, x) in [("f_min_foot", self.f_min_foot), ("f_min_hand", self.f_min_hand)] {
            if !(x.is_finite() && x >= 0.0) {
                return Err(ControllerError::Config(format!(
                    "{what}: {x} must be finite and non-negative"
                )));
            }
        }
        Ok(())
    }

    /// `friction_margin` and `patch_margin` in `(0, 1]`.
    pub fn check_margins(&self) -> Result<(), ControllerError> {
        for (what, x) in
            [("friction_margin", self.friction_margin), ("patch_margin", self.patch_margin)]
        {
            if !(x.is_finite() && x > 0.0 && x <= 1.0) {
                return Err(ControllerError::Config(format!("{what}: {x} must be in (0, 1]")));
            }
        }
        Ok(())
    }
}
