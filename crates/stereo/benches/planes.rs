//! The plane matcher's stages on a deterministic synthetic 320x240 pair, 32
//! disparities, segmented by a 8×8 grid of the ground truth's regions (the
//! segmentation itself is timed by `stereolink bench segment`).

// criterion_group! and criterion_main! define undocumented public items.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use stereolink_image::color::rgb_to_gray;
use stereolink_image::synth::{synthesize, SynthSpec};
use stereolink_image::LabelMap;
use stereolink_stereo::planes::{self, assign, graph::SegmentGraph};
use stereolink_stereo::{census, sgm, Algorithm, MatchSpec};

fn stages(c: &mut Criterion) {
    let s = synthesize(&SynthSpec {
        width: 320,
        height: 240,
        max_disp: 32,
        seed: 1,
    })
    .unwrap();
    // Segments: 8×8 blocks, each split where the true disparity steps.
    let gt = s.gt_left.as_ref().unwrap();
    let labels = LabelMap::from_fn(320, 240, |x, y| {
        ((x / 8 + 40 * (y / 8)) * 4 + (gt.get(x, y) as usize % 4)) as u16
    });
    let spec = MatchSpec::new(Algorithm::Planes, 0, 31).unwrap();
    let params = &spec.planes;
    let (gl, gr) = (rgb_to_gray(&s.left), rgb_to_gray(&s.right));
    let mut buffers = sgm::SgmBuffers::default();
    let reliable = planes::initial_disparity(&gl, &gr, &spec, &mut buffers);
    let graph = SegmentGraph::new(&labels, params.tile);
    let fitted = planes::fit_segments(&graph, &reliable, params);
    let clusters = assign::cluster(&graph, &fitted, &reliable, params);
    let census = || (census::census(&gl), census::census(&gr));
    let cost = assign::DataCost::new(census(), (&gl, &gr), &reliable, (0.0, 31.0), params);
    let weights = assign::boundary_weights(&graph, &s.left, params.contrast);

    let mut g = c.benchmark_group("planes_320x240_32");
    g.sample_size(10);
    g.bench_function("initial_sgm", |b| {
        b.iter(|| planes::initial_disparity(black_box(&gl), &gr, &spec, &mut buffers))
    });
    g.bench_function("graph", |b| {
        b.iter(|| SegmentGraph::new(black_box(&labels), params.tile))
    });
    g.bench_function("fit", |b| {
        b.iter(|| planes::fit_segments(&graph, black_box(&reliable), params))
    });
    g.bench_function("cluster", |b| {
        b.iter(|| assign::cluster(&graph, black_box(&fitted), &reliable, params))
    });
    g.bench_function("split", |b| {
        b.iter(|| planes::split_bent(&labels, &graph, black_box(&fitted), &reliable, params))
    });
    g.bench_function("census", |b| b.iter(census));
    g.bench_function("boundary_weights", |b| {
        b.iter(|| assign::boundary_weights(&graph, black_box(&s.left), params.contrast))
    });
    g.bench_function("assign", |b| {
        b.iter(|| {
            assign::assign(
                &graph,
                &cost,
                &clusters.planes,
                &clusters.of_segment,
                &weights,
                params,
            )
        })
    });
    let of_segment: Vec<planes::DisparityPlane> = assign::assign(
        &graph,
        &cost,
        &clusters.planes,
        &clusters.of_segment,
        &weights,
        params,
    )
    .unwrap()
    .iter()
    .map(|&k| clusters.planes[k as usize])
    .collect();
    let rendered = planes::render(&graph.ids, &of_segment, (0.0, 31.0));
    g.bench_function("boundary", |b| {
        b.iter(|| {
            let mut d = rendered.clone();
            planes::boundary::refine(
                &graph.ids,
                &of_segment,
                &cost,
                (&s.left, &s.right),
                (0.0, 31.0),
                &params.boundary,
                &mut d,
            );
            d
        })
    });
    g.bench_function("whole", |b| {
        b.iter(|| planes::match_planes(black_box(&s.left), &s.right, &labels, &spec).unwrap())
    });
    g.finish();
}

criterion_group!(benches, stages);
criterion_main!(benches);
