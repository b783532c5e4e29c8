//! Optimise a g2o 3-D pose graph with `mireg::graph::optimize` and write the result as g2o.
//!
//! `cargo run --release --example pose_graph_g2o -- IN.g2o OUT.g2o [--robust cauchy|geman-mcclure]
//! [--robust-all] [--scale K] [--anneal START] [--weights FILE] [--max-iterations N]
//! [--rel-tol R] [--abs-tol A]`
//!
//! With `--robust`, the kernel applies to the loop edges — every edge that is not odometry
//! (`to ≠ from + 1`); odometry edges stay Gaussian. With `--robust-all` it applies to every edge,
//! odometry included, as in `mireg::loops::optimize_trajectory` (Cauchy unless `--robust` names
//! another kernel). With `--anneal START` the graph is solved as `optimize_trajectory` solves it:
//! one solve per kernel scale, from `K · START / ANNEALING_FACTOR` down by
//! [`ANNEALING_FACTOR`] per solve to `K` (never below it), each solve from the last one's poses
//! (`optimize_trajectory` uses `START` = [`ANNEALING_START`]). Without it, one solve at `K`.
//! `--weights FILE` writes every edge's final IRLS weight, one per line, in the input's edge order.
//! Node 0 (the first vertex) is held fixed. A summary line per solve goes to stderr;
//! `tools/check_pose_graph_gtsam.py` compares the output with GTSAM.

use std::fmt::Write as _;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use mireg::graph::{GraphOptions, GraphSolution, PoseGraph, RobustKernel, g2o, optimize};
use mireg::loops::closure::{ANNEALING_FACTOR, ANNEALING_START};

fn value<T: std::str::FromStr>(args: &mut impl Iterator<Item = String>, flag: &str) -> Result<T> {
    let v = args
        .next()
        .with_context(|| format!("{flag} needs a value"))?;
    v.parse()
        .map_err(|_| anyhow::anyhow!("{flag}: cannot parse `{v}`"))
}

/// Which edges carry the kernel.
#[derive(Clone, Copy, PartialEq)]
enum Robust {
    None,
    Loops,
    All,
}

/// The kernel scales of the solves: `optimize_trajectory`'s schedule for `anneal = Some(START)`
/// (`K · START` divided by [`ANNEALING_FACTOR`] before each solve, floored at `K`, until a solve
/// at `K`), else `[K]`.
fn schedule(k: f64, anneal: Option<f64>) -> Vec<f64> {
    let Some(start) = anneal else {
        return vec![k];
    };
    let mut scales = Vec::new();
    let mut scale = k * start;
    loop {
        scale = (scale / ANNEALING_FACTOR).max(k);
        scales.push(scale);
        if scale <= k {
            return scales;
        }
    }
}

fn summary(graph: &PoseGraph, scale: f64, solution: &GraphSolution) -> String {
    format!(
        "nodes {} edges {} scale {scale} iterations {} converged {} cost {:.9e} -> {:.9e} \
         min edge weight {:.3e}",
        graph.poses.len(),
        graph.edges.len(),
        solution.iterations,
        solution.converged,
        solution.initial_cost,
        solution.final_cost,
        solution.edge_weights.iter().copied().fold(1.0, f64::min),
    )
}

fn run() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let mut paths = Vec::new();
    let mut options = GraphOptions::default();
    let mut robust = Robust::None;
    let mut anneal = None;
    let mut weights_path = None;
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--robust" => {
                if robust == Robust::None {
                    robust = Robust::Loops;
                }
                options.kernel = match value::<String>(&mut args, "--robust")?.as_str() {
                    "cauchy" => RobustKernel::Cauchy,
                    "geman-mcclure" => RobustKernel::GemanMcClure,
                    other => bail!("--robust: unknown kernel `{other}` (cauchy, geman-mcclure)"),
                };
            }
            "--robust-all" => robust = Robust::All,
            "--scale" => options.kernel_scale = value(&mut args, "--scale")?,
            "--anneal" => {
                let start: f64 = value(&mut args, "--anneal")?;
                if !(start.is_finite() && start > 0.0) {
                    bail!(
                        "--anneal: START must be finite and > 0 (optimize_trajectory: {ANNEALING_START})"
                    );
                }
                anneal = Some(start);
            }
            "--weights" => weights_path = Some(value::<String>(&mut args, "--weights")?),
            "--max-iterations" => options.max_iterations = value(&mut args, "--max-iterations")?,
            "--rel-tol" => options.relative_error_tol = value(&mut args, "--rel-tol")?,
            "--abs-tol" => options.absolute_error_tol = value(&mut args, "--abs-tol")?,
            _ if arg.starts_with("--") => bail!("unknown flag {arg}"),
            _ => paths.push(arg),
        }
    }
    let [input, output] = paths.as_slice() else {
        bail!(
            "usage: pose_graph_g2o IN.g2o OUT.g2o [--robust cauchy|geman-mcclure] [--robust-all] \
             [--scale K] [--anneal START] [--weights FILE] [--max-iterations N] [--rel-tol R] \
             [--abs-tol A]"
        );
    };
    if !(options.kernel_scale.is_finite() && options.kernel_scale > 0.0) {
        bail!("--scale must be finite and > 0");
    }
    let text = std::fs::read_to_string(input).with_context(|| format!("reading {input}"))?;
    let mut graph = g2o::read_g2o(&text).with_context(|| format!("parsing {input}"))?;
    for e in &mut graph.edges {
        e.robust = match robust {
            Robust::None => false,
            Robust::Loops => e.to != e.from + 1,
            Robust::All => true,
        };
    }
    let mut solution = None;
    for scale in schedule(options.kernel_scale, anneal) {
        let solve = GraphOptions {
            kernel_scale: scale,
            ..options.clone()
        };
        let s = optimize(&graph, &solve).with_context(|| format!("optimising {input}"))?;
        eprintln!("{}", summary(&graph, scale, &s));
        graph.poses.clone_from(&s.poses);
        solution = Some(s);
    }
    let solution = solution.context("no solve")?;
    if let Some(path) = weights_path {
        let mut text = String::new();
        for w in &solution.edge_weights {
            writeln!(text, "{w:.17e}")?;
        }
        std::fs::write(&path, text).with_context(|| format!("writing {path}"))?;
    }
    std::fs::write(output, g2o::write_g2o(&graph)).with_context(|| format!("writing {output}"))?;
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pose_graph_g2o: {e:#}");
            ExitCode::from(2)
        }
    }
}
