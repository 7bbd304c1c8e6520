//! One benchmark per matcher on a deterministic synthetic 320x240 pair, 32
//! disparities, WTA with its default refinement (as `match --algo wta`
//! runs it, frame after frame), and one per refinement step on its
//! LR-checked WTA map.

// criterion_group! and criterion_main! define undocumented public items.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use stereolink_image::synth::{synthesize, SynthSpec};
use stereolink_stereo::{compute_disparity, refine, Algorithm, MatchSpec, Matcher, Refinement};

fn matchers(c: &mut Criterion) {
    let s = synthesize(&SynthSpec {
        width: 320,
        height: 240,
        max_disp: 32,
        seed: 1,
    })
    .unwrap();
    let mut g = c.benchmark_group("match_320x240_32");
    g.sample_size(10);
    for algo in Algorithm::ALL {
        let mut spec = MatchSpec::new(algo, 0, 31).unwrap();
        spec.refine = Refinement::NONE;
        g.bench_function(algo.name(), |b| {
            b.iter(|| compute_disparity(black_box(&s.left), black_box(&s.right), &spec).unwrap())
        });
    }
    let spec = MatchSpec::new(Algorithm::Wta, 0, 31).unwrap();
    let mut matcher = Matcher::new();
    g.bench_function("wta_default_refinement", |b| {
        b.iter(|| {
            let pair = (black_box(&s.left), black_box(&s.right));
            matcher.compute(pair.0, pair.1, &spec).unwrap()
        })
    });
    g.finish();

    // The refinement steps' input: the WTA map after the LR check, holes included.
    let mut spec = MatchSpec::new(Algorithm::Wta, 0, 31).unwrap();
    spec.refine = Refinement {
        lr_check: Some(1.0),
        ..Refinement::NONE
    };
    let raw = compute_disparity(&s.left, &s.right, &spec).unwrap();
    let mut g = c.benchmark_group("refine_320x240");
    g.bench_function("median_5x5", |b| {
        b.iter(|| refine::median(black_box(&raw), 5))
    });
    g.bench_function("weighted_median", |b| {
        b.iter(|| {
            refine::weighted_median(black_box(&raw), &s.left, &refine::WeightedMedian::DEFAULT)
        })
    });
    g.bench_function("fill_holes", |b| {
        b.iter(|| refine::fill_holes(&mut black_box(raw.clone())))
    });
    g.bench_function("fill_from_directions", |b| {
        b.iter(|| refine::fill_from_directions(&mut black_box(raw.clone())))
    });
    g.finish();
}

criterion_group!(benches, matchers);
criterion_main!(benches);
