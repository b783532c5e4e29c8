//! `OdometryConfig::track_first` (the default): frames the constant-velocity prediction follows
//! are refined on the map from it and accepted without global registration; a frame it does not
//! follow (a jump against the prediction), or every frame while it keeps missing by more than the
//! ICP's reach, is registered globally as without the option. Poses against the known truth.

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
    // Frame 1 has no previous map fitness to compare with, frame 2 no measured miss of the
    // prediction (frame 1's was the identity): both global. From frame 3 on the prediction is
    // right and tracked, until the jump.
    let guesses: Vec<_> = tracked.iter().map(|(g, _, _)| *g).collect();
    assert!(
        guesses[1..3]
            .iter()
            .all(|g| matches!(g, Some(InitialGuess::Global))),
        "{guesses:?}"
    );
    assert!(
        guesses[3..8]
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

#[test]
fn tracking_is_the_default() {
    assert!(OdometryConfig::default().track_first);
}

#[test]
fn a_prediction_that_keeps_missing_is_not_tracked() {
    // Steps alternating between 0.5 m and none: the constant-velocity prediction misses by
    // 0.5 m every frame, ten map distances (the room's 5 cm voxel), beyond what tracking accepts.
    let track: Vec<(f64, f64)> = (0..8).map(|k| (0.5 * (k / 2) as f64, 0.0)).collect();
    let frames = run(&track, true);
    for (k, (guess, error, success)) in frames.iter().enumerate() {
        assert!(*success, "frame {k} failed");
        assert!(*error < 0.01, "frame {k} is {error} m off ({guess:?})");
        assert_ne!(*guess, Some(InitialGuess::Tracked), "frame {k}");
    }
    // The oracle: the same track every frame global.
    for (k, ((_, e, _), (_, e_global, _))) in frames.iter().zip(&run(&track, false)).enumerate() {
        assert!(
            (e - e_global).abs() < 1e-9,
            "frame {k}: {e} against {e_global} m"
        );
    }
}
