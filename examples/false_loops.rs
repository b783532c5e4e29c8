//! How far false loops move a real log's loop-closed trajectory: reads a `mireg register` output
//! (its odometry on `/mireg/pose`, the accepted loops on `/mireg/loops`, the reference on
//! `/ground_truth/pose`), forces N false loop edges into the pose graph (seeded: random pairs of
//! frames at least 5 apart, each claiming the query sits 0.5–2 m and 5–30° from where the
//! odometry puts it relative to the match), solves it with the settings `register` used, and
//! prints the ATE with and without them; then judges all the loops jointly
//! ([`mireg::loops::judge_loops`], PCM through the odometry) and prints how many false and true
//! loops that drops and the ATE after it.
//!
//! ```text
//! mireg register LOG -o OUT.mcap && cargo run --release --example false_loops -- OUT.mcap [N=10] [SEED=0]
//! ```

use std::path::PathBuf;

use mireg::io::poses::read_mcap_pose_topic;
use mireg::loops::{LoopConfig, LoopDecision, LoopEdge, Step, judge_loops, optimize_trajectory};
use mireg::trajectory::{Trajectory, evaluate};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};

fn main() -> mireg::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = PathBuf::from(args.first().expect("OUT.mcap"));
    let n: usize = args.get(1).map_or(10, |s| s.parse().expect("N"));
    let seed: u64 = args.get(2).map_or(0, |s| s.parse().expect("SEED"));
    let odometry = read_mcap_pose_topic(&path, "/mireg/pose")?;
    let reference = read_mcap_pose_topic(&path, "/ground_truth/pose")?;
    let (voxel, loops) = read_run(&path)?;
    let config = LoopConfig::for_voxel(voxel);
    let registered = vec![Step::Registered; odometry.poses.len()];
    let ate = |poses: Vec<Isometry3<f64>>| -> mireg::Result<f64> {
        let t = Trajectory::stamped(odometry.stamps_ns.clone(), poses);
        Ok(evaluate(&t, &reference, None, 0)?.ate_rmse_m)
    };
    let (clean, _) = optimize_trajectory(&odometry.poses, &registered, &loops, &config)?;
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    let frames = odometry.poses.len();
    let mut forced = loops.clone();
    while forced.len() < loops.len() + n {
        let (a, b) = (rng.random_range(0..frames), rng.random_range(0..frames));
        let (matched, query) = (a.min(b), a.max(b));
        if query - matched < 5 {
            continue;
        }
        let truth = odometry.poses[matched].inverse() * odometry.poses[query];
        let dir = Vector3::new(
            rng.random::<f64>() - 0.5,
            rng.random::<f64>() - 0.5,
            rng.random::<f64>() - 0.5,
        )
        .normalize();
        let axis = nalgebra::Unit::new_normalize(Vector3::new(
            rng.random::<f64>() - 0.5,
            rng.random::<f64>() - 0.5,
            rng.random::<f64>() - 0.5,
        ));
        let wrong = Isometry3::from_parts(
            Translation3::from(dir * rng.random_range(0.5..2.0)),
            UnitQuaternion::from_axis_angle(&axis, rng.random_range(5.0f64..30.0).to_radians()),
        );
        forced.push(LoopEdge {
            query,
            matched,
            match_from_query: truth * wrong,
            information: None,
        });
    }
    let (with_false, solution) =
        optimize_trajectory(&odometry.poses, &registered, &forced, &config)?;
    let weights = solution.map(|s| s.edge_weights).unwrap_or_default();
    let false_weights = &weights[weights.len() - n..];
    println!(
        "{}: odometry ATE {:.5} m; loop-closed with its {} loops {:.5} m; with {n} false loops forced in {:.5} m ({:+.1} %); false loops' weights {:.2e}..{:.2e}",
        path.display(),
        ate(odometry.poses.clone())?,
        loops.len(),
        ate(clean.clone())?,
        ate(with_false.clone())?,
        100.0 * (ate(with_false)? / ate(clean.clone())? - 1.0),
        false_weights.iter().copied().fold(f64::INFINITY, f64::min),
        false_weights.iter().copied().fold(0.0, f64::max),
    );
    // The loops read back carry no information: none is left out as held by the map.
    let judged = judge_loops(
        &odometry.poses,
        &registered,
        &vec![None; frames],
        &forced,
        &config,
    )?;
    let dropped = |d: &[LoopDecision]| {
        d.iter()
            .filter(|d| matches!(d, LoopDecision::Inconsistent { .. }))
            .count()
    };
    println!(
        "judged jointly (PCM): {} of {n} false loops and {} of {} true ones dropped; ATE {:.5} m ({:+.1} %)",
        dropped(&judged.decisions[loops.len()..]),
        dropped(&judged.decisions[..loops.len()]),
        loops.len(),
        ate(judged.optimized.clone())?,
        100.0 * (ate(judged.optimized)? / ate(clean)? - 1.0),
    );
    Ok(())
}

/// The run's voxel (from its `mireg` metadata) and its accepted loops.
fn read_run(path: &std::path::Path) -> mireg::Result<(f64, Vec<LoopEdge>)> {
    use mcap::records::Record;
    let mut voxel = None;
    let mut topics = std::collections::HashMap::new();
    let mut loops = Vec::new();
    mireg::io::mcap::log::for_each_record(path, |r| {
        match r {
            Record::Metadata(m) if m.name == "mireg" => {
                voxel = m
                    .metadata
                    .get("voxel_m")
                    .and_then(|v| v.parse::<f64>().ok());
            }
            Record::Channel(c) => {
                topics.insert(c.id, c.topic.clone());
            }
            Record::Message { header, data }
                if topics.get(&header.channel_id).map(String::as_str) == Some("/mireg/loops") =>
            {
                let v: serde_json::Value = serde_json::from_slice(&data).expect("loop JSON");
                if v["verdict"] == "accepted" {
                    let p = &v["match_from_query"];
                    let t: Vec<f64> = serde_json::from_value(p["translation"].clone()).unwrap();
                    let q: Vec<f64> = serde_json::from_value(p["rotation_xyzw"].clone()).unwrap();
                    loops.push(LoopEdge {
                        query: v["query_frame"].as_u64().unwrap() as usize,
                        matched: v["match_frame"].as_u64().unwrap() as usize,
                        match_from_query: Isometry3::from_parts(
                            Translation3::new(t[0], t[1], t[2]),
                            UnitQuaternion::from_quaternion(Quaternion::new(
                                q[3], q[0], q[1], q[2],
                            )),
                        ),
                        information: None,
                    });
                }
            }
            _ => {}
        }
        Ok(())
    })?;
    let voxel = voxel
        .ok_or_else(|| mireg::Error::InvalidInput("no voxel_m in the mireg metadata".into()))?;
    Ok((voxel, loops))
}
