//! One benchmark per segmentation method on a deterministic synthetic 320x240 view.

// criterion_group! and criterion_main! define undocumented public items.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use stereolink_image::synth::{synthesize, SynthSpec};
use stereolink_segment::{segment, Method};

fn methods(c: &mut Criterion) {
    let s = synthesize(&SynthSpec {
        width: 320,
        height: 240,
        max_disp: 32,
        seed: 1,
    })
    .unwrap();
    let mut g = c.benchmark_group("segment_320x240");
    g.sample_size(10);
    for method in Method::all() {
        g.bench_function(method.name(), |b| {
            b.iter(|| segment(black_box(&s.left), &method, 3, 1).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, methods);
criterion_main!(benches);
