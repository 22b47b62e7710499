//! The capacity found in MuJoCo: the heaviest object a run holds with every acceptance check
//! passed, by bisection on the mass in closed-loop simulation, to set against the team
//! problem's capacity (`team capacity SCENARIO --simulate`).
//!
//! Each trial is the scenario at one mass, planned without the payload check and run embedded
//! in lockstep. Two answers come from the same trials ([`Criterion`]): the heaviest object
//! *held* (every acceptance check passed) and the heaviest *tracked* (held, and the motion
//! never yielded: the contacts carried the reference's motion at every tick, which is what the
//! computed capacity promises). Above the tracked mass the controller scales the motion down on
//! some ticks, and the run may still pass its checks. The search starts at the computed
//! capacity, steps by a tenth of it up (while held) or down (while not) until one trial of each
//! kind brackets the answer, then halves the bracket to `tolerance` kg. It assumes what the
//! trials show in practice: a run that holds a mass holds every lighter one.

use std::path::Path;

use evaluation::evaluate;
use launch::run::{self, RunError, RunOptions};
use scenario::file::Scenario;
use scenario::plan::{self, PlanError};

/// What a trial must show to count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Criterion {
    /// Every acceptance check passed.
    Held,
    /// Held, and the motion never yielded.
    Tracked,
}

/// One run at one mass.
#[derive(Debug, Clone, PartialEq)]
pub struct Trial {
    pub mass: f64,
    /// Every acceptance check passed.
    pub held: bool,
    /// Control ticks on which the motion yielded (the contacts could not carry it).
    pub yielded: u64,
    /// The object was dropped (the other failures are tracking bounds, a yield held still).
    pub dropped: bool,
    /// The checks that failed.
    pub failed: Vec<String>,
}

impl Trial {
    pub fn meets(&self, c: Criterion) -> bool {
        match c {
            Criterion::Held => self.held,
            Criterion::Tracked => self.held && self.yielded == 0,
        }
    }
}

/// The result of the search.
#[derive(Debug, Clone)]
pub struct SimulatedCapacity {
    pub criterion: Criterion,
    /// The heaviest mass that meets `criterion` (`None`: not even the lightest tried).
    pub held: Option<f64>,
    /// The lightest mass that does not (`None`: every mass tried up to twice the computed one).
    pub failed_at: Option<f64>,
    /// Every trial, in the order run.
    pub trials: Vec<Trial>,
}

/// Why the search could not run a trial.
#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    #[error("the computed capacity {0} kg must be positive and finite")]
    Capacity(f64),
    #[error("planning at {mass:.3} kg: {source}")]
    Plan { mass: f64, source: Box<PlanError> },
    #[error("running at {mass:.3} kg: {source}")]
    Run { mass: f64, source: Box<RunError> },
}

/// The search of the module docs for `criterion` over `trial`, from the computed capacity
/// `computed` (kg), to `tolerance` kg, with at most `max_trials` trials.
pub fn bisect<E: From<SimulateError>>(
    computed: f64,
    tolerance: f64,
    max_trials: usize,
    criterion: Criterion,
    mut trial: impl FnMut(f64) -> Result<Trial, E>,
) -> Result<SimulatedCapacity, E> {
    if !(computed.is_finite() && computed > 0.0) {
        return Err(SimulateError::Capacity(computed).into());
    }
    let step = 0.1 * computed;
    let mut trials: Vec<Trial> = Vec::new();
    let (mut held, mut failed_at): (Option<f64>, Option<f64>) = (None, None);
    let mut mass = computed;
    // Bracket: up while held (to twice the computed), down while not (to a tenth).
    while trials.len() < max_trials {
        let t = trial(mass)?;
        let ok = t.meets(criterion);
        trials.push(t);
        if ok {
            held = Some(mass);
        } else {
            failed_at = Some(mass);
        }
        match (held, failed_at) {
            (Some(_), Some(_)) => break,
            (Some(_), None) if mass + step <= 2.0 * computed + 1e-12 => mass += step,
            (None, Some(_)) if mass - step >= 0.1 * computed - 1e-12 => mass -= step,
            _ => return Ok(SimulatedCapacity { criterion, held, failed_at, trials }),
        }
    }
    while let (Some(lo), Some(hi)) = (held, failed_at) {
        if hi - lo <= tolerance || trials.len() >= max_trials {
            break;
        }
        let mid = 0.5 * (lo + hi);
        let t = trial(mid)?;
        if t.meets(criterion) {
            held = Some(mid);
        } else {
            failed_at = Some(mid);
        }
        trials.push(t);
    }
    Ok(SimulatedCapacity { criterion, held, failed_at, trials })
}

/// Both searches ([`Criterion::Held`], then [`Criterion::Tracked`]) over the same trials: a
/// mass run once is not run again.
pub fn held_and_tracked<E: From<SimulateError>>(
    computed: f64,
    tolerance: f64,
    max_trials: usize,
    mut trial: impl FnMut(f64) -> Result<Trial, E>,
) -> Result<[SimulatedCapacity; 2], E> {
    let mut done: Vec<Trial> = Vec::new();
    let mut once = |mass: f64| -> Result<Trial, E> {
        if let Some(t) = done.iter().find(|t| (t.mass - mass).abs() < 1e-9) {
            return Ok(t.clone());
        }
        let t = trial(mass)?;
        done.push(t.clone());
        Ok(t)
    };
    let held = bisect(computed, tolerance, max_trials, Criterion::Held, &mut once)?;
    let tracked = bisect(computed, tolerance, max_trials, Criterion::Tracked, &mut once)?;
    Ok([held, tracked])
}

/// One trial: `scenario` at `mass` kg, planned without the payload check and run embedded in
/// lockstep; its report goes to `out`.
pub fn run_trial(
    scenario: &Scenario,
    root: &Path,
    mass: f64,
    out: &Path,
) -> Result<Trial, SimulateError> {
    let mut s = scenario.clone();
    s.object.mass = mass;
    s.capacity_check = false;
    let p = match plan::plan(&s, root) {
        Ok(p) => p,
        // A mass the walk's planner refuses is not held (it would not be run).
        Err(e @ PlanError::Walk(_)) => {
            return Ok(Trial {
                mass,
                held: false,
                yielded: 0,
                dropped: false,
                failed: vec![format!("plan: {e}")],
            })
        }
        Err(e) => return Err(SimulateError::Plan { mass, source: Box::new(e) }),
    };
    let opts = RunOptions { distributed: false, hosts: false, progress: false, loss: Vec::new() };
    let records =
        run::run(&p, &opts, out).map_err(|e| SimulateError::Run { mass, source: Box::new(e) })?;
    let eval = evaluate::evaluate(&p, &records, "embedded");
    let m = &eval.metrics;
    let yielded = m.motion_yield.as_ref().map_or(0, |y| y.ticks);
    Ok(Trial {
        mass,
        held: m.passed,
        yielded,
        dropped: m.drop.dropped,
        failed: m.checks.iter().filter(|c| !c.passed).map(|c| c.name.clone()).collect(),
    })
}

/// The search's result as `team capacity --simulate` prints it.
pub fn summary(sim: &SimulatedCapacity, computed: f64) -> String {
    let (name, title) = match sim.criterion {
        Criterion::Held => ("held", "every acceptance check passed"),
        Criterion::Tracked => ("tracked", "held, and the motion never yielded"),
    };
    let mut out = format!("in MuJoCo ({title}), by trial:\n");
    for t in &sim.trials {
        let what = if t.held && t.yielded > 0 {
            format!("held, the motion yielding on {} ticks", t.yielded)
        } else if t.held {
            "held".to_string()
        } else if t.dropped {
            "dropped".to_string()
        } else {
            format!("failed {}", t.failed.join(", "))
        };
        out += &format!("  {:.3} kg ({:.0} %): {what}\n", t.mass, 100.0 * t.mass / computed);
    }
    let kg = |m: Option<f64>| m.map_or("-".to_string(), |m| format!("{m:.3} kg"));
    out += &format!(
        "{name} in MuJoCo: {} (not at {}); {name} / computed = {}\n",
        kg(sim.held),
        kg(sim.failed_at),
        sim.held.map_or("-".to_string(), |h| format!("{:.3}", h / computed))
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn threshold(limit: f64) -> impl FnMut(f64) -> Result<Trial, SimulateError> {
        move |mass| {
            Ok(Trial {
                mass,
                held: mass <= limit,
                yielded: 0,
                dropped: mass > limit,
                failed: Vec::new(),
            })
        }
    }

    #[test]
    fn the_search_brackets_the_threshold_from_either_side() {
        for limit in [0.37, 0.93, 1.0, 1.234, 1.61] {
            let s = bisect(1.0, 0.005, 40, Criterion::Held, threshold(limit)).expect("search");
            let (lo, hi) = (s.held.expect("held"), s.failed_at.expect("failed"));
            assert!(lo <= limit && hi > limit && hi - lo <= 0.005, "limit {limit}: [{lo}, {hi}]");
            assert!(s.trials.iter().all(|t| t.held == (t.mass <= limit)));
        }
    }

    #[test]
    fn the_search_stops_at_its_ends_and_its_trial_budget() {
        let all =
            bisect(1.0, 0.005, 40, Criterion::Held, threshold(f64::INFINITY)).expect("search");
        assert_eq!(all.failed_at, None);
        assert!((all.held.expect("held") - 2.0).abs() < 1e-9, "{:?}", all.held);
        let none = bisect(1.0, 0.005, 40, Criterion::Held, threshold(0.0)).expect("search");
        assert_eq!(none.held, None);
        assert!(none.failed_at.expect("failed") < 0.11);
        let short = bisect(1.0, 1e-9, 5, Criterion::Held, threshold(0.5)).expect("search");
        assert_eq!(short.trials.len(), 5);
        assert!(matches!(
            bisect(0.0, 0.01, 5, Criterion::Held, threshold(1.0)),
            Err(SimulateError::Capacity(_))
        ));
    }

    #[test]
    fn both_searches_share_their_trials_and_tracking_needs_no_yield() {
        // Held up to 1.2 kg, the motion yields above 0.9 kg.
        let mut runs = 0;
        let trial = |mass: f64| {
            runs += 1;
            Ok::<_, SimulateError>(Trial {
                mass,
                held: mass <= 1.2,
                yielded: if mass > 0.9 { 10 } else { 0 },
                dropped: mass > 1.2,
                failed: Vec::new(),
            })
        };
        let [held, tracked] = held_and_tracked(1.0, 0.005, 40, trial).expect("search");
        let (h, t) = (held.held.expect("held"), tracked.held.expect("tracked"));
        assert!(h <= 1.2 && held.failed_at.expect("failed") > 1.2, "held {h}");
        assert!(
            t <= 0.9
                && tracked.failed_at.expect("not tracked") > 0.9
                && tracked.failed_at.expect("not tracked") - t <= 0.005,
            "tracked {t}"
        );
        assert_eq!(
            runs,
            held.trials.len() + tracked.trials.len() - 1,
            "the first mass, 1.0 kg, is run once"
        );
    }
}
