//! Progress and timing hooks of the stages, so a computation runs with bars on a terminal or
//! silently in a test.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Stage hooks: progress and timing, so the computation can run with or without bars.
pub trait Observer: Sync {
    /// A stage starts with `total` units of work.
    fn stage(&self, _name: &str, _total: u64) {}
    /// `n` more units are done.
    fn advance(&self, _n: u64) {}
    /// A stage ended after `secs` seconds.
    fn done(&self, _name: &str, _secs: f64) {}
}

/// An observer that does nothing (tests, library use).
pub struct Silent;
impl Observer for Silent {}

/// Progress bars on stderr (one per stage), silent with `-q` or when stderr is not a terminal.
pub struct Bars {
    quiet: bool,
    bar: std::sync::Mutex<Option<ProgressBar>>,
}

impl Bars {
    /// Bars on stderr, none when `quiet`.
    pub fn new(quiet: bool) -> Bars {
        Bars {
            quiet,
            bar: std::sync::Mutex::new(None),
        }
    }
}

impl Observer for Bars {
    fn stage(&self, name: &str, total: u64) {
        if self.quiet {
            return;
        }
        let pb = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
        pb.set_style(
            ProgressStyle::with_template(
                "{prefix:>8} [{bar:40}] {human_pos}/{human_len} points {elapsed_precise} ETA {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        pb.set_prefix(name.to_string());
        if let Ok(mut b) = self.bar.lock() {
            *b = Some(pb);
        }
    }
    fn advance(&self, n: u64) {
        if let Ok(b) = self.bar.lock() {
            if let Some(pb) = b.as_ref() {
                pb.inc(n);
            }
        }
    }
    fn done(&self, _name: &str, _secs: f64) {
        if let Ok(mut b) = self.bar.lock() {
            if let Some(pb) = b.take() {
                pb.finish();
            }
        }
    }
}
