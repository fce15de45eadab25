//! The terminal user interface of long work: an indicatif bar behind the
//! one observer trait of the library (`gb_core::Observer`). Hidden when
//! stdout or stderr is not a terminal or with `--quiet`.
use gb_core::{IterationInfo, Observer};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A progress bar (or a spinner for work of unknown length).
pub struct Bar(pub ProgressBar, std::sync::Mutex<String>);

impl Bar {
    /// A bar of `total` steps with a prefix, hidden when `quiet`.
    pub fn new(quiet: bool, total: usize, prefix: &str) -> Self {
        let pb = ProgressBar::new(total as u64);
        if quiet {
            pb.set_draw_target(ProgressDrawTarget::hidden());
        } else {
            pb.set_style(
                ProgressStyle::with_template(
                    "{spinner} {prefix}[{bar:20}] {pos}/{len} {msg} ({elapsed})",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            if !prefix.is_empty() {
                pb.set_prefix(format!("{prefix} "));
            }
            pb.enable_steady_tick(std::time::Duration::from_millis(120));
        }
        Self(pb, Default::default())
    }

    /// A spinner with a message, hidden when `quiet`.
    pub fn spinner(quiet: bool, msg: &str) -> Self {
        let pb = ProgressBar::new_spinner();
        if quiet {
            pb.set_draw_target(ProgressDrawTarget::hidden());
        } else {
            pb.enable_steady_tick(std::time::Duration::from_millis(120));
        }
        pb.set_message(msg.to_string());
        Self(pb, std::sync::Mutex::new(msg.to_string()))
    }

    /// Remove the bar from the terminal.
    pub fn finish(&self) {
        self.0.finish_and_clear();
    }
}

impl Observer for Bar {
    fn progress(&self, done: usize, total: usize, message: &str) {
        self.0.set_length(total as u64);
        self.0.set_position(done as u64);
        self.0.set_message(message.to_string());
        if let Ok(mut m) = self.1.lock() {
            *m = message.to_string();
        }
    }
    fn iteration(&self, info: &IterationInfo) {
        // keeps the bar alive during a long fit
        let base = self.1.lock().map(|m| m.clone()).unwrap_or_default();
        self.0.set_message(format!(
            "{base} ({} iteration {}, cost {:.3e})",
            info.solver, info.iteration, info.cost
        ));
    }
}

impl Drop for Bar {
    /// A bar never outlives its work on the terminal.
    fn drop(&mut self) {
        self.0.finish_and_clear();
    }
}
