//! `mireg sweep` end to end on the fixture: the CSV has exactly the documented columns, one row
//! per cell, and the same seed gives the same table on 1 and 2 threads (timings aside).

use std::process::Command;

/// The standard output of a `mireg` run that must succeed (its standard error on failure).
fn stdout_of_success(out: std::process::Output) -> String {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// `mireg sweep` on the fixture with `args` (after --quick --csv --gaps 10) on `threads`
/// threads: its CSV.
fn fixture_sweep(args: &[&str], threads: &str) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args([
            "sweep",
            concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/icl_livingroom1.mcap"),
            "--quick",
            "--csv",
            "--gaps",
            "10",
        ])
        .args(args)
        .env("RAYON_NUM_THREADS", threads)
        .output()
        .unwrap();
    stdout_of_success(out)
}

fn sweep_csv(threads: &str) -> String {
    fixture_sweep(&["--max-pairs", "4"], threads)
}

/// The CSV without its timing column.
fn untimed(csv: &str) -> Vec<String> {
    csv.lines()
        .map(|l| l.rsplit_once(',').unwrap().0.to_string())
        .collect()
}

#[test]
fn csv_columns_cells_and_thread_independence() {
    let one = sweep_csv("1");
    let mut lines = one.lines();
    assert_eq!(
        lines.next().unwrap(),
        "dataset,ranking,sampler,mu,runs,pairs,recall,precision,hypotheses_median,time_s_median"
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    // --quick: rankings ratio and count_most × (uniform, prosac, 4 Lévy μ).
    assert_eq!(rows.len(), 2 * 6);
    for r in &rows {
        assert_eq!(r.len(), 10);
        assert_eq!(r[0], "icl_livingroom1");
        assert_eq!((r[4], r[5]), ("3", "4"), "runs, pairs");
        match r[2] {
            "levy" => assert!(r[3].parse::<f64>().unwrap() < 0.0),
            "uniform" | "prosac" => assert_eq!(r[3], ""),
            other => panic!("sampler {other}"),
        }
        let (recall, precision): (f64, f64) = (r[6].parse().unwrap(), r[7].parse().unwrap());
        assert!((0.0..=1.0).contains(&recall) && (0.0..=1.0).contains(&precision));
        // 12 attempts per cell: recall is a multiple of 1/12.
        assert!(
            ((recall * 12.0) - (recall * 12.0).round()).abs() < 1e-3,
            "{recall}"
        );
    }
    assert_eq!(untimed(&one), untimed(&sweep_csv("2")));
}

/// A room with boxes (metres), seeded.
fn scene() -> Vec<[f32; 3]> {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(8);
    let mut v = Vec::new();
    for _ in 0..2500 {
        let (u, w): (f32, f32) = (rng.random_range(-2.0..2.0), rng.random_range(0.0..2.0));
        v.push(match rng.random_range(0..3u32) {
            0 => [u, w - 1.0, 3.0],
            1 => [-2.0, w - 1.0, u + 3.0],
            _ => [u, 1.0, w * 1.5 + 1.0],
        });
    }
    for k in 0..5 {
        let c = [
            rng.random_range(-1.5..1.5f32),
            rng.random_range(-0.5..0.5f32),
            rng.random_range(1.5..2.8f32),
        ];
        for _ in 0..300 {
            let mut e = [
                rng.random_range(-0.3..0.3f32),
                rng.random_range(-0.3..0.3f32),
                rng.random_range(-0.3..0.3f32),
            ];
            let axis = (k + rng.random_range(0..3usize)) % 3;
            e[axis] = 0.3 * e[axis].signum();
            v.push([c[0] + e[0], c[1] + e[1], c[2] + e[2]]);
        }
    }
    v
}

fn write_bin(path: &std::path::Path, pts: &[[f32; 3]]) {
    let bytes: Vec<u8> = pts
        .iter()
        .flat_map(|p| [p[0], p[1], p[2], 0.0f32])
        .flat_map(f32::to_le_bytes)
        .collect();
    std::fs::write(path, bytes).unwrap();
}

fn sweep_file(dir: &std::path::Path, gt: &std::path::Path, extra: &[&str]) -> Vec<Vec<String>> {
    let out = Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args([
            "sweep",
            dir.to_str().unwrap(),
            "--gt-log",
            gt.to_str().unwrap(),
        ])
        .args(["--quick", "--csv", "--voxel", "0.05", "--max-te-m", "0.05"])
        .args(extra)
        .output()
        .unwrap();
    stdout_of_success(out)
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

#[test]
fn gt_log_and_bun_conf_pairs_register_to_their_ground_truth() {
    use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let world = scene();
    // Source = the scene seen from a pose moved by target_from_source⁻¹.
    let target_from_source = Isometry3::from_parts(
        Translation3::new(0.15, -0.05, 0.1),
        UnitQuaternion::from_euler_angles(0.02, 0.12, -0.03),
    );
    let source: Vec<[f32; 3]> = world
        .iter()
        .map(|p| {
            let q = target_from_source.inverse()
                * Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            [q.x as f32, q.y as f32, q.z as f32]
        })
        .collect();
    write_bin(&d.join("cloud_bin_0.bin"), &world);
    write_bin(&d.join("cloud_bin_1.bin"), &source);
    let m = target_from_source.to_homogeneous();
    let rows: String = (0..4)
        .map(|r| format!("{} {} {} {}\n", m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]))
        .collect();
    // A second record names a fragment that is absent: skipped.
    std::fs::write(d.join("gt.log"), format!("0 1 2\n{rows}0 7 8\n{rows}")).unwrap();
    for row in sweep_file(d, &d.join("gt.log"), &[]) {
        assert_eq!(
            row[5], "1",
            "one pair: the record with absent clouds is skipped"
        );
        if row[1] == "ratio" && row[2] != "prosac" {
            assert_eq!(row[6], "1.0000", "{row:?}");
        }
    }
    // With a gt.info beside the gt.log, Choi's criterion judges the pair: Λ of the scene's
    // points (as Choi builds it) accepts these registrations at 0.04 m², and none is within
    // 1e-12 m² of a logged pose 1 mm off the true one (as a measured gt.log is; 1 mm is ~1e-6 m²),
    // which the RE/TE thresholds would have passed.
    let logged = (Translation3::new(0.001, 0.0, 0.0) * target_from_source).to_homogeneous();
    let logged_rows: String = (0..4)
        .map(|r| {
            let row = (0..4).map(|c| logged[(r, c)].to_string());
            row.collect::<Vec<_>>().join(" ") + "\n"
        })
        .collect();
    std::fs::write(d.join("gt.log"), format!("0 1 2\n{logged_rows}")).unwrap();
    let points: Vec<nalgebra::Vector3<f64>> = source
        .iter()
        .step_by(10)
        .map(|p| nalgebra::Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])))
        .collect();
    let info = choi_information(&points);
    let info_rows: String = (0..6)
        .map(|r| {
            let row: Vec<String> = (0..6).map(|c| format!("{:e}", info[(r, c)])).collect();
            row.join(" ") + "\n"
        })
        .collect();
    std::fs::write(d.join("gt.info"), format!("0 1 2\n{info_rows}")).unwrap();
    for (limit, recall) in [("0.04", "1.0000"), ("1e-12", "0.0000")] {
        let rows = sweep_file(d, &d.join("gt.log"), &["--max-info-error", limit]);
        let levy = rows
            .iter()
            .find(|r| r[1] == "ratio" && r[2] == "levy")
            .unwrap();
        assert_eq!(levy[6], recall, "--max-info-error {limit}: {levy:?}");
        // precision 0 at 1e-12: reported, but none correct.
        assert_eq!(levy[7], recall, "{levy:?}");
    }
    // The same pair as a bun.conf: translation only, so world = x + t in either convention.
    let t = [0.2f32, 0.0, -0.1];
    let shifted: Vec<[f32; 3]> = world
        .iter()
        .map(|p| [p[0] - t[0], p[1] - t[1], p[2] - t[2]])
        .collect();
    write_bin(&d.join("b.bin"), &shifted);
    std::fs::write(
        d.join("bun.conf"),
        format!(
            "bmesh cloud_bin_0.bin 0 0 0 0 0 0 1\nbmesh b.bin {} {} {} 0 0 0 1\n",
            t[0], t[1], t[2]
        ),
    )
    .unwrap();
    let rows = sweep_file(d, &d.join("bun.conf"), &[]);
    let uniform = rows
        .iter()
        .find(|r| r[1] == "ratio" && r[2] == "uniform")
        .unwrap();
    assert_eq!((uniform[5].as_str(), uniform[6].as_str()), ("1", "1.0000"));
}

/// Choi et al.'s information matrix of a set of corresponding points: `Σ JᵢᵀJᵢ` with
/// `Jᵢ = [I | −2[pᵢ]×]` (their parameterisation by the quaternion's vector part).
fn choi_information(points: &[nalgebra::Vector3<f64>]) -> nalgebra::Matrix6<f64> {
    let mut info = nalgebra::Matrix6::zeros();
    for p in points {
        let mut j = nalgebra::Matrix3x6::zeros();
        j.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&nalgebra::Matrix3::identity());
        j.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-2.0 * p.cross_matrix()));
        info += j.transpose() * j;
    }
    info
}

#[test]
fn choi_error_is_the_mean_squared_displacement_of_the_points() {
    use mireg::sweep::choi_error;
    use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal, UnitSphere};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    let normal = Normal::new(0.0, 1.0).unwrap();
    // Points about 2 m from the origin, off-centre, so the translation–rotation block matters.
    let points: Vec<Vector3<f64>> = (0..400)
        .map(|_| {
            Vector3::new(1.5, -0.8, 2.0) + Vector3::from_fn(|_, _| 0.5 * normal.sample(&mut rng))
        })
        .collect();
    let info = choi_information(&points);
    let gt = Isometry3::from_parts(
        Translation3::new(0.4, -1.0, 0.3),
        UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
    );
    let mut worst: f64 = 0.0;
    for _ in 0..20 {
        let axis: [f64; 3] = UnitSphere.sample(&mut rng);
        let dir: [f64; 3] = UnitSphere.sample(&mut rng);
        // Small errors: 5 mrad and 1 cm.
        let delta = Isometry3::from_parts(
            Translation3::from(0.01 * Vector3::from(dir)),
            UnitQuaternion::from_scaled_axis(0.005 * Vector3::from(axis)),
        );
        let est = gt * delta;
        // Direct: the mean squared displacement of the points under gt⁻¹·est = delta.
        let direct = points
            .iter()
            .map(|p| {
                let p = Point3::from(*p);
                (delta * p - p).norm_squared()
            })
            .sum::<f64>()
            / points.len() as f64;
        let p = choi_error(&gt, &est, &info);
        worst = worst.max((p - direct).abs() / direct);
        // The same rotation written as −q gives the same error.
        let flipped = Isometry3::from_parts(
            est.translation,
            UnitQuaternion::new_unchecked(-est.rotation.into_inner()),
        );
        assert!((choi_error(&gt, &flipped, &info) - p).abs() <= 1e-12 * p);
    }
    // First order: the neglected terms are O(θ) relative, θ = 0.005.
    assert!(worst < 0.02, "worst relative difference {worst}");
    // The exact estimate scores 0.
    assert!(choi_error(&gt, &gt, &info).abs() < 1e-20);
}

/// `--quick` changes defaults only: explicit `--mus`, `--runs` and `--rankings` win over it.
#[test]
fn explicit_flags_win_over_quick() {
    let csv = fixture_sweep(
        &[
            "--max-pairs",
            "2",
            "--mus=-7",
            "--runs",
            "2",
            "--rankings",
            "distance",
        ],
        "2",
    );
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    // One ranking × (uniform, prosac, one Lévy μ).
    assert_eq!(rows.len(), 3, "{csv}");
    for r in &rows {
        assert_eq!(
            (r[1], r[4], r[5]),
            ("distance", "2", "2"),
            "ranking, runs, pairs"
        );
        if r[2] == "levy" {
            assert_eq!(r[3].parse::<f64>().unwrap(), -7.0);
        }
    }
}
