//! Real-time runs judged on a machine that had its processors. A virtual machine's host can
//! take its processors away for milliseconds at a time (steal): every process of the run stops,
//! the wall clock goes on, and the ticks of that time miss whatever the product does. Such a
//! run says nothing about the product's loop, so it is run again; a test whose every try the
//! host took more than [`MAX_STEAL`] of skips, and lists itself with the figures
//! ([`super::skip`]). Load from other processes (the busy loops CI runs beside the real-time
//! tests) is the kernel sharing the processors, not the host taking them: it counts against
//! the product.

use evaluation::records::Records;

/// The most of the processors' time the host may take from a real-time run for the run to be
/// judged (0.3 % over a day of builds and tests on this kind of machine).
pub const MAX_STEAL: f64 = 0.02;
/// Runs tried for one the host left its processors.
pub const TRIES: usize = 3;

/// `run` until the host took at most [`MAX_STEAL`] of the processors' time during a run (a
/// machine that does not give the figure counts as having taken nothing): that run's records
/// and what came with them. `None`, `test` listed as skipped, if the host took more in each of
/// [`TRIES`] runs.
pub fn on_its_processors<T>(
    test: &str,
    mut run: impl FnMut() -> (Records, T),
) -> Option<(Records, T)> {
    let mut stolen = Vec::new();
    for _ in 0..TRIES {
        let (records, with) = run();
        let steal = records.machine.map_or(0.0, |m| m.steal);
        if steal <= MAX_STEAL {
            return Some((records, with));
        }
        eprintln!(
            "{test}: the host took {:.1} % of the processors' time during the run; run again",
            steal * 100.0
        );
        stolen.push(format!("{:.1} %", steal * 100.0));
    }
    let why = format!("the host took {} of the processors' time in every try", stolen.join(", "));
    eprintln!("SKIPPED {test}: {why}");
    super::skip::record(test, &why);
    None
}
