//! `mireg merge`: several `register` outputs of one site in one frame ([`crate::merge`]).

use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

use crate::merge::{MergeConfig, MergeOptions};

/// Arguments of `mireg merge`.
#[derive(Debug, Args)]
pub struct MergeArgs {
    /// Outputs of `mireg register` (sessions of one site, each in its own frame); the first is
    /// the merged frame's reference.
    #[arg(required = true, num_args = 2..)]
    pub runs: Vec<PathBuf>,
    /// Output folder: one `NAME.mcap` per run (the run with `…/pose_merged`, `…/tf_merged`,
    /// `…/session_links` added) and `merge_report.json`; created when missing.
    #[arg(short, long, value_name = "DIR", required_unless_present = "pair")]
    pub output: Option<PathBuf>,
    /// Folder of each pair's verified links, `pair_A_B.json`: read where present instead of
    /// linking that pair (checked against the runs and settings), written for the pairs linked.
    /// Pairs linked apart (`--pair`, on other machines) are then merged from their files.
    #[arg(long, value_name = "DIR")]
    pub links: Option<PathBuf>,
    /// Link runs A and B (indices from 0 in the order given) alone and write their file in the
    /// `--links` folder; no merged output.
    #[arg(long, value_name = "A,B", value_parser = parse_pair, requires = "links", conflicts_with = "output")]
    pub pair: Option<(usize, usize)>,
    /// Agreeing links, at distinct keyframes, that join two sessions.
    #[arg(long, value_name = "N", default_value_t = crate::merge::DEFAULT_MIN_LINKS)]
    pub min_links: usize,
    /// Seed of the registrations' randomness.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Memory for the prior's and the logs' prepared keyframes (a map file's tiles too), MiB, by
    /// their size on the heap: those beyond it are prepared again for the candidates that need
    /// them. A candidate verifies the same either way; 0 keeps none.
    #[arg(long, value_name = "MIB", default_value_t = crate::loops::closure::DEFAULT_LOOP_MEMORY_BYTES >> 20)]
    pub keyframe_memory: usize,
    /// Replace existing outputs.
    #[arg(long)]
    pub force: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `A,B` as two indices.
fn parse_pair(s: &str) -> std::result::Result<(usize, usize), String> {
    let parsed = s
        .split_once(',')
        .and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)));
    parsed.ok_or_else(|| format!("expected two run indices A,B (e.g. 0,1), got {s:?}"))
}

/// `mireg merge`.
pub(super) fn run_merge(args: &MergeArgs) -> Result<()> {
    let opts = MergeOptions {
        runs: args.runs.clone(),
        output_dir: args.output.clone().unwrap_or_default(),
        force: args.force,
        seed: args.seed,
        config: MergeConfig {
            min_links: args.min_links,
            keyframe_memory_bytes: args.keyframe_memory.saturating_mul(1 << 20),
            ..MergeConfig::default()
        },
        command_line: super::process::command_line(),
        links_dir: args.links.clone(),
    };
    if let Some(pair) = args.pair {
        let (report, path) = crate::merge::link_pair_file(&opts, pair)?;
        if args.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            let verdict = if report.joined { "joined" } else { "apart" };
            println!(
                "{} + {}: {verdict}: {} ({} + {} candidates) -> {}",
                report.a,
                report.b,
                report.reason,
                report.appearance_candidates,
                report.place_candidates,
                path.display()
            );
        }
        return Ok(());
    }
    let s = crate::merge::merge(&opts)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(());
    }
    println!(
        "merged {} sessions into {} group(s), {} links accepted, {:.2} s -> {}",
        s.sessions.len(),
        s.groups,
        s.links_accepted,
        s.elapsed_s,
        s.output_dir.display()
    );
    for p in &s.pairs {
        let verdict = if p.joined { "joined" } else { "apart" };
        println!(
            "  {} + {}: {verdict}: {} ({} + {} candidates)",
            p.a, p.b, p.reason, p.appearance_candidates, p.place_candidates
        );
    }
    for r in &s.sessions {
        println!(
            "  {}: group {} ({}), {} frames, {} keyframes -> {}",
            r.name,
            r.group,
            r.merged_frame,
            r.frames,
            r.keyframes,
            r.output.display()
        );
    }
    Ok(())
}
