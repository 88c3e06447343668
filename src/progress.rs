//! Progress, timing and messages of the stages, so a computation runs with bars on a terminal
//! or silently in a test: the library never prints, the caller's observer decides.

/// Stage hooks: progress and timing, so the computation can run with or without bars.
pub trait Observer: Sync {
    /// A stage starts with `total` units of work.
    fn stage(&self, _name: &str, _total: u64) {}
    /// `n` more units are done.
    fn advance(&self, _n: u64) {}
    /// A stage ended after `secs` seconds.
    fn done(&self, _name: &str, _secs: f64) {}
    /// Something the user should know that does not stop the run (also kept in the report).
    fn warn(&self, _msg: &str) {}
    /// A summary line: the parameters chosen, accuracy against a reference.
    fn info(&self, _msg: &str) {}
}

/// An observer that does nothing (tests, library use).
pub struct Silent;
impl Observer for Silent {}
