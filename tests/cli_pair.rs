//! `mireg pair` at the process boundary: the documented JSON keys, ground-truth formats, errors.

use std::process::Command;

fn mireg(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mireg"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn json_has_the_documented_keys_and_matches_the_ground_truth() {
    let out = mireg(&[
        "pair",
        "fixtures/icl_nuim/rgbd5_00004.ply",
        "fixtures/icl_nuim/rgbd5_00000.ply",
        "--voxel",
        "0.05",
        "--gt",
        "fixtures/icl_nuim/trajectory.log",
        "--gt-format",
        "trajectory",
        "--gt-pair",
        "0,4",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in [
        "num_correspondences",
        "num_inliers",
        "hypotheses",
        "converged",
        "fitness",
        "inlier_rmse_m",
    ] {
        assert!(v.get(key).is_some(), "missing {key}");
    }
    let m = v["target_from_source"].as_array().unwrap();
    assert_eq!(m.len(), 4);
    assert!(m.iter().all(|r| r.as_array().unwrap().len() == 4));
    assert_eq!(
        m[3],
        serde_json::json!([0.0, 0.0, 0.0, 1.0]),
        "row-major with the homogeneous row last"
    );
    let t = &v["timings_s"];
    assert!(
        t["total"].as_f64().unwrap() > 0.0
            && t.get("ransac").is_some()
            && t.get("features").is_some()
    );
    assert!(v["rotation_error_deg"].as_f64().unwrap() < 1.0, "{v}");
    assert!(v["translation_error_m"].as_f64().unwrap() < 0.03, "{v}");
}

#[test]
fn bad_inputs_name_the_file() {
    let out = mireg(&[
        "pair",
        "fixtures/icl_nuim/README.md",
        "fixtures/icl_nuim/rgbd5_00000.ply",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("README.md"));
    let out = mireg(&["pair", "nope.ply", "fixtures/icl_nuim/rgbd5_00000.ply"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("nope.ply"));
    let out = mireg(&[
        "pair",
        "a.ply",
        "b.ply",
        "--gt-format",
        "gt-log",
        "--gt",
        "fixtures/icl_nuim/trajectory.log",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--gt-pair"));
}
