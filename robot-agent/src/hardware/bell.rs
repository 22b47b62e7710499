//! The loop's wake-up: every input of the robot's loop (its states, when the robot sends them,
//! and the team's commands, contact sets and coordinator presence) rings one [`Bell`] when
//! something arrives, and the loop waits on it with a deadline. One flag and one condition
//! variable: ringing never blocks for longer than the flag's lock, waiting allocates nothing.

use std::sync::{Arc, Condvar, Mutex};
use std::time::Instant;

/// A shared wake-up flag. Clones ring the same bell.
#[derive(Debug, Clone, Default)]
pub struct Bell {
    inner: Arc<(Mutex<bool>, Condvar)>,
}

impl Bell {
    pub fn new() -> Self {
        Bell::default()
    }

    /// Something arrived: wake the waiting loop (or the next wait returns at once).
    pub fn ring(&self) {
        let (flag, cv) = &*self.inner;
        *flag.lock().unwrap_or_else(|p| p.into_inner()) = true;
        cv.notify_one();
    }

    /// Wait until the bell rings or until `deadline`, and clear it. Whether it rang.
    pub fn wait_until(&self, deadline: Instant) -> bool {
        let (flag, cv) = &*self.inner;
        let mut rung = flag.lock().unwrap_or_else(|p| p.into_inner());
        while !*rung {
            let Some(left) = deadline.checked_duration_since(Instant::now()) else { break };
            if left.is_zero() {
                break;
            }
            rung = match cv.wait_timeout(rung, left) {
                Ok((g, _)) => g,
                Err(p) => p.into_inner().0,
            };
        }
        std::mem::replace(&mut *rung, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_ring_before_the_wait_is_not_lost_and_a_silent_bell_times_out() {
        let bell = Bell::new();
        bell.ring();
        assert!(bell.wait_until(Instant::now() + Duration::from_secs(5)));
        let t0 = Instant::now();
        assert!(!bell.wait_until(t0 + Duration::from_millis(20)));
        assert!(t0.elapsed() >= Duration::from_millis(20));
        let other = bell.clone();
        let ringer = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(10));
            other.ring();
        });
        assert!(bell.wait_until(Instant::now() + Duration::from_secs(5)));
        ringer.join().unwrap();
    }
}
