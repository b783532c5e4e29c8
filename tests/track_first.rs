//! `OdometryConfig::track_first`: frames the constant-velocity prediction follows are refined on
//! the map from it and accepted without global registration; a frame it does not follow (a jump
//! against the prediction) is registered globally as before. Poses against the known truth.

use mireg::odometry::stream::StreamOdometry;
use mireg::odometry::{InitialGuess, OdometryConfig};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

#[path = "common/room_scene.rs"]
mod room_scene;

/// Runs the room scene along `track` ((x \[m\], yaw \[deg\]) per frame); returns each frame's
/// map guess and its position error against the truth \[m\].
fn run(track: &[(f64, f64)], track_first: bool) -> Vec<(Option<InitialGuess>, f64, bool)> {
    let config = OdometryConfig {
        track_first,
        ..OdometryConfig::default()
    };
    let mut odometry = StreamOdometry::new(config, true, false);
    let mut first = None;
    track
        .iter()
        .enumerate()
        .map(|(k, &(x, yaw_deg))| {
            let world_from_frame = Isometry3::from_parts(
                Translation3::new(0.5 + x, 0.6, 1.0),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
            );
            let points: Vec<_> = room_scene::scene(8000, k as u64)
                .into_iter()
                .map(|p| world_from_frame.inverse() * p)
                .collect();
            let est = odometry
                .push(points, None, (k as i64) * 100_000_000)
                .unwrap();
            let truth = first.get_or_insert(world_from_frame).inverse() * world_from_frame;
            let error = (truth.inverse() * est.world_from_frame)
                .translation
                .vector
                .norm();
            (est.map.map(|m| m.guess), error, est.success)
        })
        .collect()
}

#[test]
fn smooth_frames_are_tracked_and_a_jump_is_registered_globally() {
    // Steady 6 cm and 1° a frame, then a jump back of 1.4 m and 47° (a dropped stretch).
    let mut track: Vec<(f64, f64)> = (0..8).map(|k| (0.06 * k as f64, k as f64)).collect();
    track.push((-1.0, -40.0));
    let tracked = run(&track, true);
    for (k, (guess, error, success)) in tracked.iter().enumerate() {
        assert!(*success, "frame {k} failed");
        assert!(*error < 0.01, "frame {k} is {error} m off ({guess:?})");
    }
    // Frame 1 has no previous map fitness to compare with: global. From frame 2 on the
    // prediction is right and tracked, until the jump.
    let guesses: Vec<_> = tracked.iter().map(|(g, _, _)| *g).collect();
    assert!(
        guesses[2..8]
            .iter()
            .all(|g| *g == Some(InitialGuess::Tracked)),
        "{guesses:?}"
    );
    assert!(
        matches!(
            guesses[8],
            Some(InitialGuess::Global | InitialGuess::SecondGlobal)
        ),
        "the jump: {:?}",
        guesses[8]
    );
    // Without the option no frame is tracked, and the poses agree within the ICP's tolerance.
    let global = run(&track, false);
    for (k, ((g, e, _), (_, e_track, _))) in global.iter().zip(&tracked).enumerate() {
        assert_ne!(*g, Some(InitialGuess::Tracked), "frame {k}");
        assert!(
            (e - e_track).abs() < 0.005,
            "frame {k}: {e} against {e_track} m"
        );
    }
}
