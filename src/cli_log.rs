//! `mireg info` and `mireg stitch`: clap arguments → [`crate::io::input_log`] and
//! [`crate::register::stitch`] calls.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::io::input_log::InputLog;

/// Arguments of `mireg info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// A log `register` reads: MCAP file, ROS 1 bag, or ROS 2 bag directory.
    pub input: PathBuf,
    /// Print JSON (container, channels with message counts, the cloud topic and its count).
    #[arg(long)]
    pub json: bool,
}

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
    #[arg(short, long)]
    pub output: PathBuf,
    /// Replace an existing output.
    #[arg(long)]
    pub force: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `mireg info`.
pub fn run_info(args: &InfoArgs) -> Result<()> {
    let (log, catalog) = InputLog::open(&args.input)?;
    let kind = match log {
        InputLog::Mcap(_) => "mcap",
        InputLog::Bag(_) => "ros1_bag",
        InputLog::Rosbag2(_) => "rosbag2",
    };
    let channels = catalog.channel_infos();
    let cloud = crate::register::point_cloud_topic(&args.input, &channels, None).ok();
    let cloud_messages = cloud.as_ref().map(|t| {
        channels
            .iter()
            .filter(|c| &c.topic == t)
            .filter_map(|c| c.message_count)
            .sum::<u64>()
    });
    if args.json {
        let v = serde_json::json!({
            "input": args.input,
            "container": kind,
            "cloud_topic": cloud,
            "cloud_messages": cloud_messages,
            "channels": channels.iter().map(|c| serde_json::json!({
                "id": c.id, "topic": c.topic, "schema_name": c.schema_name,
                "schema_encoding": c.schema_encoding, "message_encoding": c.message_encoding,
                "message_count": c.message_count,
            })).collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!("{} ({kind})", args.input.display());
    for c in &channels {
        println!(
            "  {:>5} {}  {} ({}){}",
            c.id,
            c.topic,
            c.schema_name,
            c.message_encoding,
            c.message_count
                .map(|n| format!(", {n} messages"))
                .unwrap_or_default()
        );
    }
    match (&cloud, cloud_messages) {
        (Some(t), Some(n)) => println!("point clouds: {t}, {n} messages"),
        _ => println!("point clouds: none that register reads without --topic"),
    }
    Ok(())
}

/// `mireg stitch`.
pub fn run_stitch(args: &StitchArgs) -> Result<()> {
    let s = crate::register::stitch(
        &args.log,
        &args.segments,
        &args.output,
        args.force,
        &crate::cli::command_line(),
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
        for seam in &s.seams {
            println!(
                "  seam {}: {} shared frames, after alignment max {:.4} m / {:.3} deg",
                seam.segment, seam.shared_frames, seam.max_translation_m, seam.max_rotation_deg
            );
        }
    }
    Ok(())
}
