//! One full tick of the paper's controller (assembly, projections, impedance, QP) for 2, 4
//! and 8 robots built from the real default robot. Besides criterion's estimates it prints
//! p50/p99 of the total and of each stage over 600/N ticks. `QP_PATH=...` chooses where the
//! QP's solve starts (`PidcConfig::qp_path`: `by-blocks`, the default; `active-set` builds the
//! team-sized QP on every tick, without the hot start by the robots' blocks; `dense-ipm`;
//! `clarabel`, Clarabel alone). `PROJECTIONS=dense` computes the projections by dense SVDs of
//! the team's matrices (`PidcConfig::projections`, the oracle; `by-blocks` is the default).

#[path = "../tests/common/mod.rs"]
mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

use coordinator::building_blocks::projection::ProjectionPath;
use coordinator::qp::QpPath;
use coordinator::{Pidc, PidcConfig};
use criterion::{criterion_group, criterion_main, Criterion};
use protocol::{DynamicsTerms, RobotDescription};

/// Counts heap allocations, to report what one tick allocates: in all, and inside faer's
/// decompositions (`coordinator::linalg::in_decomposition`).
struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);
static BYTES: AtomicU64 = AtomicU64::new(0);
static DECOMPOSITION_ALLOCS: AtomicU64 = AtomicU64::new(0);
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Relaxed);
        BYTES.fetch_add(l.size() as u64, Relaxed);
        if coordinator::linalg::in_decomposition() {
            DECOMPOSITION_ALLOCS.fetch_add(1, Relaxed);
        }
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
}
#[global_allocator]
static GLOBAL: Counting = Counting;

/// The `p`-th percentile of `v` (sorted in place).
fn pct(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[((p / 100.0) * (v.len() - 1) as f64).round() as usize]
}

/// The controller on the paths `QP_PATH` and `PROJECTIONS` name, told the robots' `descs`.
fn controller(descs: &[RobotDescription]) -> Pidc {
    let qp_path =
        std::env::var("QP_PATH").map_or(Ok(QpPath::default()), |s| s.parse()).expect("QP_PATH");
    let projections = std::env::var("PROJECTIONS")
        .map_or(Ok(ProjectionPath::default()), |s| s.parse())
        .expect("PROJECTIONS");
    let mut ctl = Pidc::new(PidcConfig { qp_path, projections, ..PidcConfig::default() });
    for d in descs {
        ctl.set_description(d);
    }
    ctl
}

/// Each stage's time over `ticks` ticks, us: total, assembly, projections, impedance, QP build
/// and QP solve.
fn stage_times(ctl: &mut Pidc, terms: &[DynamicsTerms], ticks: usize) -> Vec<Vec<f64>> {
    let mut stages: Vec<Vec<f64>> = vec![Vec::new(); 6];
    for _ in 0..ticks {
        let r = ctl.compute(terms).expect("tick");
        let t = &r.timing;
        for (k, x) in
            [t.total_us, t.assembly_us, t.projections_us, t.impedance_us, t.qp_build_us, t.qp_us]
                .into_iter()
                .enumerate()
        {
            stages[k].push(x);
        }
    }
    stages
}

/// Print what one tick of `count` robots allocates: in all, and inside faer's decompositions.
fn report_allocations(ctl: &mut Pidc, terms: &[DynamicsTerms], count: usize) {
    let (a0, b0, d0) =
        (ALLOCS.load(Relaxed), BYTES.load(Relaxed), DECOMPOSITION_ALLOCS.load(Relaxed));
    ctl.compute(terms).expect("tick");
    let (a1, b1, d1) =
        (ALLOCS.load(Relaxed), BYTES.load(Relaxed), DECOMPOSITION_ALLOCS.load(Relaxed));
    println!(
        "robots {count}: one tick allocates {} times, {:.0} kB in all; {} of them inside \
         faer's SVD/LU",
        a1 - a0,
        (b1 - b0) as f64 / 1024.0,
        d1 - d0
    );
}

fn bench(c: &mut Criterion) {
    let mut fx = common::Fixture::new();
    for &count in &[2usize, 4, 8] {
        let (terms, descs) = fx.static_team(count);
        let mut ctl = controller(&descs);
        ctl.compute(&terms).expect("tick");
        // Percentiles and breakdown.
        let mut stages = stage_times(&mut ctl, &terms, 600 / count);
        report_allocations(&mut ctl, &terms, count);
        let r = ctl.last().expect("last");
        let names = ["total", "assembly", "projections", "impedance", "QP build", "QP solve"];
        println!(
            "robots {count}: n {} F_c {} QP rows {} status {:?} by {} iterations {} projections \
             by {}",
            r.team.n,
            r.team.contact_rows(),
            r.qp.rows,
            r.qp.status,
            r.qp.solver,
            r.qp.iterations,
            if r.proj.by_blocks { "blocks" } else { "dense SVDs" }
        );
        for (k, name) in names.iter().enumerate() {
            let (p50, p99) = (pct(&mut stages[k], 50.0), pct(&mut stages[k], 99.0));
            println!("  {name:12} p50 {p50:9.1} us  p99 {p99:9.1} us");
        }
        c.bench_function(&format!("tick/{count}_robots"), |b| {
            b.iter(|| ctl.compute(&terms).map(|r| r.tau[0]).unwrap_or(0.0))
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(30)
        .measurement_time(std::time::Duration::from_secs(4));
    targets = bench
}
criterion_main!(benches);
