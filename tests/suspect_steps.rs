//! Degenerate frames: frames cut down to their floor points register underdetermined (the floor
//! leaves x, y and yaw free). Each must be flagged failed or suspect, and where it registered,
//! its predicted deviations must be large along the free directions and small across the floor;
//! the frames with walls around them keep the right pose (global registration of the frame
//! right after one may fail against it: it has no features to match, and the map tracks it).

use mireg::odometry::OdometryConfig;
use mireg::odometry::stream::StreamOdometry;
use mireg::odometry::uncertainty::{PoseUncertainty, uninformed_information};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

#[path = "common/room_scene.rs"]
mod room_scene;
#[path = "common/room_track.rs"]
mod room_track;

#[test]
fn floor_only_frames_are_flagged_and_uncertain_along_the_floor() {
    let floor_only = [4usize, 7];
    let mut odometry = StreamOdometry::new(OdometryConfig::default(), true, false);
    let mut voxel = None;
    let mut first = None;
    for k in 0..10u64 {
        let world_from_frame = Isometry3::from_parts(
            Translation3::new(0.5 + 0.04 * k as f64, 0.6, 1.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.01 * k as f64),
        );
        let points: Vec<_> = room_scene::scene(8000, k)
            .into_iter()
            .filter(|p| !floor_only.contains(&(k as usize)) || p.z.abs() < 1e-9)
            .map(|p| world_from_frame.inverse() * p)
            .collect();
        let est = odometry
            .push(points, None, (k * 100_000_000) as i64)
            .unwrap();
        let v = *voxel.get_or_insert_with(|| {
            odometry
                .config()
                .pair
                .icp_voxel_size_m
                .expect("sized by the first cloud")
        });
        let flagged = !est.success || est.suspect.is_some();
        if !floor_only.contains(&(k as usize)) {
            // World = the first frame's sensor frame.
            let truth = first.get_or_insert(world_from_frame).inverse() * world_from_frame;
            let error = (truth.inverse() * est.world_from_frame)
                .translation
                .vector
                .norm();
            assert!(error < 0.02, "frame {k} with walls is {error} m off");
            assert!(est.suspect.is_none(), "frame {k}: {:?}", est.suspect);
            let after_floor = k > 0 && floor_only.contains(&(k as usize - 1));
            assert!(est.success || after_floor, "frame {k}: {:?}", est.failure);
            continue;
        }
        assert!(flagged, "floor-only frame {k} neither failed nor suspect");
        if let Some(omega) = est.information {
            // In the frame: the floor's normal is the frame's z (the sensor only yaws).
            let u = PoseUncertainty::new(Some(&omega), &uninformed_information(v));
            let sd = |i: usize| u.covariance[(i, i)].sqrt();
            let (x, y, z) = (sd(3), sd(4), sd(5));
            // NOTE: 5×, not 10×, and degeneracy below the unconfirmed rule's 0.05, not 0.01:
            // since the retries, frame 7 registers (a retry finds a model, which the prediction
            // outfits on the map) instead of failing, and the floor's edges against the map's
            // walls hold x and y at 6.8× and 7.8× z, degeneracy 0.016 (measured 2026-12-06).
            assert!(
                x > 5.0 * z && y > 5.0 * z,
                "frame {k}: sigma x {x} y {y} z {z} m"
            );
            assert!(
                u.degeneracy_translation < mireg::odometry::suspect::UNCONFIRMED_DEGENERACY,
                "{u:?}"
            );
        }
    }
}

/// A frame whose first RANSAC stream finds no model gets a second one before it falls back on
/// the prediction. With a budget of 60 hypotheses a stream fails now and then on these frames
/// (the last jumps back 0.9 m and 16° against the constant-velocity prediction, as after a
/// dropped stretch of a log); measured before the rule, with one stream, 5 of the 60 frames of
/// seeds 0–11 failed (tracked from the prediction, right but reported failed). With the second
/// stream fewer must fail, the second stream must have registered some, and every pose must be
/// within 2 cm of the truth.
#[test]
fn a_frame_whose_first_ransac_fails_gets_a_second_stream() {
    const HYPOTHESES: u64 = 60;
    const ONE_STREAM_FAILURES: usize = 5;
    let mut wrong = Vec::new();
    let mut failed = Vec::new();
    let mut second_streams = 0;
    for seed in 0..12u64 {
        let mut config = OdometryConfig::default();
        config.pair.seed = seed;
        config.pair.max_hypotheses = HYPOTHESES;
        let track = [
            (0.0, 0.0),
            (0.08, 1.0),
            (0.16, 2.0),
            (0.24, 3.0),
            (0.32, 4.0),
            (-0.5, -10.0),
        ];
        for (k, (est, error)) in room_track::run(config, &track).into_iter().enumerate() {
            if est
                .map
                .is_some_and(|m| m.guess == mireg::odometry::InitialGuess::SecondGlobal)
            {
                second_streams += 1;
            }
            if !est.success {
                failed.push((seed, k));
            }
            if error > 0.02 {
                wrong.push((seed, k, error));
            }
        }
    }
    assert!(wrong.is_empty(), "(seed, frame, error m): {wrong:?}");
    assert!(
        second_streams > 0,
        "no frame was registered by a second stream"
    );
    assert!(
        failed.len() < ONE_STREAM_FAILURES,
        "failed (seed, frame): {failed:?}"
    );
}
