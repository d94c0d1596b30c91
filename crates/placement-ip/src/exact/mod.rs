//! Exact searches that prove placements optimal where CBC on the same IP stalls at large gaps,
//! one file per algorithm:
//! - [`counts`]: count-limited configurations with one radar (the paper's three);
//! - [`budget`]: the budgeted problem, decomposed into the count vectors the budget allows;
//! - [`lidar_first`]: count vectors with several radars and at most two LiDARs of one type;
//! - [`single`]: count vectors of one modality (LiDAR-only or radar-only rigs).
//!
//! This file holds what they share: the incumbent across threads and the deadline.

mod budget;
mod counts;
mod lidar_first;
mod single;

pub use budget::{counts_upper_bound, exact_budget, maximal_count_vectors, separable_upper_bound, top_visibilities};
pub use counts::exact_counts;
pub use lidar_first::exact_lidar_first;
pub use single::exact_single;

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Shared incumbent across threads.
pub(crate) struct Best {
    value_bits: AtomicU64,
    selection: Mutex<Vec<usize>>,
}

impl Best {
    fn value(&self) -> f64 {
        f64::from_bits(self.value_bits.load(Ordering::Relaxed))
    }

    fn offer(&self, f: f64, sel: &[usize]) {
        let mut guard = match self.selection.lock() {
            Ok(g) => g,
            Err(p) => p.into_inner(),
        };
        if f > self.value() + 1e-12 {
            self.value_bits.store(f.to_bits(), Ordering::Relaxed);
            *guard = sel.to_vec();
        }
    }
}

pub(crate) fn past(deadline: Option<Instant>) -> bool {
    deadline.is_some_and(|d| Instant::now() >= d)
}

/// Raises an atomic f64 (stored as bits) to at least `v`.
pub(crate) fn raise(a: &AtomicU64, v: f64) {
    let _ =
        a.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |bits| (v > f64::from_bits(bits)).then_some(v.to_bits()));
}

/// Statistics of a search.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SearchStats {
    pub radars_explored: usize,
    pub radars_total: usize,
    pub leaves_evaluated: u64,
}

/// When a search must stop: a deadline, or a node budget.
pub(crate) struct Stop {
    pub(crate) deadline: Option<Instant>,
    pub(crate) stopped: bool,
    pub(crate) nodes: u64,
    pub(crate) budget: u64,
}

impl Stop {
    /// Counts a node; true when the search must stop (the clock is read every 64 nodes).
    pub(crate) fn tick(&mut self) -> bool {
        self.nodes += 1;
        if self.nodes >= self.budget || (self.nodes.is_multiple_of(64) && past(self.deadline)) {
            self.stopped = true;
        }
        self.stopped
    }
}
