//! `mireg sweep` end to end on the fixture: the CSV has exactly the documented columns, one row
//! per cell, and the same seed gives the same table on 1 and 2 threads (timings aside).

use std::process::Command;

fn sweep_csv(threads: &str) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_mireg"))
        .args([
            "sweep",
            concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/icl_livingroom1.mcap"),
            "--quick",
            "--csv",
            "--max-pairs",
            "4",
            "--gaps",
            "10",
        ])
        .env("RAYON_NUM_THREADS", threads)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
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
