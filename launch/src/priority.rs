//! The scheduling priority of a real-time run.
//!
//! A real-time run shares the machine with whatever else runs there; at the default priority a
//! busy process beside it takes the cores its loop needs (two busy loops beside the embedded
//! 250 Hz test: 33 and 6 of 500 ticks missed; raised to nice -10, 10 and 5). Like ros2_control's
//! controller manager, which asks for a real-time policy and goes on with a warning when it is
//! refused, a real-time run raises its priority where it may ([`raise`]); the team's processes
//! it starts afterwards inherit it. A nice value, not `SCHED_FIFO`: a real-time thread that
//! busy-waits, even briefly, would shut everything else out of its core.
//! With the kernel's autogroups on, nice ranks threads only within their session: load from
//! another session is not held back.
//!
//! Components started by hand keep the priority they were started with (`nice -n -10
//! robot-agent ...`, or systemd's `Nice=`).
//!
//! Work that is not the loop's (a recording's writer) runs below it, at [`BACKGROUND_NICE`], and
//! [`raise`] leaves such a thread there ([`background_thread`]).

use std::collections::BTreeSet;
use std::io;
use std::sync::Mutex;

/// The nice value of a real-time run's threads.
pub const REALTIME_NICE: i32 = -10;

/// The nice value of a background thread ([`background_thread`]).
pub const BACKGROUND_NICE: i32 = 10;

/// Thread ids of the background threads, which [`raise`] leaves alone.
static BACKGROUND: Mutex<BTreeSet<i64>> = Mutex::new(BTreeSet::new());

/// The calling thread, made a background thread by [`background_thread`], until this drops.
pub struct Background {
    tid: i64,
}

impl Drop for Background {
    fn drop(&mut self) {
        BACKGROUND.lock().unwrap_or_else(|e| e.into_inner()).remove(&self.tid);
    }
}

/// Run the calling thread at [`BACKGROUND_NICE`] (lowering a priority is always permitted) and
/// keep [`raise`] from raising it, while the returned guard lives. Elsewhere than on Linux it
/// changes nothing.
pub fn background_thread() -> Background {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: gettid takes nothing and cannot fail.
        let tid = unsafe { libc::gettid() };
        BACKGROUND.lock().unwrap_or_else(|e| e.into_inner()).insert(i64::from(tid));
        // SAFETY: setpriority takes plain integers; with PRIO_PROCESS a thread id names one thread.
        if unsafe { libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, BACKGROUND_NICE) } != 0
        {
            tracing::debug!(
                "background thread at its inherited priority: {}",
                io::Error::last_os_error()
            );
        }
        Background { tid: i64::from(tid) }
    }
    #[cfg(not(target_os = "linux"))]
    Background { tid: -1 }
}

fn is_background(tid: i64) -> bool {
    BACKGROUND.lock().unwrap_or_else(|e| e.into_inner()).contains(&tid)
}

#[derive(Debug, thiserror::Error)]
pub enum PriorityError {
    #[error(
        "not permitted to raise the scheduling priority to nice {nice} \
         (needs CAP_SYS_NICE, or an RLIMIT_NICE that allows it)"
    )]
    NotPermitted { nice: i32 },
    #[error("cannot list or set this process's threads: {0}")]
    Io(#[from] io::Error),
    #[error("scheduling priorities are set on Linux only")]
    Unsupported,
}

/// Set every thread of this process to nice `nice`, where it is not already at that priority
/// or higher. Threads made afterwards, and child processes, inherit it from their creator; a
/// thread made while the threads are being listed is caught by listing them again, until a
/// pass changes nothing. Returns how many threads were changed.
#[cfg(target_os = "linux")]
pub fn raise(nice: i32) -> Result<usize, PriorityError> {
    let mut changed = 0;
    for _ in 0..MAX_PASSES {
        let pass = raise_listed(nice)?;
        changed += pass;
        if pass == 0 {
            break;
        }
    }
    Ok(changed)
}

#[cfg(not(target_os = "linux"))]
pub fn raise(_nice: i32) -> Result<usize, PriorityError> {
    Err(PriorityError::Unsupported)
}

/// Passes over the thread list in [`raise`].
const MAX_PASSES: usize = 4;

/// One pass of [`raise`] over the threads listed now.
#[cfg(target_os = "linux")]
fn raise_listed(nice: i32) -> Result<usize, PriorityError> {
    let mut changed = 0;
    for entry in std::fs::read_dir("/proc/self/task")? {
        let Ok(tid) = entry?.file_name().to_string_lossy().parse::<libc::id_t>() else { continue };
        if is_background(i64::from(tid)) {
            continue;
        }
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
                Some(libc::EPERM) | Some(libc::EACCES) => {
                    return Err(PriorityError::NotPermitted { nice })
                }
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
        Ok(n) => tracing::info!(
            nice = REALTIME_NICE,
            threads = n,
            "real-time run: scheduling priority raised"
        ),
        Err(e) => tracing::warn!("real-time run at normal priority: {e}"),
    }
}

/// A thread's nice value as the kernel reports it.
#[cfg(target_os = "linux")]
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

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;
    use std::sync::mpsc;

    /// The calling thread's nice value as /proc reports it (field 19 of its `stat`).
    fn own_nice() -> i32 {
        let stat = std::fs::read_to_string("/proc/thread-self/stat").expect("stat");
        stat[stat.rfind(')').expect("comm") + 2..]
            .split(' ')
            .nth(16)
            .expect("nice")
            .parse()
            .expect("a number")
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
        let was = own_nice();
        match raise(-5) {
            Ok(changed) => {
                if was > -5 {
                    assert!(changed >= 2, "this thread and the waiting one: {changed}");
                }
                assert!(own_nice() <= -5, "this thread at nice {}", own_nice());
                let after = std::thread::spawn(own_nice).join().expect("thread");
                assert!(after <= -5, "a thread made afterwards inherits: {after}");
                go.send(()).expect("send");
                let raised = told.recv().expect("told");
                assert!(raised <= -5, "the thread made before was raised: {raised}");
                assert_eq!(raise(0).expect("raise"), 0, "a lower priority is never set");
                assert!(own_nice() <= -5);
            }
            Err(PriorityError::NotPermitted { nice }) => {
                assert_eq!(nice, -5);
                assert_eq!(own_nice(), was, "refused, nothing changed");
                go.send(()).expect("send");
                assert_eq!(told.recv().expect("told"), was);
            }
            Err(e) => panic!("{e}"),
        }
        before.join().expect("thread");
    }

    #[test]
    fn a_background_thread_runs_below_and_raising_leaves_it_there() {
        let (go, wait) = mpsc::channel::<()>();
        let (tell, told) = mpsc::channel();
        let bg = std::thread::spawn(move || {
            let guard = background_thread();
            tell.send(own_nice()).ok();
            wait.recv().ok();
            tell.send(own_nice()).ok();
            guard.tid
        });
        assert_eq!(told.recv().expect("told"), BACKGROUND_NICE, "lowered at once");
        match raise(-5) {
            Ok(_) => assert!(own_nice() <= -5, "the other threads were raised"),
            Err(PriorityError::NotPermitted { .. }) => {}
            Err(e) => panic!("{e}"),
        }
        go.send(()).expect("send");
        assert_eq!(
            told.recv().expect("told"),
            BACKGROUND_NICE,
            "the raise left the background thread alone"
        );
        let tid = bg.join().expect("thread");
        assert!(!is_background(tid), "the ended thread is no longer skipped");
    }
}
