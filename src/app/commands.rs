//! One function per subcommand: build the configuration from the flags, run the library,
//! print the summary. The binary only parses flags and prints the error chain.

use super::bars::Bars;
use super::cli::{Command, EvalArgs, PlotArgs, SweepArgs};
use anyhow::Context as _;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mvao::config::ComputeParams;
use std::io::{IsTerminal as _, Write as _};

/// Runs one subcommand.
pub fn run(cmd: Command) -> anyhow::Result<()> {
    match cmd {
        Command::Merge(args) => {
            let quiet = args.quiet;
            let cfg = args.into_config().map_err(anyhow::Error::msg)?;
            let report = mvao::pipeline::run(&cfg, &Bars::new(quiet))?;
            if let (true, Some(plan)) = (cfg.dry_run, &report.plan) {
                println!("{}", plan.to_text());
            }
            if !quiet && !cfg.dry_run {
                eprintln!(
                    "{} scans, {} points in {:.2} s; {} without SSAO sample, {} with zero merge weight; results in {}",
                    report.scans.len(),
                    report.totals.points,
                    report.totals.wall_s,
                    report.totals.no_ssao_sample,
                    report.totals.zero_merge_weight,
                    cfg.out_dir.display()
                );
                if let Some(l) = &report.totals.ssao_levels {
                    eprintln!("SSAO pixels by evaluation level: {}", l.to_text());
                }
            }
            Ok(())
        }
        Command::Prepare(args) => {
            let quiet = args.quiet;
            let mut cfg = args.into_config().map_err(anyhow::Error::msg)?;
            cfg.prepare_only = true;
            let report = mvao::pipeline::run(&cfg, &Bars::new(quiet))?;
            if !quiet {
                eprintln!(
                    "products in {}; {:.2} s",
                    cfg.work_dir
                        .clone()
                        .unwrap_or_else(|| cfg.out_dir.join("work"))
                        .display(),
                    report.totals.wall_s
                );
            }
            Ok(())
        }
        Command::Info(args) => {
            let info = mvao::info::describe(&args.scans, &args.place.options(), args.projection)?;
            if args.json {
                println!("{}", serde_json::to_string_pretty(&info)?);
            } else {
                print!("{}", super::info::text(&info));
            }
            info.status()?;
            Ok(())
        }
        Command::Reference(args) => {
            let quiet = args.quiet;
            let cfg = args.into_config().map_err(anyhow::Error::msg)?;
            let bar = points_bar(quiet);
            let rep = mvao::accuracy::run_reference(&cfg, &|n| bar.inc(n))?;
            bar.finish_and_clear();
            if !quiet {
                let worst = rep
                    .scans
                    .iter()
                    .map(|s| s.convergence.mean_abs_diff_4r)
                    .fold(0.0f32, f32::max);
                eprintln!(
                    "{} scans, {} surfels, {} triangles; {} rays per point at {:.2} M rays/s; \
                     |A_R − A_4R| ≤ {worst:.4} (mean over a sample, worst scan); {:.1} s; in {}",
                    rep.scans.len(),
                    rep.surfels,
                    rep.triangles,
                    cfg.params.rays,
                    rep.rays_per_second / 1e6,
                    rep.wall_s,
                    cfg.out_dir.display()
                );
            }
            // The self-check is printed even when quiet: a failed one makes the reference
            // untrustworthy.
            for s in &rep.scans {
                if let Some(off) = s.off_surface {
                    if !quiet {
                        eprintln!(
                            "{}: {} of {} points within the tolerance of the surface; {off} off it, not scored",
                            s.name,
                            s.points - off,
                            s.points
                        );
                    }
                }
                let Some(c) = &s.self_check else { continue };
                if !quiet || !c.passed() {
                    eprintln!(
                        "{}: self-check {}: {} of {} sampled points open by the data, {} read below {} (lowest {:.3}); {:.1} % of rays met their own surface",
                        s.name,
                        if c.passed() { "passed" } else { "FAILED" },
                        c.open,
                        c.sample,
                        c.darkened,
                        mvao::OPEN_MIN_A,
                        c.min_open_a,
                        100.0 * c.mean_self_hit_share
                    );
                }
            }
            Ok(())
        }
        Command::Eval(args) => eval(args),
        Command::Sweep(args) => sweep(args),
        Command::Plot(args) => plot(args),
        Command::Stream(args) => super::stream::run(args),
        Command::Synth(args) if args.frames > 0 => super::stream::synth(args),
        Command::Synth(args) => {
            let opts = args.into_options().map_err(anyhow::Error::msg)?;
            let summary = mvao::synth::run(&opts)?;
            let points: usize = summary.files.iter().map(|f| f.points).sum();
            eprintln!(
                "{} {} scans of the {} scene ({} points) and {} written",
                summary.files.len(),
                summary.model,
                summary.label,
                points,
                summary.alignment.display()
            );
            Ok(())
        }
    }
}

/// A progress bar counting points on stderr (hidden when quiet or not a terminal).
fn points_bar(quiet: bool) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
    pb.set_style(
        ProgressStyle::with_template("{spinner} {human_pos} points {elapsed_precise} {per_sec}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    pb
}

fn eval(args: EvalArgs) -> anyhow::Result<()> {
    let acc = mvao::accuracy::eval_files(&args.reference, &args.results)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&acc)?);
    } else {
        for s in &acc.scans {
            println!("{}: {}", s.name, s.result.one_line());
        }
        println!("all: {}", acc.result.one_line());
    }
    if let Some(csv) = &args.csv {
        let points: usize = acc.result.n;
        let m = &acc.result;
        let f = |x: Option<f64>| x.map_or(String::new(), |v| format!("{v:.6}"));
        let row = format!(
            "{},{},{},0,{},0,0,,{},{},{:.4},{:.6},{:.6},{:.6},{},{:.6},{},{},{},{}\n",
            mvao::sweep::csv_field(&args.dataset),
            mvao::sweep::csv_field(&args.method),
            mvao::sweep::csv_field(&args.method),
            args.directions,
            args.tmax,
            points,
            args.wall_s,
            m.e_a,
            m.e_lt5,
            m.rmse,
            f(m.pearson_r),
            m.bias,
            m.shaded_n,
            f(m.shaded_e_a),
            f(m.skill),
            f(m.shaded_skill),
        );
        let new = !csv.exists();
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(csv)
            .with_context(|| format!("{}: cannot open for appending", csv.display()))?;
        if new {
            writeln!(file, "{}", mvao::sweep::CSV_COLUMNS.join(","))?;
        }
        file.write_all(row.as_bytes())
            .with_context(|| format!("{}: cannot append", csv.display()))?;
    }
    Ok(())
}

fn sweep(args: SweepArgs) -> anyhow::Result<()> {
    let mut grid = mvao::sweep::default_grid();
    if args.quick {
        grid.retain(|s| {
            matches!(
                (s.estimator, s.samples, s.directions, s.steps),
                (mvao::Estimator::Paper, 16 | 32, _, _)
                    | (mvao::Estimator::Horizon, _, 4, 4)
                    | (mvao::Estimator::Horizon, _, 8, 8)
            )
        });
        for s in &mut grid {
            s.neighbors = vec![1, 3];
        }
    }
    let cfg = mvao::sweep::SweepConfig {
        dataset: args.dataset,
        scans: args.scans,
        place: args.place.options(),
        reference: args.reference,
        out_dir: args.output,
        base: ComputeParams {
            radius: args.radius,
            tmax: args.tmax,
            falloff: args.falloff,
            seed: args.seed,
            sampling: args.sampling,
            ..ComputeParams::default()
        },
        grid,
        union_rays: args.union_rays,
        force: args.force,
    };
    let rows = mvao::sweep::run(&cfg, &|line| eprintln!("{line}"))?;
    eprintln!(
        "{} rows: {} and {}",
        rows.len(),
        cfg.out_dir.join("sweep.csv").display(),
        cfg.out_dir.join("sweep.svg").display()
    );
    Ok(())
}

fn plot(args: PlotArgs) -> anyhow::Result<()> {
    let out = args
        .output
        .unwrap_or_else(|| args.csv.with_extension("svg"));
    mvao::sweep::plot_csv(&args.csv, &out, &args.title)?;
    eprintln!("{}", out.display());
    Ok(())
}
