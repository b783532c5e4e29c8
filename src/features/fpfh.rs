//! Fast Point Feature Histograms (Rusu, Blodow & Beetz, "Fast Point Feature Histograms (FPFH) for
//! 3D Registration", ICRA 2009) with Open3D's exact parameterisation and scale
//! (`open3d.pipelines.registration.compute_fpfh_feature`).
//!
//! Per point p with hybrid neighbourhood N(p) (radius + max count, p itself first):
//! - SPFH(p): for every neighbour q after the first entry, the pair features (θ, α, φ) of (p, q)
//!   (Sec. II of the paper) are binned into 3 blocks of 11 bins, each hit adding
//!   `100 / (|N(p)| − 1)`, so every block sums to 100.
//! - FPFH(p) = SPFH(p) + Σ_q SPFH(q) / ‖p − q‖², where each 11-bin block of the weighted sum is
//!   rescaled to sum to 100. Each block of the result therefore sums to 200 (600 in all; 100 per
//!   block when no neighbour at non-zero distance contributes).
//!
//! NOTE: the paper (Eq. 3) weights by 1/(k·ω_k) with ω_k the distance; Open3D (and we) weight by
//! the inverse *squared* distance and normalise each block instead of dividing by k.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::normals::check_search_params;
use crate::geometry::{KdTree, Neighbourhoods};
use crate::{Error, Result};

/// Number of histogram bins: 11 for each of the three angular features.
pub const FPFH_BINS: usize = 33;

/// Bins per angular feature.
const BINS_PER_FEATURE: usize = 11;

/// Mass of one 11-bin block of an SPFH (and of each half of an FPFH block), as Open3D.
const BLOCK_MASS: f64 = 100.0;

/// One FPFH descriptor: blocks [θ | α | φ] of 11 bins, each block normally summing to 200 (see
/// the module docs).
pub type Fpfh = [f32; FPFH_BINS];

/// Computes the FPFH descriptor of every point, exactly as Open3D's `compute_fpfh_feature` with
/// `KDTreeSearchParamHybrid(radius_m, max_nn)` (Open3D registration default: `radius_m = 5 *
/// voxel`, `max_nn = 100`).
///
/// `normals[i]` is the unit normal of `points[i]`; their signs matter (use the same orientation
/// policy on both clouds). A point whose neighbourhood holds only itself gets an all-zero
/// descriptor, as in Open3D. Neighbours at zero distance do not contribute to the weighted sum.
///
/// Arithmetic is f64; the result is rounded to f32. Runs in parallel (rayon), each SPFH computed
/// once; the result does not depend on the thread count.
///
/// Errors: [`Error::InvalidInput`] on length mismatch, non-finite points, `radius_m` not finite and
/// positive, or `max_nn == 0`.
pub fn compute_fpfh(
    points: &[Point3<f64>],
    normals: &[Vector3<f64>],
    radius_m: f64,
    max_nn: usize,
) -> Result<Vec<Fpfh>> {
    let tree = KdTree::new(points)?;
    compute_fpfh_with_tree(points, normals, &tree, radius_m, max_nn)
}

/// [`compute_fpfh`] with a prebuilt tree over exactly `points`.
pub fn compute_fpfh_with_tree(
    points: &[Point3<f64>],
    normals: &[Vector3<f64>],
    tree: &KdTree,
    radius_m: f64,
    max_nn: usize,
) -> Result<Vec<Fpfh>> {
    check_search_params(radius_m, max_nn)?;
    if normals.len() != points.len() || tree.len() != points.len() {
        return Err(Error::InvalidInput(format!(
            "{} points, {} normals and a kd-tree of {} points: lengths must agree",
            points.len(),
            normals.len(),
            tree.len()
        )));
    }
    let nbhd = tree.hybrid_neighbourhoods(points, radius_m, max_nn);
    compute_fpfh_from_neighbourhoods(points, normals, &nbhd)
}

/// [`compute_fpfh_with_tree`] from the hybrid neighbourhoods of every point
/// ([`KdTree::hybrid_neighbourhoods`] or [`grid::self_neighbourhoods`](crate::geometry::grid::self_neighbourhoods)
/// with the FPFH radius and cap), e.g. shared with normal estimation. Each neighbourhood must
/// list the nearest first; the others may come in any order (the weighted sum of the FPFH pass
/// then rounds accordingly).
pub fn compute_fpfh_from_neighbourhoods(
    points: &[Point3<f64>],
    normals: &[Vector3<f64>],
    nbhd: &Neighbourhoods,
) -> Result<Vec<Fpfh>> {
    if normals.len() != points.len() || nbhd.len() != points.len() {
        return Err(Error::InvalidInput(format!(
            "{} points, {} normals and {} neighbourhoods: lengths must agree",
            points.len(),
            normals.len(),
            nbhd.len()
        )));
    }

    // Simplified histograms, flat: N rows of SPFH_STRIDE = the 33 bins, then the sums of the
    // three 11-bin blocks (so the weighted sum of the FPFH pass accumulates them alongside).
    let mut spfh = vec![0.0f64; points.len() * SPFH_STRIDE];
    let edges = theta_edges();
    spfh.par_chunks_mut(SPFH_STRIDE * ROWS_PER_TASK)
        .enumerate()
        .for_each(|(c, hists)| {
            let rows = SpfhRows {
                first: c * ROWS_PER_TASK,
                points,
                normals,
                nbhd,
                edges: &edges,
            };
            #[cfg(target_arch = "x86_64")]
            if avx2_fma() {
                // SAFETY: the CPU supports AVX2 and FMA (checked).
                return unsafe { rows.run_avx2(hists) };
            }
            rows.run(hists);
        });

    let mut out = vec![[0.0f32; FPFH_BINS]; points.len()];
    out.par_chunks_mut(ROWS_PER_TASK)
        .enumerate()
        .for_each(|(c, out)| {
            let rows = FpfhRows {
                first: c * ROWS_PER_TASK,
                spfh: &spfh,
                nbhd,
            };
            #[cfg(target_arch = "x86_64")]
            if avx2_fma() {
                // SAFETY: the CPU supports AVX2 and FMA (checked).
                return unsafe { rows.run_avx2(out) };
            }
            rows.run(out);
        });
    Ok(out)
}

/// Points per rayon task in both passes.
const ROWS_PER_TASK: usize = 64;

/// Length of an SPFH row: 33 bins and the 3 block sums (36 = 9 vectors of 4 f64; must stay a
/// multiple of 4).
const SPFH_STRIDE: usize = FPFH_BINS + 3;

/// Whether the CPU has AVX2 and FMA. The `run_avx2` passes compile the same arithmetic as `run`
/// (Rust never contracts `a + b * c` into a fused multiply-add), so their results are
/// bit-identical; AVX2 only widens the vectorised loops.
#[cfg(target_arch = "x86_64")]
fn avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// The SPFH pass over consecutive points starting at `first`.
struct SpfhRows<'a> {
    first: usize,
    points: &'a [Point3<f64>],
    normals: &'a [Vector3<f64>],
    nbhd: &'a Neighbourhoods,
    edges: &'a [(f64, f64); BINS_PER_FEATURE - 1],
}

impl SpfhRows<'_> {
    /// Fills the rows with `add_pairs(i, neighbours, hist, incr)` adding each pair (i, j) of
    /// point `i` and a neighbour `j` to `hist` (with [`add_bins`]), then the block sums.
    #[inline(always)]
    fn run_with(&self, hists: &mut [f64], add_pairs: impl Fn(usize, &[u32], &mut [f64], f64)) {
        for (k, hist) in hists.chunks_exact_mut(SPFH_STRIDE).enumerate() {
            let i = self.first + k;
            let (idx, _) = self.nbhd.get(i);
            if idx.len() < 2 {
                continue;
            }
            // The first entry is the nearest, i.e. the query point itself (distance 0); Open3D
            // skips the first entry whatever it is, and so do we. The order of the others does
            // not matter here: each bin receives the same increment however often.
            let incr = BLOCK_MASS / (idx.len() - 1) as f64;
            add_pairs(i, &idx[1..], hist, incr);
            for b in 0..3 {
                hist[FPFH_BINS + b] = hist[b * BINS_PER_FEATURE..(b + 1) * BINS_PER_FEATURE]
                    .iter()
                    .sum();
            }
        }
    }

    /// The bins of the pair (point `i`, point `j`).
    #[inline(always)]
    fn pair_bins(&self, i: usize, j: usize) -> [usize; 3] {
        let (points, normals) = (self.points, self.normals);
        pair_bins(&points[i], &normals[i], &points[j], &normals[j], self.edges)
    }

    #[inline(always)]
    fn run(&self, hists: &mut [f64]) {
        self.run_with(hists, |i, neighbours, hist, incr| {
            for &j in neighbours {
                add_bins(hist, self.pair_bins(i, j as usize), incr);
            }
        })
    }

    /// [`run`](Self::run) with the pair features of 4 neighbours at a time in AVX2 lanes: the
    /// same operations in the same order (a separate multiply and add, as nalgebra's `dot`,
    /// `norm` and `cross` evaluate them), so the bins are identical; the 4 lanes overlap the
    /// latencies of the square roots and divisions that bound the scalar loop.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn run_avx2(&self, hists: &mut [f64]) {
        let (points, normals) = (self.points, self.normals);
        self.run_with(hists, |i, neighbours, hist, incr| {
            let mut quads = neighbours.chunks_exact(4);
            for quad in &mut quads {
                let quad: &[u32; 4] = quad.try_into().expect("4 lanes");
                // The closure inherits `run_avx2`'s target features.
                let bins = pair_bins_x4(
                    &points[i],
                    &normals[i],
                    quad.map(|j| &points[j as usize]),
                    quad.map(|j| &normals[j as usize]),
                    self.edges,
                );
                for bins in bins {
                    add_bins(hist, bins, incr);
                }
            }
            for &j in quads.remainder() {
                add_bins(hist, self.pair_bins(i, j as usize), incr);
            }
        })
    }
}

/// Adds `incr` to the θ, α and φ bins `bins` of an SPFH row.
#[inline(always)]
fn add_bins(hist: &mut [f64], [theta, alpha, phi]: [usize; 3], incr: f64) {
    hist[theta] += incr;
    hist[BINS_PER_FEATURE + alpha] += incr;
    hist[2 * BINS_PER_FEATURE + phi] += incr;
}

/// `[theta_bin, unit_bin(α), unit_bin(φ)]` of the pair features of (`p1`, `n1`) and (`p2`, `n2`).
#[inline(always)]
fn pair_bins(
    p1: &Point3<f64>,
    n1: &Vector3<f64>,
    p2: &Point3<f64>,
    n2: &Vector3<f64>,
    edges: &[(f64, f64); BINS_PER_FEATURE - 1],
) -> [usize; 3] {
    let f = pair_features(p1, n1, p2, n2);
    [
        theta_bin(f.theta_y, f.theta_x, edges),
        unit_bin(f.alpha),
        unit_bin(f.phi),
    ]
}

/// The (θ, α, φ) bins of the pairs (`p1`, `n1`)–(`p2[l]`, `n2[l]`) for 4 lanes `l`: exactly
/// [`pair_bins`], lane by lane: the features ([`pair_features_x4`]), then their bins
/// ([`theta_bins_x4`], [`unit_bins_x4`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn pair_bins_x4(
    p1: &Point3<f64>,
    n1: &Vector3<f64>,
    p2: [&Point3<f64>; 4],
    n2: [&Vector3<f64>; 4],
    edges: &[(f64, f64); BINS_PER_FEATURE - 1],
) -> [[usize; 3]; 4] {
    let [theta_y, theta_x, alpha, phi] = pair_features_x4(p1, n1, p2, n2);
    let theta = theta_bins_x4(theta_y, theta_x, edges);
    let (alpha, phi) = (unit_bins_x4(alpha), unit_bins_x4(phi));
    std::array::from_fn(|l| [theta[l], alpha[l] as usize, phi[l] as usize])
}

/// The (θ_y, θ_x, α, φ) features of [`pair_features`] (θ as the y and x of its `atan2`) of the
/// pairs (`p1`, `n1`)–(`p2[l]`, `n2[l]`), lane `l` of each vector: exactly nalgebra's
/// arithmetic, operation by operation.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
fn pair_features_x4(
    p1: &Point3<f64>,
    n1: &Vector3<f64>,
    p2: [&Point3<f64>; 4],
    n2: [&Vector3<f64>; 4],
) -> [std::arch::x86_64::__m256d; 4] {
    use std::arch::x86_64::*;
    // Lane l of a vector is element l of the array.
    let lanes = |f: &dyn Fn(usize) -> f64| _mm256_setr_pd(f(0), f(1), f(2), f(3));
    let splat = |x: f64| _mm256_set1_pd(x);
    let (add, sub, mul, div) = (_mm256_add_pd, _mm256_sub_pd, _mm256_mul_pd, _mm256_div_pd);
    // nalgebra's dot: (a·x + a·y) + a·z, each product rounded.
    let dot = |a: [__m256d; 3], b: [__m256d; 3]| {
        add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))
    };
    // nalgebra's cross.
    let cross = |a: [__m256d; 3], b: [__m256d; 3]| {
        [
            sub(mul(a[1], b[2]), mul(a[2], b[1])),
            sub(mul(a[2], b[0]), mul(a[0], b[2])),
            sub(mul(a[0], b[1]), mul(a[1], b[0])),
        ]
    };
    let select = |mask: __m256d, yes: __m256d, no: __m256d| _mm256_blendv_pd(no, yes, mask);
    let sign = splat(-0.0);
    let zero = _mm256_setzero_pd();

    let n1v = [splat(n1.x), splat(n1.y), splat(n1.z)];
    let n2v = [
        lanes(&|l| n2[l].x),
        lanes(&|l| n2[l].y),
        lanes(&|l| n2[l].z),
    ];
    let mut d = [
        sub(lanes(&|l| p2[l].x), splat(p1.x)),
        sub(lanes(&|l| p2[l].y), splat(p1.y)),
        sub(lanes(&|l| p2[l].z), splat(p1.z)),
    ];
    // ‖d‖ (nalgebra: 0 + d·d, and 0 + x is x for the non-negative d·d).
    let dist = _mm256_sqrt_pd(dot(d, d));
    let cos1 = div(dot(n1v, d), dist);
    let cos2 = div(dot(n2v, d), dist);
    let swap =
        _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, cos1), _mm256_andnot_pd(sign, cos2));
    for c in &mut d {
        *c = select(swap, _mm256_xor_pd(*c, sign), *c);
    }
    let ns: [__m256d; 3] = std::array::from_fn(|a| select(swap, n2v[a], n1v[a]));
    let nt: [__m256d; 3] = std::array::from_fn(|a| select(swap, n1v[a], n2v[a]));
    let phi = select(swap, _mm256_xor_pd(cos2, sign), cos1);
    let v = cross(d, ns);
    let v_norm = _mm256_sqrt_pd(dot(v, v));
    let w = cross(ns, v);
    // Coincident points or a normal along the line: all-zero features.
    let degenerate = _mm256_or_pd(
        _mm256_cmp_pd::<_CMP_EQ_OQ>(dist, zero),
        _mm256_cmp_pd::<_CMP_EQ_OQ>(v_norm, zero),
    );
    let keep = |x: __m256d| select(degenerate, zero, x);
    let theta_y = keep(dot(w, nt));
    let theta_x = keep(mul(dot(ns, nt), v_norm));
    let alpha = keep(div(dot(v, nt), v_norm));
    let phi = keep(phi);
    [theta_y, theta_x, alpha, phi]
}

/// [`unit_bin`] of each lane of `x`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
fn unit_bins_x4(x: std::arch::x86_64::__m256d) -> [i32; 4] {
    use std::arch::x86_64::*;
    let (add, mul, splat) = (_mm256_add_pd, _mm256_mul_pd, _mm256_set1_pd);
    let zero = _mm256_setzero_pd();
    // unit_bin: truncation of 11·(x + 1)·0.5 clamped to [0, 10]; clamping before truncating
    // gives the same bin for every input (max returns 0 for NaN, which truncates to 0 as well).
    let b = mul(
        mul(splat(BINS_PER_FEATURE as f64), add(x, splat(1.0))),
        splat(0.5),
    );
    let b = _mm256_min_pd(_mm256_max_pd(b, zero), splat((BINS_PER_FEATURE - 1) as f64));
    let mut out = [0i32; 4];
    // SAFETY: `out` is 16 writable bytes; the store is unaligned.
    unsafe { _mm_storeu_si128(out.as_mut_ptr().cast(), _mm256_cvttpd_epi32(b)) };
    out
}

/// [`theta_bin`] of each lane of (`theta_y`, `theta_x`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
fn theta_bins_x4(
    theta_y: std::arch::x86_64::__m256d,
    theta_x: std::arch::x86_64::__m256d,
    edges: &[(f64, f64); BINS_PER_FEATURE - 1],
) -> [usize; 4] {
    use std::arch::x86_64::*;
    let (add, sub, mul, splat) = (_mm256_add_pd, _mm256_sub_pd, _mm256_mul_pd, _mm256_set1_pd);
    let select = |mask: __m256d, yes: __m256d, no: __m256d| _mm256_blendv_pd(no, yes, mask);
    let zero = _mm256_setzero_pd();
    // theta_bin: edges passed in the half-plane of the sign of y.
    let lower = theta_y; // blendv selects on the sign bit, as is_sign_negative.
    let mut count = select(lower, zero, splat(5.0));
    for k in 0..5 {
        let (sin, cos) = (
            select(lower, splat(edges[k].0), splat(edges[5 + k].0)),
            select(lower, splat(edges[k].1), splat(edges[5 + k].1)),
        );
        let passed = _mm256_cmp_pd::<_CMP_GE_OQ>(sub(mul(theta_y, cos), mul(theta_x, sin)), zero);
        count = add(count, _mm256_and_pd(passed, splat(1.0)));
    }
    let (mut theta, mut ty, mut tx) = ([0i32; 4], [0.0f64; 4], [0.0f64; 4]);
    // SAFETY: each destination is a local array of exactly the stored size (16 and 32 bytes);
    // the stores are unaligned.
    unsafe {
        _mm_storeu_si128(theta.as_mut_ptr().cast(), _mm256_cvttpd_epi32(count));
        _mm256_storeu_pd(ty.as_mut_ptr(), theta_y);
        _mm256_storeu_pd(tx.as_mut_ptr(), theta_x);
    }
    std::array::from_fn(|l| {
        if ty[l] == 0.0 && tx[l] == 0.0 {
            // atan2's signed-zero conventions.
            theta_bin(ty[l], tx[l], edges)
        } else {
            theta[l] as usize
        }
    })
}

/// The weighted-sum pass over consecutive points starting at `first`.
struct FpfhRows<'a> {
    first: usize,
    /// SPFH rows of [`SPFH_STRIDE`] values.
    spfh: &'a [f64],
    nbhd: &'a Neighbourhoods,
}

impl FpfhRows<'_> {
    /// SPFH row of point `j`.
    #[inline(always)]
    fn row(&self, j: usize) -> &[f64; SPFH_STRIDE] {
        self.spfh[j * SPFH_STRIDE..(j + 1) * SPFH_STRIDE]
            .try_into()
            .expect("SPFH row")
    }

    /// Runs the pass with `accumulate(acc, row, w)` doing `acc[b] += row[b] * w` for every `b`
    /// (a separate multiply and add, so every implementation rounds identically).
    #[inline(always)]
    fn run_with(
        &self,
        out: &mut [Fpfh],
        accumulate: impl Fn(&mut [f64; SPFH_STRIDE], &[f64; SPFH_STRIDE], f64),
    ) {
        for (k, out) in out.iter_mut().enumerate() {
            let i = self.first + k;
            let (idx, d2) = self.nbhd.get(i);
            if idx.len() < 2 {
                continue;
            }
            // Bins and block sums.
            let mut acc = [0.0f64; SPFH_STRIDE];
            for (&j, &dist_sq) in idx[1..].iter().zip(&d2[1..]) {
                if dist_sq == 0.0 {
                    continue;
                }
                // NOTE: Open3D divides each bin by the squared distance; multiplying by the
                // reciprocal and summing the block totals once differ from it by rounding only.
                accumulate(&mut acc, self.row(j as usize), 1.0 / dist_sq);
            }
            let own = self.row(i);
            for b in 0..FPFH_BINS {
                let s = acc[FPFH_BINS + b / BINS_PER_FEATURE];
                let scale = if s != 0.0 { BLOCK_MASS / s } else { 0.0 };
                out[b] = (acc[b] * scale + own[b]) as f32;
            }
        }
    }

    fn run(&self, out: &mut [Fpfh]) {
        self.run_with(out, |acc, row, w| {
            for (a, &r) in acc.iter_mut().zip(row) {
                *a += r * w;
            }
        })
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn run_avx2(&self, out: &mut [Fpfh]) {
        use std::arch::x86_64::{
            _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_set1_pd, _mm256_storeu_pd,
        };
        self.run_with(out, |acc, row, w| {
            let w = _mm256_set1_pd(w);
            for (a, r) in acc.chunks_exact_mut(4).zip(row.chunks_exact(4)) {
                // SAFETY: both chunks hold exactly 4 f64 (SPFH_STRIDE is a multiple of 4).
                unsafe {
                    let product = _mm256_mul_pd(_mm256_loadu_pd(r.as_ptr()), w);
                    let sum = _mm256_add_pd(_mm256_loadu_pd(a.as_ptr()), product);
                    _mm256_storeu_pd(a.as_mut_ptr(), sum);
                }
            }
        })
    }
}

/// The Darboux-frame pair features of Rusu et al. 2009, Sec. II, in Open3D's conventions.
#[derive(Debug, Clone, Copy, PartialEq)]
struct PairFeatures {
    /// θ = atan2(`theta_y`, `theta_x`) ∈ [−π, π] with `theta_y` = s·(w · n_t) ...
    theta_y: f64,
    /// ... and `theta_x` = s·(u · n_t), for a common factor s > 0 (‖d × u‖, which saves the
    /// normalisation of v; binned without evaluating the arctangent: [`theta_bin`]).
    theta_x: f64,
    /// α = v · n_t ∈ [−1, 1].
    alpha: f64,
    /// φ = u · (p_t − p_s) / d ∈ [−1, 1].
    phi: f64,
}

impl PairFeatures {
    /// θ = atan2(w · n_t, u · n_t) ∈ [−π, π].
    #[cfg(test)]
    fn theta(&self) -> f64 {
        self.theta_y.atan2(self.theta_x)
    }
}

/// Sines and cosines of the 10 inner bin edges θ_k = −π + 2πk/11 (k = 1..=10) of [`angle_bin`].
fn theta_edges() -> [(f64, f64); BINS_PER_FEATURE - 1] {
    std::array::from_fn(|k| {
        let edge = -std::f64::consts::PI
            + 2.0 * std::f64::consts::PI * (k + 1) as f64 / BINS_PER_FEATURE as f64;
        (edge.sin(), edge.cos())
    })
}

/// `angle_bin(atan2(y, x))` without the arctangent (a libm call that was 15% of FPFH): with θ
/// and the edge θ_k in the same half-plane, θ ≥ θ_k ⇔ sin(θ − θ_k) ≥ 0 ⇔ y·cos θ_k − x·sin θ_k
/// ≥ 0, so the bin is the count of edges passed. Equals the arctangent path except within
/// rounding of an edge. `edges` from [`theta_edges`].
fn theta_bin(y: f64, x: f64, edges: &[(f64, f64); BINS_PER_FEATURE - 1]) -> usize {
    if y == 0.0 && x == 0.0 {
        // atan2's signed-zero conventions (0, ±π).
        return angle_bin(y.atan2(x));
    }
    // Lower half-plane (sign of y, as atan2): θ ∈ [−π, 0] spans bins 0..=5, edges 1..=5;
    // upper: θ ∈ [0, π], bins 5..=10, edges 6..=10.
    let (mut bin, half) = if y.is_sign_negative() {
        (0, &edges[..5])
    } else {
        (5, &edges[5..])
    };
    for &(sin, cos) in half {
        bin += usize::from(y * cos - x * sin >= 0.0);
    }
    bin
}

/// Pair features of (p1, n1) and (p2, n2). The source is the point whose normal makes the smaller
/// angle with the connecting line (Eq. 1 of the paper); the frame is u = n_s, v = d × u / ‖·‖,
/// w = u × v. Coincident points, or a normal parallel to the connecting line, give all-zero
/// features (Open3D's convention; they then land in the middle bin of each block).
///
/// NOTE: Open3D compares `acos(|cos|)`; we compare `|cos|` directly (equivalent, monotone), which
/// can only differ where acos rounds two distinct inputs to the same value.
fn pair_features(
    p1: &Point3<f64>,
    n1: &Vector3<f64>,
    p2: &Point3<f64>,
    n2: &Vector3<f64>,
) -> PairFeatures {
    const ZERO: PairFeatures = PairFeatures {
        theta_y: 0.0,
        theta_x: 0.0,
        alpha: 0.0,
        phi: 0.0,
    };
    let mut d = p2 - p1;
    let dist = d.norm();
    if dist == 0.0 {
        return ZERO;
    }
    // Both cosines are divided before they are compared, as Open3D: on near-parallel normals
    // (flat ground) the undivided products differ where the cosines tie.
    let cos1 = n1.dot(&d) / dist;
    let cos2 = n2.dot(&d) / dist;
    let (ns, nt, phi) = if cos1.abs() < cos2.abs() {
        d = -d;
        (n2, n1, -cos2)
    } else {
        (n1, n2, cos1)
    };
    // v = d × u unnormalised: θ only needs the signs of scaled sines, α one division.
    let v = d.cross(ns);
    let v_norm = v.norm();
    if v_norm == 0.0 {
        return ZERO;
    }
    let w = ns.cross(&v);
    PairFeatures {
        theta_y: w.dot(nt),
        theta_x: ns.dot(nt) * v_norm,
        alpha: v.dot(nt) / v_norm,
        phi,
    }
}

/// Bin of an angle in [−π, π] among 11 equal bins (clamped).
fn angle_bin(theta: f64) -> usize {
    clamp_bin(
        BINS_PER_FEATURE as f64 * (theta + std::f64::consts::PI) / (2.0 * std::f64::consts::PI),
    )
}

/// Bin of a cosine-like value in [−1, 1] among 11 equal bins (clamped).
fn unit_bin(x: f64) -> usize {
    clamp_bin(BINS_PER_FEATURE as f64 * (x + 1.0) * 0.5)
}

/// Clamps a bin position to [0, 10]. Truncation equals Open3D's `floor` here: they differ only
/// on negative inputs, which both clamp to 0 (and truncation avoids a libm call).
fn clamp_bin(b: f64) -> usize {
    (b as i64).clamp(0, BINS_PER_FEATURE as i64 - 1) as usize
}

#[cfg(test)]
mod tests;
