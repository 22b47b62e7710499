//! The per-tick path (compute_all_terms, frame Jacobians, Jdot v) allocates nothing after
//! start-up: a counting global allocator watches this thread.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use common::*;
use nalgebra::Matrix6xX;
use robot_model::*;

struct Counting;

thread_local! {
    static WATCH: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = WATCH.try_with(|w| {
            if w.get() {
                COUNT.with(|c| c.set(c.get() + 1));
            }
        });
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn per_tick_update_does_not_allocate() {
    let model = composed_model();
    let frames: Vec<FrameId> = ["LF_foot", "RF_foot", "LH_foot", "RH_foot", "arm_hand", "trunk"]
        .iter()
        .map(|f| model.frame_id(f).unwrap())
        .collect();
    let mut data = Data::new(&model);
    let mut jac = vec![Matrix6xX::zeros(model.nv); frames.len()];
    let mut r = rng(7);
    let states: Vec<_> = (0..10).map(|_| random_state(&model, &mut r)).collect();
    let mut checksum = 0.0;
    WATCH.with(|w| w.set(true));
    for (q, v) in &states {
        compute_all_terms(&model, &mut data, q.as_slice(), v.as_slice()).unwrap();
        for (k, &f) in frames.iter().enumerate() {
            frame_jacobian(&model, &data, f, &mut jac[k]).unwrap();
            checksum += frame_jdot_v(&model, &data, f).unwrap()[0];
        }
    }
    WATCH.with(|w| w.set(false));
    let n = COUNT.with(|c| c.get());
    assert_eq!(n, 0, "per-tick path allocated {n} times");
    assert!(checksum.is_finite());
    // the counter works: an allocation while watching is seen
    WATCH.with(|w| w.set(true));
    let v: Vec<u8> = Vec::with_capacity(16);
    WATCH.with(|w| w.set(false));
    drop(v);
    assert_eq!(COUNT.with(|c| c.get()), 1);
}
