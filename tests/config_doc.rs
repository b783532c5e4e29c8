//! The example in docs/CONFIG.md parses, and its "derived" values are what the defaults derive.

use mireg::pipeline::PairConfig;

#[test]
fn documented_example_parses_and_matches_the_defaults() {
    let doc =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/CONFIG.md")).unwrap();
    let toml_text = doc
        .split("```toml")
        .nth(1)
        .unwrap()
        .split("```")
        .next()
        .unwrap();
    let from_doc: PairConfig = toml::from_str(toml_text).expect("docs/CONFIG.md example parses");
    let defaults = PairConfig::default().resolved().unwrap();
    let doc = from_doc.resolved().unwrap();
    let close = |a: Option<f64>, b: Option<f64>| (a.unwrap() - b.unwrap()).abs() < 1e-12;
    assert_eq!(doc.voxel_size_m, defaults.voxel_size_m);
    assert!(close(doc.normal_radius_m, defaults.normal_radius_m));
    assert!(close(doc.feature_radius_m, defaults.feature_radius_m));
    assert!(close(doc.inlier_threshold_m, defaults.inlier_threshold_m));
    assert!(close(doc.icp_voxel_size_m, defaults.icp_voxel_size_m));
    assert!(close(doc.icp_max_distance_m, defaults.icp_max_distance_m));
    assert!(close(doc.icp_fine_distance_m, defaults.icp_fine_distance_m));
    assert_eq!(doc.icp_fine, defaults.icp_fine);
    assert_eq!(doc.sampler, defaults.sampler);
    // Unknown keys are rejected, not ignored.
    assert!(toml::from_str::<PairConfig>("voxel_sise_m = 0.1").is_err());
}
