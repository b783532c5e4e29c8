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
    #[arg(short, long, value_name = "DIR")]
    pub output: PathBuf,
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

/// `mireg merge`.
pub(super) fn run_merge(args: &MergeArgs) -> Result<()> {
    let opts = MergeOptions {
        runs: args.runs.clone(),
        output_dir: args.output.clone(),
        force: args.force,
        seed: args.seed,
        config: MergeConfig {
            min_links: args.min_links,
            keyframe_memory_bytes: args.keyframe_memory.saturating_mul(1 << 20),
            ..MergeConfig::default()
        },
        command_line: super::process::command_line(),
    };
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
