//! The voxel derived from a cloud's range distribution (`voxel_for_cloud`): median range / 40,
//! checked against a sort-based median on an indoor (RGB-D-like) and an outdoor (spinning
//! LiDAR-like) cloud, and on the fixture's first real cloud; `mireg register` without `--voxel`
//! uses it and says so.

use mireg::pipeline::{VOXEL_PER_MEDIAN_RANGE, voxel_for_cloud};
use nalgebra::Point3;
use rand::{RngExt, SeedableRng};

fn median_range(points: &[Point3<f64>]) -> f64 {
    let mut r: Vec<f64> = points
        .iter()
        .map(|p| p.coords.norm())
        .filter(|&r| r > 0.0)
        .collect();
    r.sort_by(f64::total_cmp);
    r[r.len() / 2]
}

#[test]
fn indoor_and_outdoor_clouds_get_voxels_from_their_median_range() {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
    // A depth camera 0.5–4 m from a room, plus zero returns (dropped).
    let mut indoor: Vec<Point3<f64>> = (0..20_001)
        .map(|_| {
            let (u, v, d): (f64, f64, f64) = (
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.4..0.4),
                rng.random_range(0.5..4.0),
            );
            Point3::new(u * d, v * d, d)
        })
        .collect();
    indoor.extend(std::iter::repeat_n(Point3::origin(), 500));
    // A spinning LiDAR on a street: ranges 2–120 m, mostly near.
    let outdoor: Vec<Point3<f64>> = (0..50_001)
        .map(|_| {
            let a = rng.random_range(0.0..std::f64::consts::TAU);
            let r = 2.0 + 118.0 * rng.random::<f64>().powi(3);
            Point3::new(r * a.cos(), r * a.sin(), rng.random_range(-2.0..2.0))
        })
        .collect();
    for cloud in [&indoor, &outdoor] {
        let v = voxel_for_cloud(cloud).unwrap();
        let expected = median_range(cloud) * VOXEL_PER_MEDIAN_RANGE;
        assert!(
            (v - expected).abs() <= 1e-12 * expected,
            "{v} vs {expected}"
        );
    }
    let (vi, vo) = (
        voxel_for_cloud(&indoor).unwrap(),
        voxel_for_cloud(&outdoor).unwrap(),
    );
    assert!((0.03..0.08).contains(&vi), "indoor {vi}");
    assert!((0.2..1.0).contains(&vo), "outdoor {vo}");
    assert_eq!(voxel_for_cloud(&[Point3::origin(); 10]), None);
    assert_eq!(voxel_for_cloud(&indoor[..2]), None);
}

#[test]
fn register_without_voxel_derives_it_from_the_first_cloud() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.mcap");
    std::fs::write(
        &input,
        mireg::fuzzing::small_log(2, mcap::WriteOptions::new()),
    )
    .unwrap();
    let out = dir.path().join("out.mcap");
    let register = |extra: &[&str]| -> serde_json::Value {
        let run = std::process::Command::new(env!("CARGO_BIN_EXE_mireg"))
            .args([
                "register",
                input.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
            ])
            .args(["--json", "--force"])
            .args(extra)
            .output()
            .unwrap();
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        serde_json::from_slice(&run.stdout).unwrap()
    };
    let s = register(&[]);
    assert_eq!(s["voxel_source"], "first_cloud");
    // The seed log's first cloud, decoded by the library, gives the same voxel.
    let mut first = None;
    mireg::io::mcap::read::for_each_record(&input, |r| {
        if let mcap::records::Record::Message { data, .. } = r
            && first.is_none()
            && let Ok(c) = mireg::io::codec::cdr::decode_point_cloud2(&data)
        {
            first = Some(c.points);
        }
        Ok(())
    })
    .unwrap();
    let expected = median_range(&first.unwrap()) * VOXEL_PER_MEDIAN_RANGE;
    assert!((s["voxel_m"].as_f64().unwrap() - expected).abs() < 1e-12);
    // Few points: global registration stays on the voxel cloud; a bound below its size moves
    // it up the ladder voxel · 2^(k/4).
    assert_eq!(s["feature_voxel_m"], s["voxel_m"]);
    let s = register(&["--voxel", "0.07", "--feature-points", "10"]);
    // The run's voxel stays the configured one; only global registration moves up.
    assert_eq!(s["voxel_m"], 0.07, "{s}");
    let k = (s["feature_voxel_m"].as_f64().unwrap() / 0.07).ln()
        / mireg::pipeline::FEATURE_VOXEL_STEP.ln();
    assert!(k > 0.5 && (k - k.round()).abs() < 1e-9, "{s}");
    let s = register(&["--voxel", "0.07"]);
    assert_eq!(
        (s["voxel_source"].as_str(), s["voxel_m"].as_f64()),
        (Some("configured"), Some(0.07))
    );
}
