//! `OdometryConfig::track_first`: frames the constant-velocity prediction follows are refined on
//! the map from it and accepted without global registration; a frame it does not follow (a jump
//! against the prediction) is registered globally as before. Poses against the known truth.

use mireg::odometry::{InitialGuess, OdometryConfig};

#[path = "common/room_scene.rs"]
mod room_scene;
#[path = "common/room_track.rs"]
mod room_track;

/// Each frame's map guess, position error \[m\] and success along `track`
/// ([`room_track::run`]).
fn run(track: &[(f64, f64)], track_first: bool) -> Vec<(Option<InitialGuess>, f64, bool)> {
    let config = OdometryConfig {
        track_first,
        ..OdometryConfig::default()
    };
    room_track::run(config, track)
        .into_iter()
        .map(|(est, error)| (est.map.map(|m| m.guess), error, est.success))
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
