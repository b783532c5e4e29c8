//! Optimise a g2o 3-D pose graph with `mireg::graph::optimize` and write the result as g2o.
//!
//! `cargo run --release --example pose_graph_g2o -- IN.g2o OUT.g2o [--robust cauchy|geman-mcclure]
//! [--scale K] [--max-iterations N] [--rel-tol R] [--abs-tol A]`
//!
//! With `--robust`, the kernel applies to the loop edges — every edge that is not odometry
//! (`to ≠ from + 1`); odometry edges stay Gaussian. Node 0 (the first vertex) is held fixed.
//! A summary line goes to stderr; `tools/check_pose_graph_gtsam.py` compares the output with GTSAM.

use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use mireg::graph::{GraphOptions, RobustKernel, g2o, optimize};

fn value<T: std::str::FromStr>(args: &mut impl Iterator<Item = String>, flag: &str) -> Result<T> {
    let v = args
        .next()
        .with_context(|| format!("{flag} needs a value"))?;
    v.parse()
        .map_err(|_| anyhow::anyhow!("{flag}: cannot parse `{v}`"))
}

fn run() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let mut paths = Vec::new();
    let mut options = GraphOptions::default();
    let mut robust = false;
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--robust" => {
                robust = true;
                options.kernel = match value::<String>(&mut args, "--robust")?.as_str() {
                    "cauchy" => RobustKernel::Cauchy,
                    "geman-mcclure" => RobustKernel::GemanMcClure,
                    other => bail!("--robust: unknown kernel `{other}` (cauchy, geman-mcclure)"),
                };
            }
            "--scale" => options.kernel_scale = value(&mut args, "--scale")?,
            "--max-iterations" => options.max_iterations = value(&mut args, "--max-iterations")?,
            "--rel-tol" => options.relative_error_tol = value(&mut args, "--rel-tol")?,
            "--abs-tol" => options.absolute_error_tol = value(&mut args, "--abs-tol")?,
            _ if arg.starts_with("--") => bail!("unknown flag {arg}"),
            _ => paths.push(arg),
        }
    }
    let [input, output] = paths.as_slice() else {
        bail!(
            "usage: pose_graph_g2o IN.g2o OUT.g2o [--robust cauchy|geman-mcclure] [--scale K] \
             [--max-iterations N] [--rel-tol R] [--abs-tol A]"
        );
    };
    let text = std::fs::read_to_string(input).with_context(|| format!("reading {input}"))?;
    let mut graph = g2o::read_g2o(&text).with_context(|| format!("parsing {input}"))?;
    if robust {
        for e in &mut graph.edges {
            e.robust = e.to != e.from + 1;
        }
    }
    let solution = optimize(&graph, &options).with_context(|| format!("optimising {input}"))?;
    eprintln!(
        "nodes {} edges {} iterations {} converged {} cost {:.9e} -> {:.9e} min edge weight {:.3e}",
        graph.poses.len(),
        graph.edges.len(),
        solution.iterations,
        solution.converged,
        solution.initial_cost,
        solution.final_cost,
        solution.edge_weights.iter().copied().fold(1.0, f64::min),
    );
    graph.poses = solution.poses;
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
