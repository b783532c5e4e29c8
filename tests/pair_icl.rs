//! Pairwise registration on the committed ICL-NUIM fixture (real data, CC BY 3.0) against its ground
//! truth, and from perturbed starts (the pipeline is global, so the start must not matter).

use std::path::Path;

use mireg::io::{cloud_file, pose_file};
use mireg::pipeline::{PairConfig, SamplerConfig, pose_error, register_pair};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};

fn fixture() -> (Vec<Point3<f64>>, Vec<Point3<f64>>, Isometry3<f64>) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_nuim");
    let source = cloud_file::read_points(&dir.join("rgbd5_00004.ply")).unwrap();
    let target = cloud_file::read_points(&dir.join("rgbd5_00000.ply")).unwrap();
    let log = pose_file::read_log(&dir.join("trajectory.log")).unwrap();
    let world_from = |k: usize| log.iter().find(|r| r.i == k).unwrap().pose;
    (source, target, world_from(0).inverse() * world_from(4))
}

#[test]
fn icl_frames_register_to_ground_truth_from_perturbed_starts() {
    let (source, target, gt) = fixture();
    let config = PairConfig {
        voxel_size_m: 0.05,
        seed: 1,
        ..Default::default()
    };
    // Perturb the source by known motions up to 90° / 1 m; the truth moves with it.
    for (k, (angles, t)) in [
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
        ((0.3, -0.2, 0.5), (0.2, -0.4, 0.1)),
        ((1.2, 0.4, -0.9), (-0.6, 0.5, 0.5)),
        ((-0.5, 1.5, 0.2), (0.3, 0.3, -0.8)),
    ]
    .into_iter()
    .enumerate()
    {
        let p = Isometry3::from_parts(
            Translation3::new(t.0, t.1, t.2),
            UnitQuaternion::from_euler_angles(angles.0, angles.1, angles.2),
        );
        let moved: Vec<_> = source.iter().map(|q| p * q).collect();
        let truth = gt * p.inverse();
        let r = register_pair(&moved, &target, &config).unwrap();
        assert!(r.failure.is_none(), "start {k}: {:?}", r.failure);
        let (rot_deg, trans_m) = pose_error(&truth, &r.target_from_source);
        assert!(
            rot_deg < 1.0 && trans_m < 0.03,
            "start {k}: error {rot_deg:.3}° {trans_m:.4} m"
        );
        assert!(r.fitness > 0.5, "start {k}: fitness {}", r.fitness);
    }
}

#[test]
fn same_seed_same_pose_on_one_and_two_threads() {
    let (source, target, _) = fixture();
    let config = PairConfig {
        voxel_size_m: 0.08,
        seed: 7,
        ..Default::default()
    };
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| register_pair(&source, &target, &config).unwrap())
    };
    let (a, b) = (run(1), run(2));
    let bits = |m: &Isometry3<f64>| {
        m.to_homogeneous()
            .iter()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&a.target_from_source), bits(&b.target_from_source));
    assert_eq!(
        (a.num_inliers, a.hypotheses, a.best_found_at),
        (b.num_inliers, b.hypotheses, b.best_found_at)
    );
}

#[test]
fn every_sampler_registers_the_pair() {
    let (source, target, gt) = fixture();
    for sampler in [
        SamplerConfig::Uniform,
        SamplerConfig::Prosac {
            growth_max_samples: 200_000,
        },
        SamplerConfig::default(),
    ] {
        let config = PairConfig {
            voxel_size_m: 0.05,
            sampler,
            ..Default::default()
        };
        let r = register_pair(&source, &target, &config).unwrap();
        let (rot_deg, trans_m) = pose_error(&gt, &r.target_from_source);
        assert!(
            rot_deg < 1.0 && trans_m < 0.03,
            "{sampler:?}: {rot_deg:.3}° {trans_m:.4} m"
        );
    }
}

#[test]
fn degenerate_input_is_a_flagged_failure_not_an_error() {
    let one = vec![Point3::new(0.0, 0.0, 0.0); 10];
    let (_, target, _) = fixture();
    let r = register_pair(&one, &target, &PairConfig::default()).unwrap();
    assert!(r.failure.is_some());
    assert_eq!(r.target_from_source, Isometry3::identity());
}
