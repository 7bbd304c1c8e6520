//! Label-map coding speed: a 480x272 segmented pair (the board's size),
//! left alone and right conditioned on the left, encode and decode.

// criterion_group! and criterion_main! define undocumented public items.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use stereolink_codec::labels::{self, Mode};
use stereolink_image::LabelMap;

fn coding(c: &mut Criterion) {
    let left = LabelMap::from_fn(480, 272, |x, y| (((x / 23) ^ (y / 17)) % 5) as u16);
    let right = LabelMap::from_fn(480, 272, |x, y| left.get((x + 7).min(479), y));
    let palette = [
        [0, 0, 0],
        [255, 0, 0],
        [0, 255, 0],
        [0, 0, 255],
        [255, 255, 255],
    ];
    let (a, b) = (
        labels::encode(&left, &palette, None, 0, Mode::Fast),
        labels::encode(&right, &palette, Some(&left), 32, Mode::Fast),
    );
    let mut g = c.benchmark_group("labels_480x272");
    g.throughput(Throughput::Elements(480 * 272));
    g.bench_function("encode_left", |bn| {
        bn.iter(|| labels::encode(black_box(&left), &palette, None, 0, Mode::Fast))
    });
    g.bench_function("decode_left", |bn| {
        bn.iter(|| labels::decode(black_box(&a), 480, 272, &palette, None).unwrap())
    });
    g.bench_function("encode_right_conditioned", |bn| {
        bn.iter(|| labels::encode(black_box(&right), &palette, Some(&left), 32, Mode::Fast))
    });
    g.bench_function("decode_right_conditioned", |bn| {
        bn.iter(|| labels::decode(black_box(&b), 480, 272, &palette, Some(&left)).unwrap())
    });
    g.finish();
}

criterion_group!(benches, coding);
criterion_main!(benches);
