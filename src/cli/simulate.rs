//! `mireg simulate`: the paper's sampling simulation (Zhang & Chen, Fig. 5).

use std::io::Write;

use anyhow::{Context, Result};
use clap::Args;

use crate::simulate::{CSV_HEADER, SimulationConfig, SimulationRow, simulate};

/// Arguments of `mireg simulate`.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Budgets ≤ 1e4 and 5 runs: finishes in seconds.
    #[arg(long)]
    pub quick: bool,
    /// Print CSV instead of a table.
    #[arg(long)]
    pub csv: bool,
    /// Monte Carlo runs per cell [default: 20, or 5 with --quick].
    #[arg(long, value_name = "N")]
    pub runs: Option<usize>,
    /// Seed of all randomness.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

pub(super) fn run_simulate(args: &SimulateArgs) -> Result<()> {
    let mut config = if args.quick {
        SimulationConfig::quick()
    } else {
        SimulationConfig::default()
    };
    if let Some(runs) = args.runs {
        config.runs = runs;
    }
    config.seed = args.seed;
    let rows = simulate(&config).context("simulation failed")?;
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if args.csv {
        writeln!(out, "{CSV_HEADER}")?;
        for row in &rows {
            writeln!(out, "{}", row.to_csv())?;
        }
    } else {
        write_table(&mut out, &rows)?;
    }
    Ok(())
}

fn write_table(out: &mut impl Write, rows: &[SimulationRow]) -> std::io::Result<()> {
    writeln!(
        out,
        "{:<9} {:>9} {:>2} {:>9} {:>14} {:>10} {:>13}",
        "strategy", "mu", "s", "budget", "unique_ok_mean", "std", "first_ok_med"
    )?;
    for r in rows {
        let mu = match r.strategy {
            crate::simulate::Strategy::Levy { mu, .. } => format!("{mu}"),
            _ => "-".into(),
        };
        writeln!(
            out,
            "{:<9} {:>9} {:>2} {:>9} {:>14.1} {:>10.1} {:>13}",
            r.strategy.name(),
            mu,
            r.sample_size,
            r.hypotheses,
            r.unique_outlier_free_mean,
            r.unique_outlier_free_std,
            r.first_success_median
                .map_or("-".into(), |m| format!("{m}"))
        )?;
    }
    Ok(())
}
