//! The binary's side: flags, one function per subcommand, progress bars and printing. The
//! library computes and reports through its progress observer; only this module talks to the
//! terminal.

pub mod bars;
pub mod cli;
pub mod commands;
pub mod info;
pub mod stream;
