//! PROSAC's sampler against a direct computation of its growth schedule (Chum & Matas 2005, Eq. 3).

use mireg::ransac::{Prosac, Sampler, hypothesis_rng};

/// T_n = T_N · C(n, m) / C(N, m), computed from binomial coefficients (in log space).
fn t_n(n: usize, m: usize, big_n: usize, t_big_n: f64) -> f64 {
    let ln_binom = |a: usize, b: usize| -> f64 {
        (0..b)
            .map(|i| ((a - i) as f64).ln() - ((i + 1) as f64).ln())
            .sum()
    };
    t_big_n * (ln_binom(n, m) - ln_binom(big_n, m)).exp()
}

#[test]
fn growth_schedule_matches_direct_computation() {
    for (big_n, m, t_big_n) in [
        (100usize, 3usize, 200_000u64),
        (500, 4, 10_000),
        (50, 2, 1_000),
    ] {
        let p = Prosac::new(big_n, m, t_big_n).unwrap();
        // T'_m = 1; T'_{n+1} = T'_n + ceil(T_{n+1} − T_n).
        let mut t_prime = vec![0u64; big_n + 1];
        t_prime[m] = 1;
        for n in m..big_n {
            let inc =
                (t_n(n + 1, m, big_n, t_big_n as f64) - t_n(n, m, big_n, t_big_n as f64)).ceil();
            t_prime[n + 1] = t_prime[n] + inc.max(1.0) as u64;
        }
        for (n, &direct) in t_prime.iter().enumerate().skip(m) {
            // Floating-point rounding inside ceil() may shift a step by one.
            let diff = p.t_prime(n).abs_diff(direct);
            assert!(
                diff <= 1,
                "N {big_n} m {m}: T'_{n} = {} vs direct {direct}",
                p.t_prime(n)
            );
        }
        // Every hypothesis t ≤ T'_N holds u_{n(t)} and otherwise only better-ranked items.
        let mut sample = vec![0usize; m];
        let last = p.t_prime(big_n).min(20_000);
        for t in 1..=last {
            let n = (m..=big_n).find(|&n| p.t_prime(n) >= t).unwrap();
            p.draw(t - 1, &mut hypothesis_rng(3, t), &mut sample);
            let max = *sample.iter().max().unwrap();
            assert_eq!(
                max,
                n - 1,
                "t {t}: sample {sample:?}, expected top-{n} with u_{n}"
            );
            let mut s = sample.clone();
            s.sort_unstable();
            s.dedup();
            assert_eq!(s.len(), m, "repeated index in {sample:?}");
        }
    }
}

#[test]
fn beyond_the_schedule_it_is_uniform() {
    let p = Prosac::new(20, 2, 100).unwrap();
    let after = p.t_prime(20) + 1;
    let mut counts = [0u32; 20];
    let mut s = [0usize; 2];
    for h in 0..20_000 {
        p.draw(after + h, &mut hypothesis_rng(1, h), &mut s);
        for &i in &s {
            counts[i] += 1;
        }
    }
    // 40,000 index draws over 20 items: 2,000 each, σ ≈ 44.
    assert!(
        counts.iter().all(|&c| (1700..2300).contains(&c)),
        "{counts:?}"
    );
}
