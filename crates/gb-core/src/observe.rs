//! One observer trait for long work across every crate: progress of a
//! computation and the iterations of the solver. Terminal user interfaces
//! (progress bars) implement it in the binary; the numerical crates only
//! report.
//!
//! `&self` methods, `Send + Sync`: one observer can be shared by fits that
//! run in parallel (an implementation that draws uses interior mutability).
//!
//! ```
//! use gb_core::{Observer, IterationInfo};
//! use std::sync::atomic::{AtomicUsize, Ordering};
//! struct Count(AtomicUsize);
//! impl Observer for Count {
//!     fn iteration(&self, _: &IterationInfo) { self.0.fetch_add(1, Ordering::Relaxed); }
//! }
//! let c = Count(AtomicUsize::new(0));
//! c.iteration(&IterationInfo { solver: "lm", iteration: 1, cost: 1.0, lambda: 1e-3, evaluations: 2 });
//! assert_eq!(c.0.load(Ordering::Relaxed), 1);
//! ```

/// One solver iteration, as reported to [`Observer::iteration`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IterationInfo {
    /// Which solver (e.g. `"levenberg-marquardt"`).
    pub solver: &'static str,
    /// Iteration number, 1-based.
    pub iteration: usize,
    /// Cost after the iteration.
    pub cost: f64,
    /// Damping parameter after the iteration (0 where the solver has none).
    pub lambda: f64,
    /// Cost evaluations so far (each a simulation).
    pub evaluations: usize,
}

/// Receives progress reports of long computations.
pub trait Observer: Send + Sync {
    /// `done` of `total` units of work finished; `message` says what runs now.
    fn progress(&self, done: usize, total: usize, message: &str) {
        let _ = (done, total, message);
    }
    /// A solver finished an iteration (called often: keep it cheap).
    fn iteration(&self, info: &IterationInfo) {
        let _ = info;
    }
}

/// An observer that ignores everything.
#[derive(Debug, Clone, Copy, Default)]
pub struct Silent;

impl Observer for Silent {}

/// Forwards [`Observer::iteration`] and maps [`Observer::progress`] of a
/// sub-task into the range `offset..offset + span` of an outer task of
/// `total` units, so a long fit inside one step of a loop moves the outer
/// progress bar.
#[derive(Clone, Copy)]
pub struct SubTask<'a> {
    /// The outer observer.
    pub outer: &'a dyn Observer,
    /// Units of the outer task done before this sub-task.
    pub offset: usize,
    /// Units of the outer task this sub-task stands for.
    pub span: usize,
    /// Units of the whole outer task.
    pub total: usize,
}

impl Observer for SubTask<'_> {
    fn progress(&self, done: usize, total: usize, message: &str) {
        let frac = if total == 0 {
            1.0
        } else {
            done.min(total) as f64 / total as f64
        };
        let d = self.offset + (frac * self.span as f64).floor() as usize;
        self.outer.progress(d.min(self.total), self.total, message);
    }
    fn iteration(&self, info: &IterationInfo) {
        self.outer.iteration(info);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[derive(Default)]
    struct Log(Mutex<Vec<(usize, usize)>>);
    impl Observer for Log {
        fn progress(&self, done: usize, total: usize, _: &str) {
            self.0.lock().unwrap().push((done, total));
        }
    }

    #[test]
    fn sub_task_maps_into_its_span() {
        let log = Log::default();
        let sub = SubTask {
            outer: &log,
            offset: 10,
            span: 20,
            total: 100,
        };
        sub.progress(0, 4, "a");
        sub.progress(2, 4, "b");
        sub.progress(4, 4, "c");
        sub.progress(9, 4, "overrun");
        assert_eq!(
            *log.0.lock().unwrap(),
            [(10, 100), (20, 100), (30, 100), (30, 100)]
        );
    }
}
