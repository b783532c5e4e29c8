use super::*;
use nalgebra::{Isometry3, Rotation3, Translation3, Unit};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64;

/// A bumpy closed surface (sphere with a height field) with analytic-ish normals from PCA.
fn bumpy_cloud(n: usize, seed: u64) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let mut rng = Pcg64::seed_from_u64(seed);
    let points: Vec<Point3<f64>> = (0..n)
        .map(|_| {
            let u: [f64; 3] = rand_distr::Distribution::sample(&rand_distr::UnitSphere, &mut rng);
            let d = Vector3::from(u);
            let r = 1.0 + 0.15 * (3.0 * d.x).sin() * (2.0 * d.y).cos() + 0.1 * d.z * d.z;
            Point3::from(d * r)
        })
        .collect();
    let normals =
        crate::geometry::estimate_normals(&points, 0.2, 30, Some(Point3::origin())).unwrap();
    (points, normals)
}

#[test]
fn blocks_sum_to_open3d_scale() {
    let (points, normals) = bumpy_cloud(1500, 61);
    let f = compute_fpfh(&points, &normals, 0.3, 100).unwrap();
    for h in &f {
        for block in h.chunks(BINS_PER_FEATURE) {
            let s: f32 = block.iter().sum();
            assert!((s - 200.0).abs() < 1e-3, "block sums to {s}");
        }
    }
}

#[test]
fn invariant_to_rigid_motion() {
    let (points, normals) = bumpy_cloud(1500, 71);
    let mut rng = Pcg64::seed_from_u64(72);
    let axis = Unit::new_normalize(Vector3::new(0.3, -0.8, 0.5));
    let motion = Isometry3::from_parts(
        Translation3::new(
            rng.random_range(-5.0..5.0),
            rng.random_range(-5.0..5.0),
            2.0,
        ),
        Rotation3::from_axis_angle(&axis, rng.random_range(0.5..3.0)).into(),
    );
    let moved: Vec<Point3<f64>> = points.iter().map(|p| motion * p).collect();
    let turned: Vec<Vector3<f64>> = normals.iter().map(|n| motion * n).collect();
    let a = compute_fpfh(&points, &normals, 0.3, 100).unwrap();
    let b = compute_fpfh(&moved, &turned, 0.3, 100).unwrap();
    // A rigid motion perturbs coordinates by rounding only, far below the f32 output's
    // resolution. A pair feature landing on an exact bin boundary could still flip bins
    // (~1e-2 relative); with this seed none does (measured: all differences exactly 0).
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| {
            let diff: f64 = x
                .iter()
                .zip(y)
                .map(|(p, q)| f64::from(p - q).powi(2))
                .sum::<f64>()
                .sqrt();
            let norm: f64 = x.iter().map(|p| f64::from(*p).powi(2)).sum::<f64>().sqrt();
            diff / norm
        })
        .fold(0.0, f64::max);
    assert!(worst < 1e-4, "worst relative difference {worst}");
}

#[test]
fn pair_features_of_constructed_configurations() {
    let o = Point3::origin();
    // Parallel normals perpendicular to the connecting line: θ = 0, α = 0, φ = 0.
    let f = pair_features(
        &o,
        &Vector3::z(),
        &Point3::new(1.0, 0.0, 0.0),
        &Vector3::z(),
    );
    assert_eq!((f.theta(), f.alpha, f.phi), (0.0, 0.0, 0.0));
    // Source normal at 45° to the line, target normal tilted about the line:
    // n1 = (1,0,1)/√2, line = +x => φ = cos 45°; n2 = z: α = v·n2 with v = d × n1 ∝ (0,-1,0)... = 0.
    let n1 = Vector3::new(1.0, 0.0, 1.0).normalize();
    let f = pair_features(&o, &n1, &Point3::new(2.0, 0.0, 0.0), &Vector3::z());
    assert!((f.phi - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-15);
    assert!(f.alpha.abs() < 1e-15);
    // u = n1, w = u × v with v = (0,-1,0): w = (1/√2)(1,0,1)×(0,-1,0) = (1/√2)(1,0,-1);
    // θ = atan2(w·z, u·z) = atan2(-1/√2, 1/√2) = -π/4.
    assert!((f.theta() + std::f64::consts::FRAC_PI_4).abs() < 1e-15);
    // Swapped roles: the second normal makes the smaller angle with the line.
    let g = pair_features(&Point3::new(2.0, 0.0, 0.0), &Vector3::z(), &o, &n1);
    assert!((g.phi - f.phi).abs() < 1e-15 && (g.theta() - f.theta()).abs() < 1e-15);
    // Coincident points: all zero.
    assert_eq!(
        pair_features(&o, &n1, &o, &Vector3::z()),
        PairFeatures {
            theta_y: 0.0,
            theta_x: 0.0,
            alpha: 0.0,
            phi: 0.0
        }
    );
    // Bin edges.
    assert_eq!(
        (
            angle_bin(-std::f64::consts::PI),
            angle_bin(std::f64::consts::PI),
            angle_bin(0.0)
        ),
        (0, 10, 5)
    );
    assert_eq!((unit_bin(-1.0), unit_bin(1.0), unit_bin(0.0)), (0, 10, 5));
}

#[test]
fn isolated_points_are_zero_and_threads_do_not_matter() {
    let (mut points, mut normals) = bumpy_cloud(800, 81);
    points.push(Point3::new(10.0, 0.0, 0.0));
    normals.push(Vector3::z());
    let run = |t| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| compute_fpfh(&points, &normals, 0.3, 50).unwrap())
    };
    let one = run(1);
    assert_eq!(one, run(3));
    assert_eq!(one.last().unwrap(), &[0.0f32; FPFH_BINS]);
    assert!(matches!(
        compute_fpfh(&points, &normals[1..], 0.3, 50),
        Err(Error::InvalidInput(_))
    ));
}

#[test]
fn theta_bin_equals_binned_arctangent() {
    let edges = theta_edges();
    let mut rng = Pcg64::seed_from_u64(77);
    for _ in 0..200_000 {
        let (y, x): (f64, f64) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        assert_eq!(
            theta_bin(y, x, &edges),
            angle_bin(y.atan2(x)),
            "y {y} x {x}"
        );
    }
    // Axes and signed zeros, as atan2.
    for y in [0.0, -0.0, 1.0, -1.0, 1e-300, -1e-300] {
        for x in [0.0, -0.0, 1.0, -1.0, 1e-300, -1e-300] {
            assert_eq!(
                theta_bin(y, x, &edges),
                angle_bin(y.atan2(x)),
                "y {y} x {x}"
            );
        }
    }
    // Points just either side of every edge (well beyond rounding).
    for k in 1..BINS_PER_FEATURE {
        let edge =
            -std::f64::consts::PI + 2.0 * std::f64::consts::PI * k as f64 / BINS_PER_FEATURE as f64;
        for t in [edge - 1e-9, edge + 1e-9] {
            let (y, x) = (t.sin(), t.cos());
            assert_eq!(theta_bin(y, x, &edges), angle_bin(y.atan2(x)), "θ {t}");
        }
    }
}
#[cfg(target_arch = "x86_64")]
#[test]
fn vector_pair_bins_equal_the_scalar_ones() {
    if !avx2_fma() {
        eprintln!("skipped: this CPU has no AVX2 + FMA");
        return;
    }
    let edges = theta_edges();
    let mut rng = Pcg64::seed_from_u64(91);
    let unit = |rng: &mut Pcg64| {
        Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0f64),
        )
        .normalize()
    };
    // Degenerate and boundary configurations next to random ones: coincident points, normals
    // along the connecting line, equal cosines (the swap tie), parallel normals (θ = 0),
    // exact zeros of both signs, and unnormalised or non-finite normals.
    type Pair = (Point3<f64>, Vector3<f64>, Point3<f64>, Vector3<f64>);
    let mut pairs: Vec<Pair> = vec![
        (
            Point3::origin(),
            Vector3::z(),
            Point3::origin(),
            Vector3::x(),
        ),
        (
            Point3::origin(),
            Vector3::x(),
            Point3::new(1.0, 0.0, 0.0),
            Vector3::z(),
        ),
        (
            Point3::origin(),
            Vector3::z(),
            Point3::new(1.0, 0.0, 0.0),
            Vector3::z(),
        ),
        (
            Point3::origin(),
            -Vector3::z(),
            Point3::new(-1.0, 0.0, 0.0),
            Vector3::z(),
        ),
        (
            Point3::origin(),
            Vector3::y(),
            Point3::new(0.0, -0.0, 2.0),
            -Vector3::y(),
        ),
        (
            Point3::origin(),
            Vector3::new(1.0, 0.0, 1.0).normalize(),
            Point3::new(2.0, 0.0, 0.0),
            Vector3::new(-1.0, 0.0, 1.0).normalize(),
        ),
        (
            Point3::origin(),
            Vector3::new(1.0, 0.0, 1.0).normalize(),
            Point3::new(1.0, 0.0, 0.0),
            Vector3::new(1.0, 1.0, 0.0).normalize(),
        ),
        (
            Point3::origin(),
            Vector3::new(0.0, 3.0, 4.0),
            Point3::new(1.0, 1.0, 0.0),
            Vector3::new(5.0, 0.0, 0.0),
        ),
        (
            Point3::origin(),
            Vector3::new(f64::NAN, 0.0, 1.0),
            Point3::new(1.0, 0.0, 0.0),
            Vector3::z(),
        ),
        (
            Point3::origin(),
            Vector3::z(),
            Point3::new(1.0, 0.0, 0.0),
            Vector3::new(f64::INFINITY, 0.0, 0.0),
        ),
    ];
    for _ in 0..40_000 {
        let p1 = Point3::from(unit(&mut rng) * rng.random_range(0.0..3.0));
        let p2 = p1 + unit(&mut rng) * rng.random_range(0.0..1.0);
        // Snap some normals to axes and some points onto each other's planes.
        let n1 = if rng.random_bool(0.2) {
            Vector3::z()
        } else {
            unit(&mut rng)
        };
        let n2 = if rng.random_bool(0.2) {
            n1
        } else {
            unit(&mut rng)
        };
        let p2 = if rng.random_bool(0.1) {
            Point3::new(p2.x, p2.y, p1.z)
        } else {
            p2
        };
        pairs.push((p1, n1, p2, n2));
    }
    // Each pair in every lane, next to three random ones.
    for (k, (p1, n1, p2, n2)) in pairs.iter().enumerate() {
        for lane in 0..4 {
            let others: [usize; 4] = std::array::from_fn(|l| {
                if l == lane {
                    k
                } else {
                    rng.random_range(0..pairs.len())
                }
            });
            // Lanes share the first point: take each other pair's second point relative to it.
            let p2s: [Point3<f64>; 4] = others.map(|o| {
                if o == k {
                    *p2
                } else {
                    p1 + (pairs[o].2 - pairs[o].0)
                }
            });
            let n2s: [Vector3<f64>; 4] = others.map(|o| if o == k { *n2 } else { pairs[o].3 });
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            let got = unsafe {
                pair_bins_x4(
                    p1,
                    n1,
                    std::array::from_fn(|l| &p2s[l]),
                    std::array::from_fn(|l| &n2s[l]),
                    &edges,
                )
            };
            for l in 0..4 {
                assert_eq!(
                    got[l],
                    pair_bins(p1, n1, &p2s[l], &n2s[l], &edges),
                    "pair {k}, lane {l}: {p1:?} {n1:?} {:?} {:?}",
                    p2s[l],
                    n2s[l]
                );
            }
        }
    }
}
