//! `mireg simulate` at the process boundary.

use std::process::Command;

fn simulate_csv(threads: &str) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args(["simulate", "--quick", "--csv", "--seed", "3"])
        .env("RAYON_NUM_THREADS", threads)
        .output()
        .expect("run mireg");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn csv_has_the_documented_columns_and_rows() {
    let csv = simulate_csv("2");
    let mut lines = csv.lines();
    assert_eq!(
        lines.next().unwrap(),
        "strategy,mu,c,sample_size,hypotheses,runs,unique_outlier_free_mean,unique_outlier_free_std,first_success_median"
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    // 9 strategies × 3 sample sizes × 3 budgets.
    assert_eq!(rows.len(), 81);
    assert!(rows.iter().all(|r| r.len() == 9 && r[5] == "5"));
    let levy_mus: std::collections::BTreeSet<&str> = rows
        .iter()
        .filter(|r| r[0] == "levy")
        .map(|r| r[1])
        .collect();
    assert_eq!(levy_mus.len(), 7);
    assert!(
        rows.iter()
            .filter(|r| r[0] != "levy")
            .all(|r| r[1].is_empty() && r[2].is_empty())
    );

    // Analytic oracle: a uniform pair is outlier-free with p = C(300,2)/C(3000,2) ≈ 0.00997, so 1e4
    // hypotheses give ≈ 99.7 unique ones (repeats among 44,850 pairs are negligible). The mean of 5
    // runs has σ ≈ 4.5: accept ±5σ.
    let uniform = rows
        .iter()
        .find(|r| r[0] == "uniform" && r[3] == "2" && r[4] == "10000")
        .unwrap();
    let mean: f64 = uniform[6].parse().unwrap();
    assert!((77.0..122.0).contains(&mean), "uniform s=2 mean {mean}");
}

#[test]
fn same_seed_same_bytes_on_one_and_two_threads() {
    assert_eq!(simulate_csv("1"), simulate_csv("2"));
}
