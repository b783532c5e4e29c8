//! The fine ICP stage (`PairConfig::icp_fine`) against a known transform: two independent dense
//! samplings of the same curved scene, so that their voxel centroids differ as two scans' do.
//! The fine stage must land closer to the truth than ICP of the voxel clouds alone.

#[path = "common/room_scene.rs"]
mod room_scene;

use mireg::pipeline::{PairConfig, pose_error, prepare_frame, register_prepared};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
use room_scene::scene;

#[test]
fn fine_stage_lands_closer_to_the_truth_than_voxel_icp() {
    let target = scene(60_000, 1);
    let mut errors = [Vec::new(), Vec::new()];
    for k in 0..5u32 {
        let truth = Isometry3::from_parts(
            Translation3::new(0.3 + 0.05 * f64::from(k), -0.2, 0.1),
            UnitQuaternion::from_euler_angles(0.05, -0.03, 0.3 + 0.1 * f64::from(k)),
        );
        // The source frame sees the scene through truth⁻¹, sampled afresh.
        let source: Vec<Point3<f64>> = scene(60_000, 100 + u64::from(k))
            .iter()
            .map(|p| truth.inverse() * p)
            .collect();
        for (i, fine) in [false, true].into_iter().enumerate() {
            let c = PairConfig {
                voxel_size_m: 0.1,
                icp_fine: fine,
                seed: u64::from(k),
                ..Default::default()
            };
            let (s, t) = (
                prepare_frame(&source, &c).unwrap(),
                prepare_frame(&target, &c).unwrap(),
            );
            assert_eq!(s.fine.is_empty(), !fine);
            let r = register_prepared(&s, &t, &c).unwrap();
            assert!(r.failure.is_none(), "pose {k}: {:?}", r.failure);
            let (re, te) = pose_error(&truth, &r.target_from_source);
            // Both land on the scene (within a tenth of the voxel) ...
            assert!(re < 0.5 && te < 0.01, "pose {k}, fine {fine}: {re}° {te} m");
            errors[i].push(re.to_radians() * 3.0 + te);
        }
    }
    // ... and the fine stage closer: on every pose, and by a margin in the median.
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    for (k, (base, fine)) in errors[0].iter().zip(&errors[1]).enumerate() {
        assert!(fine < base, "pose {k}: fine {fine} vs voxel ICP {base}");
    }
    let (base, fine) = (median(&mut errors[0]), median(&mut errors[1]));
    eprintln!("median error: voxel ICP {base}, fine {fine}");
    assert!(fine < 0.7 * base, "median fine {fine} vs voxel ICP {base}");
}

#[test]
fn fine_points_are_a_seeded_draw_of_the_finite_input_in_its_order() {
    use mireg::pipeline::refine::FINE_POINTS_PER_ICP_POINT;
    // A 100 × 50 grid of points 1 cm apart with NaNs among them; a 10 cm voxel cloud.
    let mut pts: Vec<Point3<f64>> = (0..5000)
        .map(|i| Point3::new(f64::from(i % 100), f64::from(i / 100), 0.0) * 0.01)
        .collect();
    for k in (0..5000).step_by(97) {
        pts[k].y = f64::NAN;
    }
    let prepared = |seed: u64| {
        let c = PairConfig {
            voxel_size_m: 0.1,
            seed,
            ..Default::default()
        };
        prepare_frame(&pts, &c).unwrap()
    };
    let f = prepared(0);
    let icp_points = f.icp.as_ref().unwrap().points().len();
    assert_eq!(f.fine.len(), FINE_POINTS_PER_ICP_POINT * icp_points);
    // Finite input points, each once, in input order (the grid index grows along the input).
    let index = |p: &Point3<f64>| (p.y * 100.0).round() as i64 * 100 + (p.x * 100.0).round() as i64;
    assert!(f.fine.iter().all(|p| p.x.is_finite() && p.y.is_finite()));
    assert!(f.fine.windows(2).all(|w| index(&w[0]) < index(&w[1])));
    assert!(f.fine.iter().all(|p| pts[index(p) as usize] == *p));
    // Seeded: the same seed draws the same points, another seed others.
    assert_eq!(prepared(0).fine, f.fine);
    assert_ne!(prepared(1).fine, f.fine);
    // Fewer finite points than wanted (4 per 10 cm voxel): all of them.
    let sparse: Vec<Point3<f64>> = (0..100)
        .map(|i| Point3::new(f64::from(i % 10), f64::from(i / 10), 0.0) * 0.05)
        .collect();
    let few = prepare_frame(
        &sparse,
        &PairConfig {
            voxel_size_m: 0.1,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(few.fine, sparse);
    // Without the fine stage: none.
    let off = PairConfig {
        voxel_size_m: 0.1,
        icp_fine: false,
        ..Default::default()
    };
    assert!(prepare_frame(&pts, &off).unwrap().fine.is_empty());
}
