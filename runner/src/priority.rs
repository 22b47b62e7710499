//! The scheduling priority of a real-time run.
//!
//! A real-time run shares the machine with whatever else runs there; at the default priority a
//! busy process beside it takes the cores its loop needs (two busy loops beside the embedded
//! 250 Hz test: 33 of 500 ticks missed; at nice -10, 2 of 500). Like ros2_control's controller
//! manager, which asks for a real-time policy and goes on with a warning when it is refused, a
//! real-time run raises its priority where it may ([`raise`]); the team's processes it starts
//! afterwards inherit it. A nice value, not `SCHED_FIFO`: a real-time thread that spins (the
//! bridge polls its last millisecond) would shut everything else out of its core.
//!
//! Components started by hand keep the priority they were started with (`nice -n -10
//! robot-agent ...`, or systemd's `Nice=`).

use std::io;

/// The nice value of a real-time run's threads.
pub const REALTIME_NICE: i32 = -10;

#[derive(Debug, thiserror::Error)]
pub enum PriorityError {
    #[error("not permitted to raise the scheduling priority to nice {nice} (needs root or CAP_SYS_NICE)")]
    NotPermitted { nice: i32 },
    #[error("cannot list or set this process's threads: {0}")]
    Io(#[from] io::Error),
}

/// Set every thread of this process to nice `nice`, where it is not already at that priority
/// or higher. Threads made afterwards, and child processes, inherit it from their creator.
/// Returns how many threads were changed.
pub fn raise(nice: i32) -> Result<usize, PriorityError> {
    let mut changed = 0;
    for entry in std::fs::read_dir("/proc/self/task")? {
        let Ok(tid) = entry?.file_name().to_string_lossy().parse::<libc::id_t>() else { continue };
        match thread_nice(tid) {
            Ok(now) if now <= nice => continue,
            Ok(_) => {}
            Err(e) if e.raw_os_error() == Some(libc::ESRCH) => continue, // the thread ended
            Err(e) => return Err(e.into()),
        }
        // SAFETY: setpriority takes plain integers; with PRIO_PROCESS a thread id names one thread.
        if unsafe { libc::setpriority(libc::PRIO_PROCESS, tid, nice) } != 0 {
            let e = io::Error::last_os_error();
            match e.raw_os_error() {
                Some(libc::ESRCH) => continue,
                Some(libc::EPERM) | Some(libc::EACCES) => return Err(PriorityError::NotPermitted { nice }),
                _ => return Err(e.into()),
            }
        }
        changed += 1;
    }
    Ok(changed)
}

/// [`raise`] to [`REALTIME_NICE`], logging the outcome: a run that may not raise it goes on at
/// its priority with a warning.
pub fn raise_for_realtime() {
    match raise(REALTIME_NICE) {
        Ok(n) => tracing::info!(nice = REALTIME_NICE, threads = n, "real-time run: scheduling priority raised"),
        Err(e) => tracing::warn!("real-time run at normal priority: {e}"),
    }
}

/// A thread's nice value as the kernel reports it.
fn thread_nice(tid: libc::id_t) -> io::Result<i32> {
    // getpriority returns -1 both as a value and as an error: errno tells them apart.
    // SAFETY: errno is thread-local; getpriority takes plain integers.
    unsafe { *libc::__errno_location() = 0 };
    let n = unsafe { libc::getpriority(libc::PRIO_PROCESS, tid) };
    let e = io::Error::last_os_error();
    if n == -1 && e.raw_os_error().is_some_and(|c| c != 0) {
        return Err(e);
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    /// Every thread's nice value as /proc reports it (field 19 of its `stat`).
    fn nice_values() -> Vec<(String, i32)> {
        std::fs::read_dir("/proc/self/task")
            .expect("tasks")
            .filter_map(|e| {
                let tid = e.ok()?.file_name().to_string_lossy().into_owned();
                let stat = std::fs::read_to_string(format!("/proc/self/task/{tid}/stat")).ok()?;
                let after = &stat[stat.rfind(')')? + 2..];
                Some((tid, after.split(' ').nth(16)?.parse().ok()?))
            })
            .collect()
    }

    fn own_nice() -> i32 {
        let stat = std::fs::read_to_string("/proc/thread-self/stat").expect("stat");
        stat[stat.rfind(')').unwrap() + 2..].split(' ').nth(16).unwrap().parse().unwrap()
    }

    #[test]
    fn raising_reaches_every_thread_and_what_they_start_and_never_lowers_it() {
        // A thread that exists before the raise, waiting.
        let (go, wait) = mpsc::channel::<()>();
        let (tell, told) = mpsc::channel();
        let before = std::thread::spawn(move || {
            wait.recv().ok();
            tell.send(own_nice()).ok();
        });
        match raise(-5) {
            Ok(changed) => {
                assert!(changed >= 2, "this thread and the waiting one: {changed}");
                for (tid, n) in nice_values() {
                    assert!(n <= -5, "thread {tid} at nice {n}");
                }
                let after = std::thread::spawn(own_nice).join().unwrap();
                assert!(after <= -5, "a thread made afterwards inherits: {after}");
                go.send(()).unwrap();
                assert!(told.recv().unwrap() <= -5, "the thread made before was raised");
                assert_eq!(raise(0).unwrap(), 0, "a lower priority is never set");
                assert!(own_nice() <= -5);
            }
            Err(PriorityError::NotPermitted { nice }) => {
                assert_eq!(nice, -5);
                // SAFETY: geteuid has no preconditions.
                assert_ne!(unsafe { libc::geteuid() }, 0, "root may raise it");
                go.send(()).unwrap();
            }
            Err(e) => panic!("{e}"),
        }
        before.join().unwrap();
    }
}
