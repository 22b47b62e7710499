//! # experiments
//!
//! Experiments over many runs of the team, each run a scenario's plan through
//! [`launch::run`] and evaluated by [`evaluation`]:
//!
//! * [`compare`]: controllers side by side on the same scenarios (the paper's experiment S3)
//!   and the motion sweep; [`compare_plot`] draws its object-height figure.
//! * [`simulated_capacity`]: the heaviest object held in MuJoCo, by bisection over closed-loop
//!   runs, to measure the computed capacity against (`team capacity --simulate`).

pub mod compare;
pub mod compare_plot;
pub mod simulated_capacity;
