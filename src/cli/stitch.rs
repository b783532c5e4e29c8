//! `mireg stitch`: join overlapping `register --start/--end` segments
//! ([`crate::register::stitch`]).

use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

/// Arguments of `mireg stitch`.
#[derive(Debug, Args)]
pub struct StitchArgs {
    /// The log the segments were registered from (copied into the output as `register` does).
    pub log: PathBuf,
    /// Outputs of `mireg register LOG --start … --end …`, in log order, each sharing at least
    /// one frame with the next.
    #[arg(required = true)]
    pub segments: Vec<PathBuf>,
    /// Output MCAP.
    #[arg(short, long, value_name = "FILE")]
    pub output: PathBuf,
    /// Skip loop closure over the stitched trajectory (on by default, as in `register`).
    #[arg(long)]
    pub no_loops: bool,
    /// Replace an existing output.
    #[arg(long)]
    pub force: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `mireg stitch`.
pub(super) fn run_stitch(args: &StitchArgs) -> Result<()> {
    let s = crate::register::stitch(
        &args.log,
        &args.segments,
        &args.output,
        args.force,
        &super::process::command_line(),
        !args.no_loops,
    )?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
    } else {
        println!(
            "stitched {} frames from {} segments -> {} ({} input messages copied)",
            s.frames,
            s.segments,
            s.output.display(),
            s.messages_copied
        );
        if let Some(l) = &s.loops {
            println!(
                "  loops over the whole log: {} keyframes, {} candidates tried, {} accepted, {:.2} s",
                l.keyframes, l.candidates, l.accepted, l.elapsed_s
            );
        }
        for seam in &s.seams {
            println!(
                "  seam {}: {} shared frames, after alignment max {:.4} m / {:.3} deg",
                seam.segment, seam.shared_frames, seam.max_translation_m, seam.max_rotation_deg
            );
        }
    }
    Ok(())
}
