//! ROS 1 logs in MCAP (profile `ros1`): the real Ouster OS1-64 recording in fixtures/ registers,
//! every input message reaches the output unchanged, zero returns are dropped and counted (checked
//! against a byte scan of the point data), and our channels are ROS 1 messages with the profile's
//! channel metadata.

use std::path::{Path, PathBuf};

use mcap::records::Record;
use mireg::io::codec::ros1;
use mireg::io::mcap::log::for_each_record;
use mireg::odometry::OdometryConfig;
use mireg::register::{RegisterOptions, register_log};

#[path = "common/log_contents.rs"]
mod log_contents;
use log_contents::{assert_superset, contents};

const CLOUD_TOPIC: &str = "/os1_cloud_node/points";
/// The OS1-64 in this log: 64 beams × 2048 columns, 48-byte points (fixtures/ouster_os1_ros1.md).
const POINTS_PER_SCAN: usize = 64 * 2048;
const POINT_STEP: usize = 48;

fn ouster() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/ouster_os1_ros1.mcap")
}

/// Zero returns of one cloud message, by scanning its point data: the data array is the
/// message's last `4 + N + 1` bytes (length, data, `is_dense`), N = points × point step.
fn zero_returns_by_scan(message: &[u8]) -> usize {
    let n = POINTS_PER_SCAN * POINT_STEP;
    let data_start = message.len() - 1 - n;
    let len = u32::from_le_bytes(message[data_start - 4..data_start].try_into().unwrap());
    assert_eq!(len as usize, n, "data length where the layout puts it");
    message[data_start..data_start + n]
        .chunks_exact(POINT_STEP)
        .filter(|p| {
            // +0.0 or −0.0 (a zero range times a negative direction cosine).
            p[..12]
                .chunks_exact(4)
                .all(|c| f32::from_le_bytes(c.try_into().unwrap()) == 0.0)
        })
        .count()
}

fn stats(path: &Path) -> Vec<serde_json::Value> {
    contents(path)
        .messages
        .iter()
        .filter(|m| m.0 == "/mireg/stats")
        .map(|m| serde_json::from_slice(&m.3).unwrap())
        .collect()
}

#[test]
fn real_ouster_ros1_log_registers_and_keeps_every_message() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    let mut opts = RegisterOptions::new(&ouster(), &out, OdometryConfig::default());
    opts.derive_voxel = true;
    let summary = register_log(&opts).unwrap();
    assert_eq!(summary.topic, CLOUD_TOPIC);
    assert_eq!(summary.frames, 2);
    assert_eq!(summary.failed_frames, 0);

    let (input, output) = (contents(&ouster()), contents(&out));
    assert_superset(&input, &output);
    let loops = output
        .messages
        .iter()
        .filter(|m| m.0 == "/mireg/loops")
        .count();
    assert_eq!(loops, 0, "two frames, no loop candidates");
    assert_eq!(
        output.messages.len(),
        input.messages.len() + 6 * 2,
        "ours: /tf, /mireg/pose, /mireg/stats, /mireg/pose_cov, /mireg/tf_optimized, /mireg/pose_optimized per frame"
    );

    // Zero returns: counted by the decoder, checked against a scan of the bytes.
    let clouds: Vec<&Vec<u8>> = input
        .messages
        .iter()
        .filter(|m| m.0 == CLOUD_TOPIC)
        .map(|m| &m.3)
        .collect();
    for (s, cloud) in stats(&out).iter().zip(&clouds) {
        let zeros = zero_returns_by_scan(cloud);
        assert!(zeros > 10_000, "an outdoor scan has many no-returns");
        assert_eq!(s["num_dropped_zero"], zeros);
        assert_eq!(s["num_points"], POINTS_PER_SCAN - zeros);
        assert_eq!(s["time_field"], "t");
        assert_eq!(s["success"], true);
    }
}

#[test]
fn our_channels_are_ros1_with_the_profile_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    let opts = RegisterOptions::new(&ouster(), &out, OdometryConfig::default());
    register_log(&opts).unwrap();

    let mut schemas = std::collections::BTreeMap::new();
    let mut ours = Vec::new();
    let mut profile = String::new();
    let mut messages: Vec<(u16, Vec<u8>)> = Vec::new();
    for_each_record(&out, |r| {
        match r {
            Record::Schema { header, data } => {
                schemas.insert(header.id, (header.name, header.encoding, data.to_vec()));
            }
            Record::Channel(c)
                if c.topic == "/tf" || c.topic == "/mireg/pose" || c.topic == "/mireg/pose_cov" =>
            {
                ours.push(c)
            }
            Record::Message { header, data } => messages.push((header.channel_id, data.to_vec())),
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    // The Header record: magic (8), opcode (1), length (8), profile (u32 length + bytes).
    let bytes = std::fs::read(&out).unwrap();
    let len = u32::from_le_bytes(bytes[17..21].try_into().unwrap()) as usize;
    profile.push_str(std::str::from_utf8(&bytes[21..21 + len]).unwrap());
    assert_eq!(bytes[8], 0x01, "header opcode");
    assert_eq!(profile, "ros1");
    assert_eq!(ours.len(), 3);
    for c in &ours {
        let (name, encoding, text) = &schemas[&c.schema_id];
        assert_eq!(c.message_encoding, "ros1");
        assert_eq!(encoding, "ros1msg");
        let (want_name, want_text, want_md5) = if c.topic == "/tf" {
            (
                ros1::TF_MESSAGE_SCHEMA_NAME,
                ros1::TF_MESSAGE_SCHEMA,
                ros1::TF_MESSAGE_MD5,
            )
        } else if c.topic == "/mireg/pose_cov" {
            (
                ros1::POSE_WITH_COVARIANCE_STAMPED_SCHEMA_NAME,
                ros1::POSE_WITH_COVARIANCE_STAMPED_SCHEMA,
                ros1::POSE_WITH_COVARIANCE_STAMPED_MD5,
            )
        } else {
            (
                ros1::POSE_STAMPED_SCHEMA_NAME,
                ros1::POSE_STAMPED_SCHEMA,
                ros1::POSE_STAMPED_MD5,
            )
        };
        assert_eq!(name, want_name);
        assert_eq!(text, want_text.as_bytes());
        assert_eq!(c.metadata["md5sum"], want_md5);
        assert_eq!(c.metadata["latching"], "0");
        assert_eq!(c.metadata["callerid"], "/mireg");
        assert_eq!(c.metadata["topic"], c.topic);
    }
    // The input's own tf2_msgs/TFMessage channel declares the MD5 sum we write.
    assert!(
        contents(&ouster())
            .messages
            .iter()
            .any(|m| m.0 == "/tf_static"),
        "the log has /tf_static"
    );
    let tf = ours.iter().find(|c| c.topic == "/tf").unwrap();
    let pose = ours.iter().find(|c| c.topic == "/mireg/pose").unwrap();
    let tfs: Vec<_> = messages
        .iter()
        .filter(|m| m.0 == tf.id)
        .map(|m| ros1::decode_tf_message(&m.1).unwrap())
        .collect();
    let poses: Vec<_> = messages
        .iter()
        .filter(|m| m.0 == pose.id)
        .map(|m| ros1::decode_pose_stamped(&m.1).unwrap())
        .collect();
    assert_eq!((tfs.len(), poses.len()), (2, 2));
    for (t, (h, p)) in tfs.iter().zip(&poses) {
        assert_eq!(t[0].header, *h);
        assert_eq!(t[0].transform, *p);
        assert_eq!(t[0].child_frame_id, "os1_lidar");
    }
    assert_eq!(poses[0].1, nalgebra::Isometry3::identity());
}

#[test]
fn input_md5_of_tf_message_is_ours() {
    // An independent source for one of our constants: the recorder's own connection header.
    let mut md5 = None;
    for_each_record(&ouster(), |r| {
        if let Record::Channel(c) = r
            && c.topic == "/tf_static"
        {
            md5 = c.metadata.get("md5sum").cloned();
        }
        Ok(())
    })
    .unwrap();
    assert_eq!(md5.as_deref(), Some(ros1::TF_MESSAGE_MD5));
}

#[test]
fn exported_trajectory_of_a_ros1_output_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.mcap");
    register_log(&RegisterOptions::new(
        &ouster(),
        &out,
        OdometryConfig::default(),
    ))
    .unwrap();
    let t = mireg::io::poses::read_mcap_pose_topics(&out, &["/mireg/pose"]).unwrap();
    assert_eq!(t[0].poses.len(), 2);
}

#[test]
fn output_messages_picks_the_family_of_our_channels() {
    use mireg::io::codec::cdr;
    use mireg::register::OutputMessages;
    let dir = tempfile::tempdir().unwrap();
    let mut poses = Vec::new();
    for (family, decode) in [
        (
            OutputMessages::Auto,
            ros1::decode_pose_stamped as mireg::io::codec::PoseStampedDecoder,
        ),
        (OutputMessages::Ros2, cdr::decode_pose_stamped),
    ] {
        let out = dir.path().join(format!("{family:?}.mcap"));
        let mut opts = RegisterOptions::new(&ouster(), &out, OdometryConfig::default());
        opts.output_messages = family;
        register_log(&opts).unwrap();
        let p: Vec<_> = contents(&out)
            .messages
            .iter()
            .filter(|m| m.0 == "/mireg/pose")
            .map(|m| decode(&m.3).unwrap())
            .collect();
        assert_eq!(p.len(), 2, "{family:?}");
        poses.push(p);
    }
    assert_eq!(poses[0], poses[1], "same poses in either family");
}
