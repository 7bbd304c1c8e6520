//! The fast mode: its one context per decision, and its row loop, which
//! codes runs of W's label (and the candidate after W) straight from the
//! map, leaving the rest of a pixel to the shared candidate scan.

use stereolink_image::LabelMap;

use super::bitio::BitIo;
use super::model::{Model, RANKS};
use super::pixel::{checked, code_after_w, code_pixel, Scan};
use super::shifts::BLOCK;
use super::template::{is_flat, own_template, ref_template, NONE};
use crate::rangecoder::Counter;
use crate::CodecError;

/// Context bits besides the rank of the fast mode: eight bits of the own
/// mask alone, four and the prediction's six conditioned.
const FAST_BITS: u32 = 10;
/// Contexts of the fast mode.
pub(super) const FAST_CONTEXTS: usize = RANKS << FAST_BITS;

/// The counter of the fast mode's decision for the candidate of rank `r`
/// with own mask `mo` and prediction mask `mr`: the own-mask bits are W, N,
/// NW, NE when coding conditioned (`COND`: the prediction's mask takes the
/// place), else the eight nearest (and `mr` is 0). The contexts are those
/// of `docs/wire-format.md`, packed densely, so that the few that occur
/// share cache lines.
#[inline(always)]
const fn fast_context<const COND: bool>(r: usize, mo: usize, mr: usize) -> usize {
    if COND {
        r << FAST_BITS | (mo & 15) << 6 | mr
    } else {
        r << FAST_BITS | (mo & 255)
    }
}

/// The fast mode's counter for [`fast_context`] (which is below
/// [`FAST_CONTEXTS`]: the mask only spares the bounds check).
#[inline(always)]
pub(super) fn fast_counter<const COND: bool>(
    fast: &mut [Counter; FAST_CONTEXTS],
    r: usize,
    mo: usize,
    mr: usize,
) -> &mut Counter {
    &mut fast[fast_context::<COND>(r, mo, mr) & (FAST_CONTEXTS - 1)]
}

/// Codes row `y` in the fast mode. Pixels whose own template reaches W,
/// N, NW, NE, WW, NN, NEE and NWW inside the map (and, conditioned, whose
/// prediction template lies inside the reference) have their W decisions,
/// and after a 0 the next candidate's, coded by [`w_run`], block by block,
/// and after two 0s the rest of the pixel; the others go through
/// [`code_pixel`].
#[inline(always)]
pub(super) fn code_row_fast<I: BitIo, const COND: bool>(
    io: &mut I,
    model: &mut Model,
    n_labels: usize,
    (data, w, y): (&mut [u16], usize, usize),
    reference: Option<&LabelMap>,
    shifts: &[u8],
) -> Result<(), CodecError> {
    let h = data.len() / w;
    let mut x = 0;
    while x < w {
        let s = shifts[x / BLOCK] as usize;
        let rf = |x: usize| match reference {
            Some(r) if COND => ref_template(r, x + s, y),
            _ => [NONE; 6],
        };
        // The stretch from x that [`w_run`] may code: inside the own
        // template, the block and (conditioned) the prediction's template.
        let mut end = match y >= 2 && x >= 2 {
            true => w.saturating_sub(2),
            false => x,
        };
        if let (true, Some(_)) = (COND, reference) {
            let inside = y + 1 < h && x + s >= 1;
            end = match inside {
                true => end
                    .min(w.saturating_sub(2 + s))
                    .min((x / BLOCK + 1) * BLOCK),
                false => x,
            };
        }
        let i = y * w + x;
        if x < end {
            let pred = reference.filter(|_| COND).map(|r| (r.as_slice(), s));
            let fast = &mut model.fast;
            match w_run::<I, COND>(io, fast, n_labels, (data, w, y), x..end, pred)? {
                Some((miss, scan)) => {
                    let own = own_template(data, w, miss, y);
                    let v = data[y * w + miss] as u32;
                    let rf = &rf(miss);
                    data[y * w + miss] =
                        code_after_w::<I, false, COND>(io, model, n_labels, &own, rf, v, scan)?;
                    x = miss + 1;
                }
                None => x = end,
            }
        } else {
            let own = own_template(data, w, x, y);
            let v = data[i] as u32;
            data[i] = code_pixel::<I, false, COND>(
                io,
                model,
                n_labels,
                (&own, is_flat(&own)),
                &rf(x),
                v,
            )?;
            x += 1;
        }
    }
    Ok(())
}

/// The fast mode's W decisions of row `y` over `run`, read straight from
/// the map (and, conditioned, from `pred`: the reference's labels and the
/// block's shift): each "1" writes W's label. On a "0" the pixel's first
/// candidate after W (nearly always the prediction P, conditioned) is
/// coded here too, and on a "1" its label is written and the run goes on
/// with it as W; else the run ends at the pixel, returned with where the
/// scan of its candidates stands (the rest of that pixel is the caller's).
/// The context needs only W, N, NW, NE (and, coding alone, WW, NN, NEE,
/// NWW) and the prediction's mask, so the loop holds few values; after a
/// "1" W's label is the same, so the masks shift, and only the positions
/// entering on the right are read.
#[inline(always)]
fn w_run<I: BitIo, const COND: bool>(
    io: &mut I,
    fast: &mut [Counter; FAST_CONTEXTS],
    n_labels: usize,
    (data, w, y): (&mut [u16], usize, usize),
    run: std::ops::Range<usize>,
    pred: Option<(&[u16], usize)>,
) -> Result<Option<(usize, Scan)>, CodecError> {
    let (above, cur) = data.split_at_mut(y * w);
    let (cur, up, up2) = (&mut cur[..w], &above[(y - 1) * w..], &above[(y - 2) * w..]);
    // Conditioned, the prediction's rows y − 1, y and y + 1 from x + s on.
    let (refs, s) = pred.unwrap_or((&[], 0));
    let rows = match COND {
        // Three slices rather than an `array::map`, which is not inlined.
        true => [
            &refs[(y - 1) * w + s..y * w],
            &refs[y * w + s..(y + 1) * w],
            &refs[(y + 1) * w + s..(y + 2) * w],
        ],
        false => [&[][..]; 3],
    };
    // Every index below lies in x − 2 ..= x + 2 of a row (x + 2 of the
    // prediction's, which start at x + s): inside each of them.
    assert!(run.start >= 2 && run.end + 2 <= w && (!COND || run.end + 2 + s <= w));
    // SAFETY: the assertion above, for every row read.
    let g = |row: &[u16], x: usize| unsafe { *row.get_unchecked(x) };
    let [above, row, below] = rows;
    let eq = |v: u16, l: u16| (v == l) as usize;
    // The masks of label `l` at x (W's bit set when W holds `l`).
    let masks = |cur: &[u16], x: usize, l: u16| {
        let mut mo = eq(g(cur, x - 1), l)
            | eq(g(up, x), l) << 1
            | eq(g(up, x - 1), l) << 2
            | eq(g(up, x + 1), l) << 3;
        let mut mr = 0;
        if COND {
            mr = eq(g(row, x), l)
                | eq(g(row, x + 1), l) << 1
                | eq(g(row, x - 1), l) << 2
                | eq(g(below, x), l) << 3
                | eq(g(above, x), l) << 4
                | eq(g(row, x + 2), l) << 5;
        } else {
            mo |= eq(g(cur, x - 2), l) << 4
                | eq(g(up2, x), l) << 5
                | eq(g(up, x + 2), l) << 6
                | eq(g(up, x - 2), l) << 7;
        }
        (mo, mr)
    };
    // The masks one pixel right of x − 1, whose label `l` is now W's: N,
    // NW and NWW are the last NE, N and NW, NE the last NEE, WW is the
    // last W (`ww`: its bit, set in a run); the prediction's W, P, E are
    // the last P, E, EE. Only what enters on the right is read.
    let step = |(mo, mr): (usize, usize), x: usize, l: u16, ww: usize| {
        if COND {
            let mo = 1 | (mo >> 2 & 2) | (mo << 1 & 4) | eq(g(up, x + 1), l) << 3;
            let mr = (mr >> 1 & 1)
                | (mr >> 4 & 2)
                | (mr << 2 & 4)
                | eq(g(below, x), l) << 3
                | eq(g(above, x), l) << 4
                | eq(g(row, x + 2), l) << 5;
            (mo, mr)
        } else {
            let mo = 1
                | (mo >> 2 & 2)
                | (mo << 1 & 4)
                | (mo >> 3 & 8)
                | ww
                | eq(g(up2, x), l) << 5
                | eq(g(up, x + 2), l) << 6
                | (mo << 5 & 128);
            (mo, mr)
        }
    };
    let (mut x, end) = (run.start, run.end);
    // W's label, the run's: each "1" writes it, so it is the next W too.
    let mut wv = g(cur, x - 1);
    let mut m = masks(cur, x, wv);
    loop {
        if io.bit(fast_counter::<COND>(fast, 0, m.0, m.1), g(cur, x) == wv) {
            cur[x] = wv;
            x += 1;
            if x == end {
                return Ok(None);
            }
            m = step(m, x, wv, 16);
            continue;
        }
        // The first candidate after W: of [`code_after_w`]'s order, the
        // first label other than W's. Nearly always P (conditioned) or N;
        // else the positions within x ± 2 are looked at (coding alone,
        // the prediction's stand as W's label, never a candidate).
        let rf = |row: &[u16], x: usize| if COND { g(row, x) } else { wv };
        let (k, c) = match (rf(row, x), g(up, x)) {
            (p, _) if p != wv => (0, p),
            (_, n) if n != wv => (1, n),
            _ => {
                let near = [
                    g(up, x + 1),
                    g(up, x - 1),
                    g(cur, x - 2),
                    g(up2, x),
                    g(up, x + 2),
                    g(up, x - 2),
                    rf(row, x + 1),
                    rf(row, x - 1),
                    rf(below, x),
                    rf(above, x),
                    rf(row, x + 2),
                ];
                match near.iter().position(|&c| c != wv) {
                    Some(k) => (k + 2, near[k]),
                    None => return Ok(Some((x, Scan::after(wv.into()).from(near.len() + 2)))),
                }
            }
        };
        let mc = masks(cur, x, c);
        if !io.bit(fast_counter::<COND>(fast, 1, mc.0, mc.1), g(cur, x) == c) {
            return Ok(Some((x, Scan::after(wv.into()).refused(k, c.into()))));
        }
        cur[x] = checked(c.into(), n_labels)?;
        wv = c;
        x += 1;
        if x == end {
            return Ok(None);
        }
        // WW holds the last W's label, not `c`.
        m = step(mc, x, wv, 0);
    }
}
