//! The `mvao` binary: parse flags, run one command, print the error chain once, exit non-zero
//! on failure.

use clap::Parser;
use mvao::cli::{Cli, Command};
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("mvao: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Merge(args) => {
            let quiet = args.quiet;
            let cfg = args.into_config().map_err(anyhow::Error::msg)?;
            let report = mvao::pipeline::run(&cfg)?;
            if !quiet {
                eprintln!(
                    "{} scans, {} points in {:.2} s; {} without SSAO sample, {} with zero merge weight; results in {}",
                    report.scans.len(),
                    report.totals.points,
                    report.totals.wall_s,
                    report.totals.no_ssao_sample,
                    report.totals.zero_merge_weight,
                    cfg.out_dir.display()
                );
            }
            Ok(())
        }
        Command::Info(args) => {
            let info = mvao::info::describe(&args.scans, &args.place.options(), args.projection)?;
            if args.json {
                println!("{}", serde_json::to_string_pretty(&info)?);
            } else {
                print!("{}", info.to_text());
            }
            Ok(())
        }
        Command::Synth(args) => {
            let opts = args.into_options();
            let summary = mvao::synth::run(&opts)?;
            let points: usize = summary.files.iter().map(|f| f.points).sum();
            eprintln!(
                "{} {} scans of the {} scene ({} points) and {} written",
                summary.files.len(),
                summary.model,
                summary.scene,
                points,
                summary.alignment.display()
            );
            Ok(())
        }
    }
}
