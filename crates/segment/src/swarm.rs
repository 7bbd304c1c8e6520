//! Swarm searches for Otsu thresholds (one channel at a time): PSO,
//! Darwinian PSO (Tillett et al. 2005) and fractional-order Darwinian PSO
//! (Ghamisi et al. 2012), as the paper defines them.
//!
//! A particle is a threshold vector `x ∈ [0, 255]^{n−1}`; its fitness is
//! Otsu's `σ_B²` of the sorted, rounded thresholds. Velocity update (paper
//! eq. 7–8 with ρ3 = 0), with fresh `r1, r2 ∈ U(0, 1)` per dimension:
//!
//! * PSO and DPSO: `v ← w·v + ρ1·r1·(pbest − x) + ρ2·r2·(gbest − x)`;
//! * FO-DPSO: the inertia term becomes the truncated Grünwald–Letnikov
//!   derivative of order α: `α·v[t] + ½α·v[t−1] + ⅙α(1−α)·v[t−2] +
//!   (1/24)·α(1−α)(2−α)·v[t−3]` (four velocities of history);
//!
//! then `|v| ≤ v_max` and `x ← x + v`, clamped to `[0, 255]`.
//!
//! Darwinian selection (both DPSO variants) runs several swarms. A swarm whose
//! best improves is rewarded: it spawns a particle (up to the maximum
//! population) and, with probability `f/NS` (`f ∈ U(0,1)`, `NS` swarms), a new
//! swarm if it never deleted a particle and fewer than the maximum number of
//! swarms exist; the child takes half its particles from the parent and half
//! from a random other swarm, topped up randomly. A swarm that fails to
//! improve for `SC_max` steps loses its worst particle and its stagnation
//! counter is reset to `SC_max·(1 − 1/(N_kill + 1))` (eq. 11); a swarm at the
//! minimum population is deleted while more than the minimum number of swarms
//! exist.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::SegmentError;

/// Parameters of the swarm search (defaults from the authors' reference code).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SwarmSpec {
    /// Particles per swarm at the start.
    pub particles: usize,
    /// Iterations.
    pub iterations: usize,
    /// Inertia weight w (PSO, DPSO).
    pub inertia: f64,
    /// Cognitive weight ρ1.
    pub rho1: f64,
    /// Social weight ρ2.
    pub rho2: f64,
    /// Velocity clamp |v| ≤ v_max.
    pub vmax: f64,
    /// Fractional order α; `Some` selects FO-DPSO's velocity rule.
    pub alpha: Option<f64>,
    /// Darwinian selection on (DPSO, FO-DPSO) or off (PSO, one swarm).
    pub darwinian: bool,
    /// Swarms at the start.
    pub swarms: usize,
    /// Fewest swarms kept.
    pub min_swarms: usize,
    /// Most swarms allowed.
    pub max_swarms: usize,
    /// Smallest swarm population.
    pub min_population: usize,
    /// Largest swarm population.
    pub max_population: usize,
    /// Stagnation steps before a particle is deleted (SC_max).
    pub sc_max: usize,
}

impl SwarmSpec {
    /// PSO: 150 particles, w = 1.2, ρ1 = ρ2 = 0.8, 150 iterations, |v| ≤ 5.
    pub fn pso() -> Self {
        SwarmSpec {
            particles: 150,
            iterations: 150,
            inertia: 1.2,
            rho1: 0.8,
            rho2: 0.8,
            vmax: 5.0,
            alpha: None,
            darwinian: false,
            swarms: 1,
            min_swarms: 1,
            max_swarms: 1,
            min_population: 150,
            max_population: 150,
            sc_max: usize::MAX,
        }
    }

    /// DPSO: 4 swarms (2–6) of 30 particles (10–50), SC_max = 10, |v| ≤ 1.5.
    pub fn dpso() -> Self {
        SwarmSpec {
            particles: 30,
            vmax: 1.5,
            darwinian: true,
            swarms: 4,
            min_swarms: 2,
            max_swarms: 6,
            min_population: 10,
            max_population: 50,
            sc_max: 10,
            ..Self::pso()
        }
    }

    /// FO-DPSO: DPSO with the fractional velocity rule, α = 0.6.
    pub fn fodpso() -> Self {
        SwarmSpec {
            alpha: Some(0.6),
            ..Self::dpso()
        }
    }

    pub(crate) fn validate(&self) -> Result<(), SegmentError> {
        let ok = self.particles >= 1
            && self.swarms >= 1
            && self.min_swarms <= self.swarms
            && self.swarms <= self.max_swarms
            && self.min_population >= 1
            && self.min_population <= self.max_population
            && self.vmax > 0.0
            && self.iterations <= 100_000
            && self.particles <= 10_000
            && self.alpha.is_none_or(|a| a > 0.0 && a <= 1.0);
        if ok {
            Ok(())
        } else {
            Err(SegmentError::Parameter(format!(
                "inconsistent swarm parameters: {self:?}"
            )))
        }
    }
}

/// Result of one channel's search.
#[derive(Clone, Debug, PartialEq)]
pub struct SwarmResult {
    /// Best thresholds found (sorted).
    pub thresholds: Vec<u8>,
    /// Their fitness σ_B².
    pub fitness: f64,
    /// Iterations run.
    pub iterations: usize,
    /// Fitness evaluations made.
    pub evaluations: usize,
}

/// σ_B² from prefix sums, O(levels) per evaluation.
struct Fitness {
    w: [f64; 257],
    s: [f64; 257],
    total: f64,
    mu_t: f64,
}

impl Fitness {
    fn new(hist: &[u64; 256]) -> Self {
        let (mut w, mut s) = ([0.0; 257], [0.0; 257]);
        for v in 0..256 {
            w[v + 1] = w[v] + hist[v] as f64;
            s[v + 1] = s[v] + v as f64 * hist[v] as f64;
        }
        let total = w[256];
        Fitness {
            w,
            s,
            total,
            mu_t: if total > 0.0 { s[256] / total } else { 0.0 },
        }
    }

    fn thresholds(x: &[f64]) -> Vec<u8> {
        let mut t: Vec<u8> = x
            .iter()
            .map(|v| v.round().clamp(0.0, 255.0) as u8)
            .collect();
        t.sort_unstable();
        t
    }

    fn eval(&self, t: &[u8]) -> f64 {
        if self.total == 0.0 {
            return 0.0;
        }
        let mut lo = 0usize;
        let mut sum = 0.0;
        for hi in t
            .iter()
            .map(|&v| v as usize + 1)
            .chain(std::iter::once(256))
        {
            if hi > lo {
                let w = self.w[hi] - self.w[lo];
                if w > 0.0 {
                    let mu = (self.s[hi] - self.s[lo]) / w;
                    sum += w / self.total * (mu - self.mu_t).powi(2);
                }
                lo = hi;
            }
        }
        sum
    }
}

#[derive(Clone)]
struct Particle {
    x: Vec<f64>,
    /// `v[t]`, `v[t−1]`, `v[t−2]`, `v[t−3]`.
    v: [Vec<f64>; 4],
    best_x: Vec<f64>,
    best: f64,
    fit: f64,
}

struct Swarm {
    particles: Vec<Particle>,
    best_x: Vec<f64>,
    best: f64,
    stagnation: usize,
    kills: usize,
}

fn random_particle(rng: &mut ChaCha8Rng, dims: usize) -> Particle {
    let x: Vec<f64> = (0..dims).map(|_| rng.gen_range(0.0..=255.0)).collect();
    Particle {
        best_x: x.clone(),
        x,
        v: std::array::from_fn(|_| vec![0.0; dims]),
        best: f64::NEG_INFINITY,
        fit: f64::NEG_INFINITY,
    }
}

fn new_swarm(particles: Vec<Particle>) -> Swarm {
    Swarm {
        particles,
        best_x: Vec::new(),
        best: f64::NEG_INFINITY,
        stagnation: 0,
        kills: 0,
    }
}

/// Searches `levels − 1` thresholds maximising σ_B² of `hist`.
pub fn optimise(hist: &[u64; 256], levels: usize, spec: &SwarmSpec, seed: u64) -> SwarmResult {
    let dims = levels - 1;
    let fitness = Fitness::new(hist);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut swarms: Vec<Swarm> = (0..spec.swarms)
        .map(|_| {
            new_swarm(
                (0..spec.particles)
                    .map(|_| random_particle(&mut rng, dims))
                    .collect(),
            )
        })
        .collect();
    let (mut best_x, mut best) = (vec![0.0; dims], f64::NEG_INFINITY);
    let mut evaluations = 0;
    for _ in 0..spec.iterations {
        let n_swarms = swarms.len();
        let mut spawned: Vec<Swarm> = Vec::new();
        let mut deleted = vec![false; n_swarms];
        for s in 0..n_swarms {
            // Evaluate.
            let mut improved = false;
            let swarm = &mut swarms[s];
            for p in &mut swarm.particles {
                p.fit = fitness.eval(&Fitness::thresholds(&p.x));
                evaluations += 1;
                if p.fit > p.best {
                    p.best = p.fit;
                    p.best_x.clone_from(&p.x);
                }
                if p.fit > swarm.best {
                    swarm.best = p.fit;
                    swarm.best_x.clone_from(&p.x);
                    improved = true;
                }
            }
            if swarm.best > best {
                best = swarm.best;
                best_x.clone_from(&swarm.best_x);
            }
            if spec.darwinian {
                if improved {
                    swarm.stagnation = 0;
                    if swarm.particles.len() < spec.max_population {
                        swarm.particles.push(random_particle(&mut rng, dims));
                    }
                    let p_spawn = rng.gen_range(0.0..1.0) / n_swarms as f64;
                    if swarm.kills == 0
                        && n_swarms + spawned.len() < spec.max_swarms
                        && rng.gen_bool(p_spawn.clamp(0.0, 1.0))
                    {
                        let half = swarm.particles.len() / 2;
                        let mut child: Vec<Particle> = swarm.particles[..half].to_vec();
                        let other = rng.gen_range(0..n_swarms);
                        let donor = &swarms[other].particles;
                        child.extend(donor.iter().take(half).cloned());
                        while child.len() < spec.particles {
                            child.push(random_particle(&mut rng, dims));
                        }
                        spawned.push(new_swarm(child));
                    }
                } else {
                    swarm.stagnation += 1;
                    if swarm.stagnation >= spec.sc_max {
                        if swarm.particles.len() > spec.min_population {
                            let worst = (0..swarm.particles.len())
                                .min_by(|&a, &b| {
                                    swarm.particles[a].fit.total_cmp(&swarm.particles[b].fit)
                                })
                                .expect("non-empty swarm");
                            swarm.particles.swap_remove(worst);
                            swarm.kills += 1;
                            // Eq. 11: SC ← SC_max · (1 − 1/(N_kill + 1)).
                            swarm.stagnation = (spec.sc_max as f64
                                * (1.0 - 1.0 / (swarm.kills as f64 + 1.0)))
                                as usize;
                        } else if n_swarms - deleted.iter().filter(|&&d| d).count()
                            > spec.min_swarms
                        {
                            deleted[s] = true;
                        }
                    }
                }
            }
            // Move.
            let swarm = &mut swarms[s];
            let gbest = swarm.best_x.clone();
            for p in &mut swarm.particles {
                for d in 0..dims {
                    let (r1, r2): (f64, f64) = (rng.gen(), rng.gen());
                    let memory = match spec.alpha {
                        None => spec.inertia * p.v[0][d],
                        Some(a) => {
                            let h = |i: usize| p.v[i][d];
                            a * h(0)
                                + 0.5 * a * h(1)
                                + a * (1.0 - a) / 6.0 * h(2)
                                + a * (1.0 - a) * (2.0 - a) / 24.0 * h(3)
                        }
                    };
                    let v = (memory
                        + spec.rho1 * r1 * (p.best_x[d] - p.x[d])
                        + spec.rho2 * r2 * (gbest[d] - p.x[d]))
                        .clamp(-spec.vmax, spec.vmax);
                    p.v[3][d] = p.v[2][d];
                    p.v[2][d] = p.v[1][d];
                    p.v[1][d] = p.v[0][d];
                    p.v[0][d] = v;
                    p.x[d] = (p.x[d] + v).clamp(0.0, 255.0);
                }
            }
        }
        let mut i = 0;
        swarms.retain(|_| {
            i += 1;
            !deleted[i - 1]
        });
        swarms.extend(spawned);
    }
    let thresholds = Fitness::thresholds(&best_x);
    SwarmResult {
        fitness: fitness.eval(&thresholds),
        thresholds,
        iterations: spec.iterations,
        evaluations,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::otsu::{between_class_variance, optimal_thresholds};

    fn bimodal_noise() -> [u64; 256] {
        let mut h = [0u64; 256];
        for (v, c) in h.iter_mut().enumerate() {
            let g = |m: f64, s: f64| (-(v as f64 - m).powi(2) / (2.0 * s * s)).exp();
            *c = (1000.0 * (g(40.0, 12.0) + 0.7 * g(120.0, 20.0) + 0.5 * g(200.0, 15.0))) as u64;
        }
        h
    }

    #[test]
    fn prefix_fitness_equals_direct_formula() {
        let h = bimodal_noise();
        for t in [vec![80u8], vec![60, 160], vec![10, 10, 200]] {
            let a = Fitness::new(&h).eval(&t);
            let b = between_class_variance(&h, &t);
            assert!((a - b).abs() < 1e-6 * b, "{t:?}: {a} vs {b}");
        }
    }

    #[test]
    fn every_swarm_reaches_near_the_optimum() {
        let h = bimodal_noise();
        let opt = between_class_variance(&h, &optimal_thresholds(&h, 4));
        for spec in [SwarmSpec::pso(), SwarmSpec::dpso(), SwarmSpec::fodpso()] {
            let r = optimise(&h, 4, &spec, 5);
            assert!(
                r.fitness >= 0.995 * opt,
                "{:?}: {} of {}",
                spec.alpha,
                r.fitness,
                opt
            );
            assert_eq!(r.thresholds.len(), 3);
        }
    }
}
