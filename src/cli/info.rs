//! `mireg info`: a log's channels, message counts and the cloud topic `register` reads
//! ([`crate::io::input_log`]).

use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

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

/// `mireg info`.
pub(super) fn run_info(args: &InfoArgs) -> Result<()> {
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
