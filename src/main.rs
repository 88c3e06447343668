//! The `mvao` binary: parse flags, run one command, print the error chain once, exit non-zero
//! on failure.

#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

mod app;

use app::cli::Cli;
use clap::Parser;
use std::process::ExitCode;

#[global_allocator]
static ALLOC: mvao::bigalloc::BigAlloc = mvao::bigalloc::BigAlloc;

fn main() -> ExitCode {
    let cli = Cli::parse();
    match app::commands::run(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("mvao: error: {e:#}");
            ExitCode::from(2)
        }
    }
}
