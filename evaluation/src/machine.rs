//! The machine a run had: how busy its processors were over the run and how much of their
//! time the host took (steal: a virtual machine's processor descheduled by its hypervisor).
//! A real-time run's misses mean something only on a machine that gave it its processors; the
//! summary names both figures beside the loop, and the real-time tests judge a run only when
//! the host stole little of it.
//!
//! Read from the kernel's processor counters (`/proc/stat`, Linux); elsewhere there is no
//! figure ([`CpuTimes::read`] gives `None`).

use serde::Serialize;

/// What the machine's processors did over a run, as shares of all their time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MachineLoad {
    /// Share of the processors' time spent running anything (this run and every other
    /// process), 0 to 1.
    pub busy: f64,
    /// Share of the processors' time the host took from this machine, 0 to 1.
    pub steal: f64,
}

impl MachineLoad {
    /// The summary's line.
    pub fn summary(&self) -> String {
        format!(
            "  machine: processors {:.0} % busy, {:.1} % of their time taken by the host\n",
            self.busy * 100.0,
            self.steal * 100.0
        )
    }
}

/// The kernel's processor counters at one moment, all processors summed, in clock ticks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CpuTimes {
    busy: u64,
    idle: u64,
    steal: u64,
}

impl CpuTimes {
    /// The counters now (`None` where the kernel does not give them).
    pub fn read() -> Option<CpuTimes> {
        let text = std::fs::read_to_string("/proc/stat").ok()?;
        CpuTimes::parse(&text)
    }

    /// The counters of `/proc/stat`'s first line (`cpu user nice system idle iowait irq
    /// softirq steal ...`).
    pub fn parse(stat: &str) -> Option<CpuTimes> {
        let line = stat.lines().next()?;
        let mut fields = line.split_whitespace();
        if fields.next()? != "cpu" {
            return None;
        }
        let v: Vec<u64> = fields.take(8).map(str::parse).collect::<Result<_, _>>().ok()?;
        let [user, nice, system, idle, iowait, irq, softirq, steal] = v[..] else {
            return None;
        };
        Some(CpuTimes { busy: user + nice + system + irq + softirq, idle: idle + iowait, steal })
    }

    /// What the processors did from `earlier` to these counters (`None` if no time passed
    /// or the counters went back).
    pub fn since(&self, earlier: &CpuTimes) -> Option<MachineLoad> {
        let busy = self.busy.checked_sub(earlier.busy)?;
        let idle = self.idle.checked_sub(earlier.idle)?;
        let steal = self.steal.checked_sub(earlier.steal)?;
        let total = busy + idle + steal;
        (total > 0).then(|| MachineLoad {
            busy: busy as f64 / total as f64,
            steal: steal as f64 / total as f64,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BEFORE: &str = "cpu  100 0 50 800 10 0 5 35 0 0\ncpu0 1 2 3 4 5 6 7 8 0 0\n";
    const AFTER: &str = "cpu  200 0 100 1000 10 0 5 85 0 0\n";

    #[test]
    fn shares_are_the_counters_differences_over_their_sum() {
        let (a, b) = (CpuTimes::parse(BEFORE).unwrap(), CpuTimes::parse(AFTER).unwrap());
        let m = b.since(&a).unwrap();
        // 150 busy, 200 idle, 50 stolen of 400.
        assert!((m.busy - 0.375).abs() < 1e-12, "{m:?}");
        assert!((m.steal - 0.125).abs() < 1e-12, "{m:?}");
        assert_eq!(a.since(&b), None, "counters that went back give no figure");
        assert_eq!(a.since(&a), None, "no time passed");
    }

    #[test]
    fn a_line_that_is_not_the_processors_total_gives_nothing() {
        assert_eq!(CpuTimes::parse("cpu0 1 2 3 4 5 6 7 8\n"), None);
        assert_eq!(CpuTimes::parse("cpu 1 2 3\n"), None);
        assert_eq!(CpuTimes::parse("cpu 1 2 x 4 5 6 7 8\n"), None);
        assert_eq!(CpuTimes::parse(""), None);
    }

    #[test]
    fn this_machine_gives_its_counters_where_it_is_linux() {
        if cfg!(target_os = "linux") {
            let a = CpuTimes::read().expect("/proc/stat");
            std::thread::sleep(std::time::Duration::from_millis(50));
            let b = CpuTimes::read().expect("/proc/stat");
            assert!(b.busy >= a.busy && b.idle >= a.idle && b.steal >= a.steal);
        }
    }
}
