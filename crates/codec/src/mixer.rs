//! Logistic mixing of several probabilities into one (the paq scheme, all
//! in integers so that any implementation reproduces it bit for bit):
//! each input probability is *stretched* to the logistic domain,
//! `ln(p / (1 − p))`, the stretches are weighted and summed, the sum is
//! *squashed* back, and the weights learn online by gradient descent on the
//! coding cost. Mixing a small, a medium and a large context lets the large
//! one speak where it has statistics and the small ones elsewhere. An
//! [`Apm`] then refines the mixed probability by a small context.

/// Weight of 1.0.
const ONE: i32 = 1 << 16;
/// Bound of a weight's magnitude (256.0), so that no input overflows the sums.
const WEIGHT_MAX: i32 = 1 << 24;
/// Learning rate: a weight moves by input × error × `RATE` / 2^14 (the
/// error in 1/4096).
const RATE: i32 = 4;

/// `4096 / (1 + e^(−d/256))` at d = −2048, −1920, …, 2048 (the paq table).
const SQUASH_KNOTS: [i32; 33] = [
    1, 2, 3, 6, 10, 16, 27, 45, 73, 120, 194, 310, 488, 747, 1101, 1546, 2047, 2549, 2994, 3348,
    3607, 3785, 3901, 3975, 4022, 4050, 4068, 4079, 4085, 4089, 4092, 4093, 4094,
];

/// The logistic function, 12-bit probability of `d` (a stretch, 8 fractional
/// bits), interpolating `SQUASH_KNOTS`; 1..4095.
pub const fn squash(d: i32) -> i32 {
    if d > 2047 {
        return 4095;
    }
    if d < -2047 {
        return 1;
    }
    let w = d & 127;
    let i = ((d >> 7) + 16) as usize;
    (SQUASH_KNOTS[i] * (128 - w) + SQUASH_KNOTS[i + 1] * w + 64) >> 7
}

/// `stretch[p]` for a 12-bit probability: the smallest d in −2047..=2047
/// with `squash(d) ≥ p` (2047 if none), the inverse of [`squash`].
pub const STRETCH: [i16; 4096] = {
    let mut t = [2047i16; 4096];
    let mut pi = 0usize;
    let mut x = -2047;
    while x <= 2047 {
        let v = squash(x) as usize;
        let mut j = pi;
        while j <= v {
            t[j] = x as i16;
            j += 1;
        }
        if v + 1 > pi {
            pi = v + 1;
        }
        x += 1;
    }
    t
};

/// Sets of `N` weights (one per mixed input), one set per mixing context.
pub struct Mixer<const N: usize> {
    weights: Vec<[i32; N]>,
}

/// One mixing in progress: the stretched inputs, the weight set and the result.
pub struct Mix<const N: usize> {
    st: [i32; N],
    set: usize,
    d: i32,
    p1: i32,
}

impl<const N: usize> Mix<N> {
    /// The probability of a 0 in 1/2^16 (for the range coder).
    #[inline(always)]
    pub fn p0(&self) -> u32 {
        ((4096 - self.p1) as u32) << 4
    }

    /// The mixed stretch (−2047..=2047), before squashing: several mixings
    /// of the same inputs are averaged in this domain.
    #[inline(always)]
    pub fn stretch(&self) -> i32 {
        self.d
    }
}

impl<const N: usize> Mixer<N> {
    /// `sets` weight sets.
    pub fn new(sets: usize) -> Self {
        Mixer {
            weights: vec![[ONE / N as i32; N]; sets],
        }
    }

    /// Back to the state of [`Mixer::new`]`(sets)`, reusing the storage.
    pub fn reset(&mut self, sets: usize) {
        self.weights.clear();
        self.weights.resize(sets, [ONE / N as i32; N]);
    }

    /// Mixes the probabilities of a 0 `p0` (each in 1/2^16) with weight set `set`.
    #[inline(always)]
    pub fn mix(&self, set: usize, p0: [u32; N]) -> Mix<N> {
        let st = p0.map(|p| STRETCH[(((1 << 16) - p) >> 4) as usize] as i32);
        let w = &self.weights[set];
        let dot: i64 = (0..N).map(|i| w[i] as i64 * st[i] as i64).sum();
        let d = (dot >> 16).clamp(-2047, 2047) as i32;
        Mix {
            st,
            set,
            d,
            p1: squash(d),
        }
    }

    /// Learns `bit` after `mix` (from the mixing's own error, also when
    /// its result was averaged with others).
    #[inline(always)]
    pub fn update(&mut self, mix: &Mix<N>, bit: bool) {
        let err = (((bit as i32) << 12) - mix.p1) * RATE;
        let w = &mut self.weights[mix.set];
        for (w, &st) in w.iter_mut().zip(&mix.st) {
            *w = (*w + ((st * err) >> 14)).clamp(-WEIGHT_MAX, WEIGHT_MAX);
        }
    }
}

/// Knots of an [`Apm`] context: stretches −2048, −1920, …, 2048.
const APM_KNOTS: usize = 33;
/// An [`Apm`] knot moves by 1/2^`APM_RATE` of its error per bit.
const APM_RATE: u32 = 6;

/// Secondary estimation (APM / SSE, after paq): refines a probability by a
/// small context. Each context holds a piecewise-linear map of the
/// stretched probability: `APM_KNOTS` 16-bit probabilities of a 1, which
/// start on the identity (the squash of the knot's stretch). The input is
/// interpolated between its two knots, and the nearer knot learns the bit.
/// It corrects what the mixer gets wrong in a context, systematically
/// (over- or under-confidence), which the mixer's weights cannot.
pub struct Apm {
    knots: Vec<u16>,
}

/// One refinement in progress: the knot that learns, and the result.
pub struct Refined {
    knot: usize,
    p1: i32,
}

impl Refined {
    /// The refined probability of a 1 in 1/2^16.
    #[inline(always)]
    pub fn p1(&self) -> i32 {
        self.p1
    }
}

impl Apm {
    /// `contexts` contexts on the identity.
    pub fn new(contexts: usize) -> Self {
        let mut apm = Apm { knots: Vec::new() };
        apm.reset(contexts);
        apm
    }

    /// Back to the state of [`Apm::new`]`(contexts)`, reusing the storage.
    pub fn reset(&mut self, contexts: usize) {
        self.knots.clear();
        self.knots.extend(
            (0..contexts * APM_KNOTS)
                .map(|i| (squash((i % APM_KNOTS) as i32 * 128 - 2048) * 16) as u16),
        );
    }

    /// Refines the stretch `d` (−2047..=2047) of a probability in context `cx`.
    #[inline(always)]
    pub fn refine(&self, d: i32, cx: usize) -> Refined {
        let s = d + 2048;
        let (j, f) = (cx * APM_KNOTS + (s >> 7) as usize, s & 127);
        let p1 = (self.knots[j] as i32 * (128 - f) + self.knots[j + 1] as i32 * f) >> 7;
        Refined {
            knot: j + (f >> 6) as usize,
            p1,
        }
    }

    /// Learns `bit` after `refine`.
    #[inline(always)]
    pub fn update(&mut self, r: &Refined, bit: bool) {
        let k = &mut self.knots[r.knot];
        let target = if bit { 65535 } else { 0 };
        *k = (*k as i32 + ((target - *k as i32) >> APM_RATE)) as u16;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stretch_inverts_squash() {
        assert_eq!((squash(-2047), squash(0), squash(2047)), (1, 2047, 4094));
        for d in (-2000..2000).step_by(37) {
            assert!((squash(STRETCH[squash(d) as usize] as i32) - squash(d)).abs() <= 1);
        }
    }
}
