//! Progress bars and messages on stderr: the binary's progress observer.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mvao::progress::Observer;

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
    // Warnings are printed even when quiet: they may explain a result.
    fn warn(&self, msg: &str) {
        eprintln!("warning: {msg}");
    }
    fn info(&self, msg: &str) {
        if !self.quiet {
            eprintln!("{msg}");
        }
    }
}
