//! Multilevel Otsu thresholding of one channel: the fitness (between-class
//! variance, the paper's eq. 9–10) and its exact maximiser by dynamic
//! programming.
//!
//! With `L = 256` bins and `n` classes, thresholds `t_1 < … < t_{n−1}` split
//! the histogram into classes `C_j`; the fitness is
//! `σ_B² = Σ_j ω_j (μ_j − μ_T)²` with class probability `ω_j` and mean `μ_j`.
//! Because `Σ_j ω_j μ_T² ` and `μ_T` are constant, maximising `σ_B²` equals
//! maximising `Σ_j S_j² / W_j` (class sums `S_j`, weights `W_j`), which splits
//! over classes: `best[j][b] = max_a best[j−1][a] + S(a+1..=b)² / W(a+1..=b)`,
//! O(n·L²) with prefix sums. Empty classes contribute 0 (never NaN).

use stereolink_image::RgbImage;

/// Histogram of one channel (0 = R, 1 = G, 2 = B).
pub fn histogram(image: &RgbImage, channel: usize) -> [u64; 256] {
    let mut h = [0u64; 256];
    for p in image.as_slice() {
        h[p[channel] as usize] += 1;
    }
    h
}

/// Class boundaries of sorted thresholds: `[(lo, hi)]` inclusive ranges.
fn classes(thresholds: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::with_capacity(thresholds.len() + 1);
    let mut lo = 0;
    for &t in thresholds {
        out.push((lo, t as usize));
        lo = t as usize + 1;
    }
    out.push((lo, 255));
    out
}

/// Otsu's between-class variance `σ_B²` of a threshold set (sorted ascending;
/// a value `v` falls in class `#{t : v > t}`).
pub fn between_class_variance(hist: &[u64; 256], thresholds: &[u8]) -> f64 {
    let total: f64 = hist.iter().sum::<u64>() as f64;
    if total == 0.0 {
        return 0.0;
    }
    let mu_t: f64 = hist
        .iter()
        .enumerate()
        .map(|(v, &c)| v as f64 * c as f64)
        .sum::<f64>()
        / total;
    classes(thresholds)
        .into_iter()
        .filter(|(lo, hi)| lo <= hi)
        .map(|(lo, hi)| {
            let w: f64 = hist[lo..=hi].iter().sum::<u64>() as f64;
            if w == 0.0 {
                return 0.0;
            }
            let mu = hist[lo..=hi]
                .iter()
                .enumerate()
                .map(|(i, &c)| (lo + i) as f64 * c as f64)
                .sum::<f64>()
                / w;
            (w / total) * (mu - mu_t).powi(2)
        })
        .sum()
}

/// Rounded mean value of each class (the class's own value range midpoint when empty).
pub fn class_means(hist: &[u64; 256], thresholds: &[u8]) -> Vec<u8> {
    classes(thresholds)
        .into_iter()
        .map(|(lo, hi)| {
            if lo > 255 {
                return 255; // an empty class above a threshold of 255
            }
            let hi = hi.max(lo);
            let w: u64 = hist[lo..=hi].iter().sum();
            let s: u64 = hist[lo..=hi]
                .iter()
                .enumerate()
                .map(|(i, &c)| (lo + i) as u64 * c)
                .sum();
            (s + w / 2)
                .checked_div(w)
                .map_or(((lo + hi) / 2) as u8, |m| m as u8)
        })
        .collect()
}

/// The thresholds (`levels − 1` of them, strictly increasing) that maximise
/// `σ_B²`, found exactly by dynamic programming in O(levels·256²).
///
/// # Panics
/// If `levels` is not in `2..=256`.
pub fn optimal_thresholds(hist: &[u64; 256], levels: usize) -> Vec<u8> {
    assert!((2..=256).contains(&levels));
    const L: usize = 256;
    let mut w = [0f64; L + 1];
    let mut s = [0f64; L + 1];
    for v in 0..L {
        w[v + 1] = w[v] + hist[v] as f64;
        s[v + 1] = s[v] + v as f64 * hist[v] as f64;
    }
    // Score of class a..b (bins a..b-1 as half-open prefix indices), once
    // per pair: the DP below reads each one up to `levels` times.
    let table: Vec<f64> = (0..=L)
        .flat_map(|a| (0..=L).map(move |b| (a, b)))
        .map(|(a, b)| {
            let ww = if b > a { w[b] - w[a] } else { 0.0 };
            if ww > 0.0 {
                (s[b] - s[a]).powi(2) / ww
            } else {
                0.0
            }
        })
        .collect();
    let score = |a: usize, b: usize| table[a * (L + 1) + b];
    // best[j][b]: best score of splitting bins 0..b into j + 1 classes.
    let mut best = vec![vec![f64::NEG_INFINITY; L + 1]; levels];
    let mut arg = vec![vec![0usize; L + 1]; levels];
    for b in 1..=L {
        best[0][b] = score(0, b);
    }
    for j in 1..levels {
        for b in (j + 1)..=L {
            let (mut bv, mut ba) = (f64::NEG_INFINITY, j);
            for a in j..b {
                let v = best[j - 1][a] + score(a, b);
                if v > bv {
                    bv = v;
                    ba = a;
                }
            }
            best[j][b] = bv;
            arg[j][b] = ba;
        }
    }
    let mut cuts = Vec::with_capacity(levels - 1);
    let mut b = L;
    for j in (1..levels).rev() {
        let a = arg[j][b];
        cuts.push((a - 1) as u8); // class j starts at bin a, so threshold a − 1
        b = a;
    }
    cuts.reverse();
    cuts
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn brute(hist: &[u64; 256], levels: usize, max_value: usize) -> f64 {
        // All increasing threshold tuples over 0..max_value.
        fn rec(
            hist: &[u64; 256],
            start: usize,
            left: usize,
            max_value: usize,
            cur: &mut Vec<u8>,
            best: &mut f64,
        ) {
            if left == 0 {
                *best = best.max(between_class_variance(hist, cur));
                return;
            }
            for t in start..max_value {
                cur.push(t as u8);
                rec(hist, t + 1, left - 1, max_value, cur, best);
                cur.pop();
            }
        }
        let mut best = 0.0;
        rec(hist, 0, levels - 1, max_value, &mut Vec::new(), &mut best);
        best
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// The DP optimum equals brute force on small histograms.
        #[test]
        fn dp_matches_brute_force(counts in proptest::collection::vec(0u64..50, 12), levels in 2usize..5) {
            let mut h = [0u64; 256];
            for (i, c) in counts.iter().enumerate() {
                h[i * 3] = *c; // values 0, 3, …, 33
            }
            let t = optimal_thresholds(&h, levels);
            prop_assert_eq!(t.len(), levels - 1);
            prop_assert!(t.windows(2).all(|p| p[0] < p[1]));
            let dp = between_class_variance(&h, &t);
            let bf = brute(&h, levels, 36);
            prop_assert!((dp - bf).abs() <= 1e-9 * bf.max(1.0), "dp {} brute {}", dp, bf);
        }
    }

    #[test]
    fn two_spikes_split_between_them() {
        let mut h = [0u64; 256];
        h[50] = 100;
        h[200] = 100;
        let t = optimal_thresholds(&h, 2);
        assert!((50..200).contains(&(t[0] as usize)));
        assert_eq!(class_means(&h, &t), vec![50, 200]);
        // Degenerate thresholds (duplicates, 255) give empty classes, not panics.
        assert_eq!(class_means(&h, &[255]), vec![125, 255]);
        assert_eq!(class_means(&h, &[10, 10]), vec![5, 11, 125]);
        assert!((between_class_variance(&h, &t) - 75.0f64.powi(2)).abs() < 1e-9);
    }
}
