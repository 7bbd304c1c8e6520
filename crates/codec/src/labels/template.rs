//! What the model sees around a pixel: the causal template of the map, its
//! outer ring (strong mode) and the stereo prediction's template, gathered
//! as labels, and the masks of which positions hold a candidate.

use stereolink_image::LabelMap;

/// The causal template of the map: W, N, NW, NE, WW, NN, NEE, NWW, NNW,
/// NNE, WWW, NEEE.
const OWN: [(isize, isize); OWN_LEN] = [
    (-1, 0),
    (0, -1),
    (-1, -1),
    (1, -1),
    (-2, 0),
    (0, -2),
    (2, -1),
    (-2, -1),
    (-1, -2),
    (1, -2),
    (-3, 0),
    (3, -1),
];
pub(super) const OWN_LEN: usize = 12;
/// The template of the stereo prediction around `(x + s, y)`: P, E, W, S, N, EE.
const REF: [(isize, isize); 6] = [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1), (2, 0)];

/// The outer ring of the strong mode's template, beyond [`OWN`]: WWWW,
/// NNWW, NNEE, NNN, NWWW, NEEEE, NNWWW, NNEEE. Which of these hold a
/// candidate tells a noisy area from a clean edge.
const OUTER: [(isize, isize); OUTER_LEN] = [
    (-4, 0),
    (-2, -2),
    (2, -2),
    (0, -3),
    (-3, -1),
    (4, -1),
    (-3, -2),
    (3, -2),
];
pub(super) const OUTER_LEN: usize = 8;

/// Stands for a template position outside the map (or no prediction).
pub(super) const NONE: u32 = u32::MAX;

/// The labels of the map's template around (x, y).
#[inline(always)]
pub(super) fn own_template(data: &[u16], w: usize, x: usize, y: usize) -> [u32; OWN_LEN] {
    if x >= 3 && x + 3 < w && y >= 2 {
        // Inside (most pixels): direct reads, in the order of OWN.
        let (r0, r1, r2) = (y * w + x, (y - 1) * w + x, (y - 2) * w + x);
        assert!(r0 <= data.len());
        // SAFETY: the indices lie in r2 − 1 ..= r1 + 3, below r0 (x + 3 < w).
        let g = |i: usize| u32::from(unsafe { *data.get_unchecked(i) });
        [
            g(r0 - 1),
            g(r1),
            g(r1 - 1),
            g(r1 + 1),
            g(r0 - 2),
            g(r2),
            g(r1 + 2),
            g(r1 - 2),
            g(r2 - 1),
            g(r2 + 1),
            g(r0 - 3),
            g(r1 + 3),
        ]
    } else {
        // A plain loop: `array::map` is not inlined here.
        let mut t = [NONE; OWN_LEN];
        for (t, &(dx, dy)) in t.iter_mut().zip(&OWN) {
            let (xx, yy) = (x as isize + dx, y as isize + dy);
            if xx >= 0 && yy >= 0 && (xx as usize) < w {
                *t = u32::from(data[yy as usize * w + xx as usize]);
            }
        }
        t
    }
}

/// The labels of [`OUTER`] around (x, y).
#[inline(always)]
pub(super) fn outer_template(data: &[u16], w: usize, x: usize, y: usize) -> [u32; OUTER_LEN] {
    if x >= 4 && x + 4 < w && y >= 3 {
        // Inside: direct reads, in the order of OUTER.
        let (r0, r1, r2, r3) = (y * w + x, (y - 1) * w + x, (y - 2) * w + x, (y - 3) * w + x);
        let g = |i: usize| u32::from(data[i]);
        return [
            g(r0 - 4),
            g(r2 - 2),
            g(r2 + 2),
            g(r3),
            g(r1 - 3),
            g(r1 + 4),
            g(r2 - 3),
            g(r2 + 3),
        ];
    }
    OUTER.map(|(dx, dy)| {
        let (xx, yy) = (x as isize + dx, y as isize + dy);
        if xx >= 0 && yy >= 0 && (xx as usize) < w {
            u32::from(data[yy as usize * w + xx as usize])
        } else {
            NONE
        }
    })
}

/// The label of W if (x, y) is inside and its whole template holds it (most
/// pixels: a quick test without gathering the template).
#[inline(always)]
pub(super) fn flat_inside(data: &[u16], w: usize, x: usize, y: usize) -> Option<u32> {
    if x < 3 || x + 3 >= w || y < 2 {
        return None;
    }
    let (r0, r1, r2) = (y * w + x, (y - 1) * w + x, (y - 2) * w + x);
    let wv = data[r0 - 1];
    let same = |s: &[u16]| s.iter().fold(true, |a, &v| a & (v == wv));
    (same(&data[r0 - 3..r0 - 1]) & same(&data[r1 - 2..r1 + 4]) & same(&data[r2 - 1..r2 + 2]))
        .then_some(wv as u32)
}

/// Whether the whole template holds one label (W's, which exists).
#[inline(always)]
pub(super) fn is_flat(t: &[u32; OWN_LEN]) -> bool {
    t[0] != NONE && t.iter().all(|&l| l == t[0])
}

/// The labels of the prediction's template around (`xs`, y).
#[inline(always)]
pub(super) fn ref_template(reference: &LabelMap, xs: usize, y: usize) -> [u32; 6] {
    let (w, h) = reference.dims();
    let data = reference.as_slice();
    if xs >= 1 && xs + 2 < w && y >= 1 && y + 1 < h {
        // Inside: direct reads, in the order of REF.
        let i = y * w + xs;
        assert!(i + w < data.len());
        // SAFETY: the indices lie in i − w ..= i + w, inside the map (the
        // test above and the assertion).
        let g = |i: usize| u32::from(unsafe { *data.get_unchecked(i) });
        return [g(i), g(i + 1), g(i - 1), g(i + w), g(i - w), g(i + 2)];
    }
    let mut t = [NONE; 6];
    for (t, &(dx, dy)) in t.iter_mut().zip(&REF) {
        let (xx, yy) = (xs as isize + dx, y as isize + dy);
        if xx >= 0 && yy >= 0 && (xx as usize) < w && (yy as usize) < h {
            *t = u32::from(data[yy as usize * w + xx as usize]);
        }
    }
    t
}

/// Which positions of `t` hold `c`, as bits.
#[inline(always)]
pub(super) fn mask<const N: usize>(t: &[u32; N], c: u32) -> usize {
    let mut m = 0;
    for (k, &v) in t.iter().enumerate() {
        m |= ((v == c) as usize) << k;
    }
    m
}
