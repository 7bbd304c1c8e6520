//! The plane matcher on synthetic slanted planes, and its bad inputs.

use super::*;

/// A textured scene of slanted planar surfaces: the surface of each pixel
/// by `region(x, y)`, `planes[region]` its disparity; the right view shows
/// each left surface point at `x − d`, the nearest surface in front.
struct SlantedScene {
    left: RgbImage,
    right: RgbImage,
    truth: DisparityMap,
    labels: LabelMap,
}

/// A smooth random texture: bilinear interpolation of a hashed 3 px grid.
fn texture(x: f32, y: f32) -> u8 {
    let hash = |i: i64, j: i64| {
        let mut v = (i.wrapping_mul(73_856_093) ^ j.wrapping_mul(19_349_663)) as u64;
        v = v.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        ((v >> 40) % 200) as f32 + 28.0
    };
    let (u, v) = (x / 3.0, y / 3.0);
    let (i, j) = (u.floor(), v.floor());
    let (fu, fv) = (u - i, v - j);
    let (i, j) = (i as i64, j as i64);
    let top = hash(i, j) * (1.0 - fu) + hash(i + 1, j) * fu;
    let bottom = hash(i, j + 1) * (1.0 - fu) + hash(i + 1, j + 1) * fu;
    (top * (1.0 - fv) + bottom * fv) as u8
}

fn slanted_scene(
    w: usize,
    h: usize,
    planes: &[DisparityPlane],
    region: impl Fn(usize, usize) -> usize,
    label: impl Fn(usize, usize) -> u16,
) -> SlantedScene {
    shaded_scene(w, h, planes, region, label, |_, g| g)
}

/// [`slanted_scene`] with each surface's grey `shade(region, texture)`, so
/// that a colour edge can run along each depth edge.
fn shaded_scene(
    w: usize,
    h: usize,
    planes: &[DisparityPlane],
    region: impl Fn(usize, usize) -> usize,
    label: impl Fn(usize, usize) -> u16,
    shade: impl Fn(usize, u8) -> u8,
) -> SlantedScene {
    let truth = DisparityMap::from_fn(w, h, |x, y| planes[region(x, y)].at(x as f32, y as f32));
    let left = RgbImage::from_fn(w, h, |x, y| {
        [shade(region(x, y), texture(x as f32, y as f32)); 3]
    });
    let right = RgbImage::from_fn(w, h, |xr, y| {
        // The left pixels that land nearest xr; the largest disparity is in front.
        let mut best: Option<(f32, f32, usize)> = None;
        for x in xr..w {
            let d = truth.get(x, y);
            let xl = xr as f32 + d;
            if (xl - x as f32).abs() <= 0.5 && best.is_none_or(|(bd, _, _)| d > bd) {
                best = Some((d, xl, region(x, y)));
            }
        }
        let g = best.map_or(90, |(_, xl, r)| shade(r, texture(xl, y as f32)));
        [g; 3]
    });
    let labels = LabelMap::from_fn(w, h, label);
    SlantedScene {
        left,
        right,
        truth,
        labels,
    }
}

const BACK: DisparityPlane = DisparityPlane {
    a: 0.05,
    b: 0.02,
    c: 6.0,
};
const FRONT: DisparityPlane = DisparityPlane {
    a: -0.04,
    b: 0.03,
    c: 18.0,
};

fn in_front(x: usize, y: usize) -> bool {
    (60..120).contains(&x) && (30..90).contains(&y)
}

/// Background split into four segments, the slanted box one more.
fn two_planes() -> SlantedScene {
    box_scene(
        |x, y| {
            if in_front(x, y) {
                4
            } else {
                (x / 90 + 2 * (y / 60)) as u16
            }
        },
        |_, g| g,
    )
}

/// The slanted box in front of the slanted background, 180×120, with the
/// given labels and shades (of region 0, the background, and 1, the box).
fn box_scene(label: impl Fn(usize, usize) -> u16, shade: impl Fn(usize, u8) -> u8) -> SlantedScene {
    shaded_scene(
        180,
        120,
        &[BACK, FRONT],
        |x, y| in_front(x, y) as usize,
        label,
        shade,
    )
}

/// The matcher without tiles (the segments are the label map's
/// components) and without the boundary step, which needs a colour edge
/// along each depth edge: these scenes have one texture throughout, and
/// with the step 0.8 % of their pixels (the box's edge rows) take the
/// background's plane.
fn spec() -> MatchSpec {
    let mut spec = MatchSpec::new(Algorithm::Planes, 0, 31).unwrap();
    spec.planes.tile = 0;
    spec.planes.boundary.radius = 0;
    spec
}

fn bad_rate(d: &DisparityMap, truth: &DisparityMap) -> f64 {
    let bad = d
        .as_slice()
        .iter()
        .zip(truth.as_slice())
        .filter(|(d, t)| (*d - *t).abs() > 1.0 || d.is_nan() || t.is_nan())
        .count();
    100.0 * bad as f64 / d.len() as f64
}

#[test]
fn slanted_planes_are_recovered_from_the_pair() {
    let s = two_planes();
    let m = match_planes(&s.left, &s.right, &s.labels, &spec()).unwrap();
    assert_eq!(m.graph.len(), 5);
    assert_eq!(m.planes.len(), 5);
    for (id, want) in [(0, BACK), (1, BACK), (2, FRONT), (3, BACK), (4, BACK)] {
        let got = m.planes[id];
        assert!(
            (got.a - want.a).abs() < 0.01 && (got.b - want.b).abs() < 0.01,
            "segment {id}: {got:?} against {want:?}"
        );
        // Within a quarter pixel at the middle of the image.
        assert!((got.at(90.0, 60.0) - want.at(90.0, 60.0)).abs() < 0.25);
    }
    let bad = bad_rate(&m.disparity, &s.truth);
    assert!(bad < 0.5, "{bad:.2} % bad");
    // The background's four segments agree and share one refitted plane.
    assert_eq!(m.planes[0], m.planes[1]);
    assert_eq!(m.planes[0], m.planes[4]);
}

#[test]
fn tiles_cut_segments_and_keep_the_planes() {
    let s = two_planes();
    let mut spec = spec();
    spec.planes.tile = 32;
    let m = match_planes(&s.left, &s.right, &s.labels, &spec).unwrap();
    assert!(m.graph.len() > 5);
    let bad = bad_rate(&m.disparity, &s.truth);
    assert!(bad < 0.5, "{bad:.2} % bad");
}

#[test]
fn a_folded_surface_is_cut_again_and_gets_a_plane_per_side() {
    // One label over a surface folded at x = 32, in one 64 px tile: one
    // plane cannot fit it, two can.
    let rising = DisparityPlane {
        a: 0.3,
        b: 0.0,
        c: 2.0,
    };
    let falling = DisparityPlane {
        a: -0.3,
        b: 0.0,
        c: 21.2,
    };
    let s = slanted_scene(
        64,
        64,
        &[rising, falling],
        |x, _| usize::from(x >= 32),
        |_, _| 0,
    );
    let mut spec = spec();
    spec.planes.tile = 64;
    spec.planes.split = 0.0;
    let whole = match_planes(&s.left, &s.right, &s.labels, &spec).unwrap();
    spec.planes.split = 0.4;
    let cut = match_planes(&s.left, &s.right, &s.labels, &spec).unwrap();
    assert_eq!(whole.graph.len(), 1);
    assert_eq!(cut.graph.len(), 4, "the tile is cut in four");
    let (before, after) = (
        bad_rate(&whole.disparity, &s.truth),
        bad_rate(&cut.disparity, &s.truth),
    );
    assert!(before > 5.0, "{before:.2} % bad with one plane per tile");
    assert!(after < 1.0, "{after:.2} % bad after the cut");
}

#[test]
fn without_the_boundary_step_the_dense_map_is_the_plane_table_rendered() {
    let s = two_planes();
    // Nor the refinement after it (the weighted median by default).
    let raw = MatchSpec {
        refine: Refinement::NONE,
        ..spec()
    };
    let m = match_planes(&s.left, &s.right, &s.labels, &raw).unwrap();
    assert_eq!(render(&m.graph.ids, &m.planes, (0.0, 31.0)), m.disparity);
    let mut matcher = crate::Matcher::new();
    let d = matcher
        .compute_segmented(&s.left, &s.right, Some(&s.labels), &raw)
        .unwrap();
    assert_eq!(d, m.disparity);
    assert_eq!(
        matcher.compute(&s.left, &s.right, &raw),
        Err(StereoError::NoSegments)
    );
    // The default refinement is the small weighted median of the map.
    let refined = matcher
        .compute_segmented(&s.left, &s.right, Some(&s.labels), &spec())
        .unwrap();
    let wm = crate::refine::WeightedMedian::AFTER_PLANES;
    assert_eq!(
        refined,
        crate::refine::weighted_median(&m.disparity, &s.left, &wm)
    );
}

#[test]
fn the_boundary_step_moves_a_misplaced_segment_edge_onto_the_depth_edge() {
    // The box is darker than the background (grey 9–76 against 114–214),
    // but its segment is two columns right of it: columns 60–61 of the box
    // are labelled background, 120–121 of the background box.
    let s = box_scene(
        |x, y| u16::from((62..122).contains(&x) && (30..90).contains(&y)),
        |r, g| if r == 1 { g / 3 } else { 100 + g / 2 },
    );
    let band_bad = |d: &DisparityMap| {
        let wrong = |x: usize, y: usize| (d.get(x, y) - s.truth.get(x, y)).abs() > 1.0;
        (35..85)
            .flat_map(|y| [60, 61, 120, 121].map(|x| (x, y)))
            .filter(|&(x, y)| wrong(x, y))
            .count()
    };
    let mut spec = spec();
    let kept = match_planes(&s.left, &s.right, &s.labels, &spec).unwrap();
    spec.planes.boundary.radius = 2;
    let moved = match_planes(&s.left, &s.right, &s.labels, &spec).unwrap();
    // All 200 band pixels take the wrong plane without the step.
    assert_eq!(band_bad(&kept.disparity), 200);
    let left = band_bad(&moved.disparity);
    assert!(left <= 20, "{left} of 200 band pixels still wrong");
    assert_eq!(moved.planes, kept.planes, "the plane table is unchanged");
    let bad = bad_rate(&moved.disparity, &s.truth);
    assert!(bad < bad_rate(&kept.disparity, &s.truth), "{bad:.2} % bad");
}

#[test]
fn a_label_map_of_another_size_is_an_error() {
    let s = two_planes();
    let labels = LabelMap::new(100, 120, 0);
    assert_eq!(
        match_planes(&s.left, &s.right, &labels, &spec()),
        Err(StereoError::LabelMapSize {
            labels: (100, 120),
            image: (180, 120)
        })
    );
}

#[test]
fn a_segment_without_reliable_pixels_borrows_a_neighbours_plane() {
    // The band left of the box is occluded in the right view: nothing there
    // passes the LR check, yet it gets the background's plane.
    let s = box_scene(
        |x, y| match (
            in_front(x, y),
            (50..60).contains(&x) && (30..90).contains(&y),
        ) {
            (true, _) => 2,
            (false, true) => 1,
            _ => 0,
        },
        |_, g| g,
    );
    let m = match_planes(&s.left, &s.right, &s.labels, &spec()).unwrap();
    assert!(m.disparity.as_slice().iter().all(|d| d.is_finite()));
    assert!(bad_rate(&m.disparity, &s.truth) < 0.5);
}

#[test]
fn the_strip_the_right_camera_does_not_see_keeps_its_surface_not_a_farther_one() {
    // A wall at 12 px, and a band at the top 8 px farther back. The wall's
    // first 12 columns are outside the right view, so no match there is
    // right whatever the plane: the data term must not prefer the band's
    // plane, which keeps 8 of those columns in view (with a truncation
    // above what this texture's mismatches cost, a charge of the
    // truncation outside the view did). The strip, bordered by the wall
    // along 100 rows and by the band along 12 columns, takes the wall's
    // plane.
    let (wall, band) = (
        DisparityPlane {
            a: 0.0,
            b: 0.0,
            c: 12.0,
        },
        DisparityPlane {
            a: 0.0,
            b: 0.0,
            c: 4.0,
        },
    );
    let s = slanted_scene(
        180,
        120,
        &[wall, band],
        |_, y| usize::from(y < 20),
        |x, y| match (y < 20, x < 12) {
            (true, _) => 0,
            (false, true) => 2,
            (false, false) => 1,
        },
    );
    let mut spec = spec();
    spec.planes.truncation = 60.0;
    let m = match_planes(&s.left, &s.right, &s.labels, &spec).unwrap();
    let strip = (20..120).flat_map(|y| (0..12).map(move |x| (x, y)));
    let off = strip
        .filter(|&(x, y)| (m.disparity.get(x, y) - 12.0).abs() > 0.5)
        .count();
    assert_eq!(off, 0, "{off} of the strip's 1200 pixels off the wall");
}

#[test]
fn one_pixel_and_thousands_of_segments_still_give_a_dense_map() {
    let s = two_planes();
    for labels in [
        // One segment per pixel: 21 600 segments.
        LabelMap::from_fn(180, 120, |x, y| ((x + 180 * y) % 65_536) as u16),
        // 4×4 blocks: 1 350 segments.
        LabelMap::from_fn(180, 120, |x, y| (x / 4 + 45 * (y / 4)) as u16),
    ] {
        let m = match_planes(&s.left, &s.right, &labels, &spec()).unwrap();
        assert!(m.disparity.as_slice().iter().all(|d| d.is_finite()));
        let bad = bad_rate(&m.disparity, &s.truth);
        assert!(bad < 10.0, "{} segments: {bad:.2} % bad", m.graph.len());
    }
}

#[test]
fn out_of_range_split_boundary_and_contrast_parameters_are_errors() {
    let s = two_planes();
    for change in [
        |p: &mut PlanesParams| p.split = 1.5,
        |p: &mut PlanesParams| p.split = f32::NAN,
        |p: &mut PlanesParams| p.boundary.radius = 1000,
        |p: &mut PlanesParams| p.boundary.window = 9,
        |p: &mut PlanesParams| p.boundary.sigma = 0.0,
        |p: &mut PlanesParams| p.boundary.margin = 1.0,
        |p: &mut PlanesParams| p.boundary.distinct = f32::NAN,
        |p: &mut PlanesParams| p.boundary.census = [4, 3],
        |p: &mut PlanesParams| p.boundary.census = [11, 3],
        |p: &mut PlanesParams| p.boundary.census = [5, 9],
        |p: &mut PlanesParams| p.boundary.census_weight = -1.0,
        |p: &mut PlanesParams| p.boundary.census_weight = f32::INFINITY,
        |p: &mut PlanesParams| p.contrast = 0.0,
        |p: &mut PlanesParams| p.contrast = f32::NAN,
    ] {
        let mut spec = spec();
        change(&mut spec.planes);
        let err = match_planes(&s.left, &s.right, &s.labels, &spec).unwrap_err();
        assert!(matches!(err, StereoError::Parameter(_)), "{err:?}");
    }
}

#[test]
fn a_textureless_pair_gives_no_nan() {
    let img = RgbImage::new(60, 40, [128; 3]);
    let labels = LabelMap::from_fn(60, 40, |x, _| (x / 20) as u16);
    let m = match_planes(
        &img,
        &img,
        &labels,
        &MatchSpec::new(Algorithm::Planes, 0, 8).unwrap(),
    )
    .unwrap();
    assert!(m.disparity.as_slice().iter().all(|d| !d.is_nan()));
    assert!(m
        .planes
        .iter()
        .all(|p| p.a.is_finite() && p.b.is_finite() && p.c.is_finite()));
}

#[test]
fn a_plane_is_refitted_over_every_segment_that_took_it() {
    // Two segments side by side on one slanted plane, both given a plane
    // that is 0.4 px off (within the inlier tolerance); a third plane is
    // taken by none.
    let truth = DisparityPlane {
        a: 0.05,
        b: -0.02,
        c: 6.0,
    };
    let off = DisparityPlane { c: 6.4, ..truth };
    let other = DisparityPlane {
        a: 0.0,
        b: 0.0,
        c: 2.0,
    };
    let ids = Plane::from_fn(40, 20, |x, _| u32::from(x >= 20));
    let graph = SegmentGraph::from_ids(ids, 2);
    let reliable = DisparityMap::from_fn(40, 20, |x, y| truth.at(x as f32, y as f32));
    let params = PlanesParams::default();
    let planes = assign::refit_taken(&graph, &[0, 0], &[off, other], &reliable, &params);
    for (got, want) in [
        (planes[0].a, truth.a),
        (planes[0].b, truth.b),
        (planes[0].c, truth.c),
    ] {
        assert!(
            (got - want).abs() < 1e-4,
            "{:?} against {truth:?}",
            planes[0]
        );
    }
    assert_eq!(planes[1], other);
}

#[test]
fn boundary_pairs_weigh_by_colour_contrast() {
    // Two segments side by side; across the boundary the colours differ by
    // 0, 10 and 20 (summed over RGB) in the three rows.
    let ids = Plane::from_fn(4, 3, |x, _| u32::from(x >= 2));
    let graph = SegmentGraph::from_ids(ids, 2);
    let left = RgbImage::from_fn(4, 3, |x, y| {
        let blue = if x >= 2 { 30 + 10 * y as u8 } else { 30 };
        [10, 20, blue]
    });
    let weights = assign::boundary_weights(&graph, &left, 5.0);
    let want = 1.0 + (-2.0f32).exp() + (-4.0f32).exp();
    assert!((weights[0] - want).abs() < 1e-6, "{weights:?}");
    assert_eq!(weights[0], weights[1]);
    let lengths = assign::boundary_weights(&graph, &left, f32::INFINITY);
    assert_eq!(lengths, [3.0, 3.0]);
}

#[test]
fn a_group_of_segments_moves_where_no_one_of_them_can() {
    // The box's left third is one segment on the box's plane; the rest is
    // cut into 10 px squares of the same texture, all on the background's
    // plane. Each square would pay more boundary than it saves in data by
    // moving alone; the squares together pay none: a colour edge runs
    // around the box.
    let anchor = |x: usize| x < 80;
    let s = box_scene(
        |x, y| match (in_front(x, y), anchor(x)) {
            (false, _) => 0,
            (true, true) => 1,
            (true, false) => (2 + (x - 80) / 10 + 4 * ((y - 30) / 10)) as u16,
        },
        |_, g| g,
    );
    let graph = SegmentGraph::new(&s.labels, 0);
    assert_eq!(graph.len(), 2 + 4 * 6);
    let spec = spec();
    let (gl, gr) = crate::gray_pair(&s.left, &s.right, spec.ripple);
    let reliable = initial_disparity(&gl, &gr, &spec, &mut sgm::SgmBuffers::default());
    let census = (crate::census::census(&gl), crate::census::census(&gr));
    let range = (0.0, 31.0);
    let cost = assign::DataCost::new(census, (&gl, &gr), &reliable, range, &spec.planes);
    let planes = [BACK, FRONT];
    let (back, anchor_id) = (graph.ids.get(0, 0) as usize, graph.ids.get(60, 30) as usize);
    let on_front = |t: usize| t == anchor_id;
    let squares: Vec<usize> = (0..graph.len())
        .filter(|&t| t != back && t != anchor_id)
        .collect();
    let gain =
        |t: usize| cost.segment(graph.pixels(t), &BACK) - cost.segment(graph.pixels(t), &FRONT);
    // A colour edge around the box: its boundaries with the background
    // weigh nothing, the others their length.
    let w = s.left.width();
    let weights = graph.boundary_weights(|p, q| {
        let inside = |p: usize| in_front(p % w, p / w);
        f32::from(u8::from(inside(p) == inside(q)))
    });
    // Boundary weight that a move of the squares in `moving` to the front adds.
    let added_cut = |moving: &[usize]| -> f32 {
        let mut cut = 0.0;
        for &q in moving {
            let around = graph
                .neighbours(q)
                .iter()
                .zip(graph.of_segment(q, &weights));
            for (&(t, _), &weight) in around {
                let t = t as usize;
                if !moving.contains(&t) {
                    cut += if on_front(t) { -weight } else { weight };
                }
            }
        }
        cut
    };
    // λ above every square's own gain per added boundary, below the
    // group's, and below what keeps the left third on the box's plane.
    let alone = squares
        .iter()
        .map(|&q| {
            let cut = added_cut(&[q]);
            assert!(cut > 0.0 || gain(q) <= 0.0, "square {q} moves at any λ");
            gain(q) / cut
        })
        .fold(0.0f32, f32::max);
    assert!(
        added_cut(&squares) < 0.0,
        "the group cuts less on the front"
    );
    let anchor_cut: f32 = graph.of_segment(anchor_id, &weights).iter().sum();
    let anchored = gain(anchor_id) / anchor_cut;
    assert!(alone < anchored, "no λ fits: {alone} against {anchored}");
    let smoothness = (alone + anchored) / 2.0;
    let initial: Vec<Option<u32>> = (0..graph.len())
        .map(|t| Some(u32::from(on_front(t))))
        .collect();
    let run = |coupling: f32| {
        let params = PlanesParams {
            smoothness,
            coupling,
            ..spec.planes
        };
        assign::assign(&graph, &cost, &planes, &initial, &weights, &params).unwrap()
    };
    let one_at_a_time = run(f32::INFINITY);
    assert!(squares.iter().all(|&q| one_at_a_time[q] == 0));
    let grouped = run(0.1);
    assert!(squares.iter().all(|&q| grouped[q] == 1), "{grouped:?}");
    assert_eq!((grouped[back], grouped[anchor_id]), (0, 1));
}

#[test]
fn groups_join_same_plane_neighbours_across_even_colour_only() {
    // Five segments in a row, 2 px wide; the boundary between the second
    // and third is a colour edge (weight 0); the fourth has another plane.
    let ids = Plane::from_fn(10, 2, |x, _| (x / 2) as u32);
    let graph = SegmentGraph::from_ids(ids, 5);
    let weights = graph.boundary_weights(|p, q| f32::from(u8::from(p % 10 != 3 || q % 10 != 4)));
    let (group, groups) = assign::coupled_groups(&graph, &weights, &[0, 0, 0, 1, 0], 0.5);
    assert_eq!(groups, [vec![0, 1]]);
    assert_eq!(group, [0, 0, usize::MAX, usize::MAX, usize::MAX]);
    // At coupling 0 the colour edge joins too.
    let (_, groups) = assign::coupled_groups(&graph, &weights, &[0, 0, 0, 1, 0], 0.0);
    assert_eq!(groups, [vec![0, 1, 2]]);
}
