//! The receiver's 480x272 screen: the 3-D view and the disparity map side by
//! side, each scaled to fit a 236x177 panel, and a status area below (frame
//! id, link quality, distance, axis position, and a free message).
//!
//! [`Screen`] keeps its buffers, so rendering frame after frame allocates
//! nothing once the first frame is drawn. The board has no FPU: integer
//! disparities ([`Screen::render_levels`]) are painted from a table of the
//! range's colours, and the panels are scaled without a division per pixel.

use serde::Serialize;
use std::fmt::Write;

use stereolink_image::{colormap, DisparityMap, Plane, Rgb, RgbImage};

use crate::font::{draw_text, text_width, GLYPH_H};

/// Screen width (the board's TFT).
pub const SCREEN_WIDTH: usize = 480;
/// Screen height.
pub const SCREEN_HEIGHT: usize = 272;
const PANEL_W: usize = 236;
const PANEL_H: usize = 177;
const MARGIN: usize = 2;
const BAR_W: usize = 8;
const BACKGROUND: Rgb = [16, 18, 24];
const TEXT: Rgb = [230, 230, 230];
const ACCENT: Rgb = [255, 200, 60];

/// What the status area says.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ScreenStatus {
    /// Frame id of the shown pair.
    pub frame_id: u32,
    /// Share of link segments that needed no retransmission (0..1), if known.
    pub link_quality: Option<f64>,
    /// Signal strength of the last radio frame received, dBm, where the
    /// radio gives it.
    pub rssi_dbm: Option<i16>,
    /// Retransmitted segments the link received (duplicates it dropped),
    /// if counted.
    pub retransmitted: Option<u64>,
    /// Their share of the segments received (0..1), if any were.
    pub retransmit_rate: Option<f64>,
    /// Target distance from the depth report, metres.
    pub distance_m: Option<f64>,
    /// Axis position, millimetres.
    pub axis_mm: Option<f64>,
    /// The axis is held by a stop command (reports no longer move it).
    pub axis_held: bool,
    /// A free line (method, errors, ...).
    pub message: String,
    /// The link's security, after the free line: sealed or not, and the
    /// messages refused by cause.
    pub security: String,
}

/// The screen and its buffers.
pub struct Screen {
    image: RgbImage,
    /// The colour of each integer disparity of the range (render_levels).
    palette: Vec<Rgb>,
    /// Scratch for the text drawn, so rendering allocates nothing.
    text: String,
}

impl Default for Screen {
    fn default() -> Self {
        Screen {
            image: RgbImage::new(SCREEN_WIDTH, SCREEN_HEIGHT, BACKGROUND),
            palette: Vec::new(),
            text: String::new(),
        }
    }
}

/// `pixels.fill(c)` a word at a time: the colour's bytes repeat every
/// three, so three words hold four pixels (an ARMv5 stores no unaligned
/// word, and a pixel at a time takes three byte stores).
fn fill_rgb(pixels: &mut [Rgb], c: Rgb) {
    let bytes = pixels.as_flattened_mut();
    // SAFETY: any four bytes are a valid u32, and any u32 four valid bytes.
    let (head, words, tail) = unsafe { bytes.align_to_mut::<u32>() };
    // Byte `i` of the pixels is c[i % 3].
    let at = |i: usize| c[i % 3];
    for (i, b) in head.iter_mut().enumerate() {
        *b = at(i);
    }
    let start = head.len();
    let word = |k: usize| {
        let i = start + 4 * k;
        u32::from_ne_bytes([at(i), at(i + 1), at(i + 2), at(i + 3)])
    };
    let pattern = [word(0), word(1), word(2)];
    let mut threes = words.chunks_exact_mut(3);
    for three in &mut threes {
        three.copy_from_slice(&pattern);
    }
    for (w, p) in threes.into_remainder().iter_mut().zip(pattern) {
        *w = p;
    }
    let end = start + 4 * words.len();
    for (i, b) in tail.iter_mut().enumerate() {
        *b = at(end + i);
    }
}

/// Nearest-neighbour scale of `src`, painted by `paint`, into the panel at
/// `(x0, y0)`, keeping the aspect ratio: only the pixels shown are painted.
fn blit_scaled<T: Copy>(
    dst: &mut RgbImage,
    (src, paint): (&Plane<T>, impl Fn(T) -> Rgb),
    (x0, y0, w, h): (usize, usize, usize, usize),
) {
    let (sw, sh) = src.dims();
    if sw == 0 || sh == 0 {
        return;
    }
    let (tw, th) = scaled_size(sw, sh, w, h);
    let (ox, oy) = (x0 + (w - tw.min(w)) / 2, y0 + (h - th.min(h)) / 2);
    for (y, sy) in nearest(sh, th).take(h).enumerate() {
        let row = src.row(sy);
        let out = &mut dst.row_mut(oy + y)[ox..ox + tw.min(w)];
        for (px, sx) in out.iter_mut().zip(nearest(sw, tw)) {
            *px = paint(row[sx]);
        }
    }
}

/// The size `(tw, th)` a `sw` x `sh` source (neither 0) is scaled to in a
/// `w` x `h` panel, keeping its aspect ratio.
fn scaled_size(sw: usize, sh: usize, w: usize, h: usize) -> (usize, usize) {
    let scale = (w as f32 / sw as f32).min(h as f32 / sh as f32);
    (
        ((sw as f32 * scale) as usize).max(1),
        ((sh as f32 * scale) as usize).max(1),
    )
}

/// The source pixels the scaled blit of a `sw` x `sh` source into a `w` x
/// `h` panel reads: its rows (in order, repeated when scaled up) and its
/// columns (the same for each row); none for an empty source.
fn shown_in(
    (sw, sh): (usize, usize),
    (w, h): (usize, usize),
) -> (
    impl Iterator<Item = usize> + Clone,
    impl Iterator<Item = usize> + Clone,
) {
    let (tw, th) = match (sw, sh) {
        (0, _) | (_, 0) => (0, 0),
        _ => scaled_size(sw, sh, w, h),
    };
    (nearest(sh, th).take(h), nearest(sw, tw).take(tw.min(w)))
}

/// The source indices `⌊i · n / len⌋` for `i = 0..len` of a target `len`
/// long scaled from a source `n` long (each below `n`): stepped without a
/// division per index, a whole step `n / len` and a carried remainder.
fn nearest(n: usize, len: usize) -> impl Iterator<Item = usize> + Clone {
    let (step, rem) = match len {
        0 => (0, 0),
        _ => (n / len, n % len),
    };
    let (mut at, mut carry) = (0, 0);
    (0..len).map(move |_| {
        let i = at;
        at += step;
        carry += rem;
        if carry >= len {
            at += 1;
            carry -= len;
        }
        i
    })
}

impl Screen {
    /// A blank screen.
    pub fn new() -> Self {
        Self::default()
    }

    /// The pixels of a `width` x `height` 3-D view the screen shows (it
    /// scales the view into its panel): the rows, in order and repeated
    /// when the view is scaled up, and the columns of each. The other
    /// pixels of the view passed to [`render`](Self::render) are not read.
    pub fn view_shown(
        width: usize,
        height: usize,
    ) -> (
        impl Iterator<Item = usize> + Clone,
        impl Iterator<Item = usize> + Clone,
    ) {
        shown_in((width, height), (PANEL_W, PANEL_H))
    }

    /// The current screen image.
    pub fn image(&self) -> &RgbImage {
        &self.image
    }

    /// Draws a frame: the 3-D view, the disparity map over `[dmin, dmax]` with
    /// a labelled colour bar, and the status.
    pub fn render(
        &mut self,
        view: &RgbImage,
        disparity: &DisparityMap,
        dmin: f32,
        dmax: f32,
        status: &ScreenStatus,
    ) -> &RgbImage {
        let span = (dmax - dmin).max(f32::EPSILON);
        let turbo = colormap::turbo_table();
        let paint = |d: f32| {
            if d.is_finite() {
                turbo[colormap::turbo_index((d - dmin) / span)]
            } else {
                colormap::INVALID
            }
        };
        self.compose(view, (disparity, paint), dmin, dmax, status);
        &self.image
    }

    /// [`render`](Self::render) for integer disparities (`no_disparity`
    /// marks a pixel without one) over `dmin..=dmax`: the same screen as
    /// `render` of their `f32` values, painted from a table of the range's
    /// colours, with no floating point per pixel.
    pub fn render_levels(
        &mut self,
        view: &RgbImage,
        levels: &Plane<u16>,
        no_disparity: u16,
        (dmin, dmax): (u16, u16),
        status: &ScreenStatus,
    ) -> &RgbImage {
        let dmax = dmax.max(dmin);
        let (lo, span) = (dmin as f32, ((dmax - dmin) as f32).max(f32::EPSILON));
        let turbo = colormap::turbo_table();
        let mut palette = std::mem::take(&mut self.palette);
        palette.clear();
        palette.extend((dmin..=dmax).map(|l| turbo[colormap::turbo_index((l as f32 - lo) / span)]));
        // Above dmax the float path clamps to the last colour of the table
        // (below dmin, to the first, which is dmin's).
        palette.push(turbo[255]);
        let above = palette.len() - 1;
        let paint = |l: u16| match l {
            _ if l == no_disparity => colormap::INVALID,
            _ => palette[(l.saturating_sub(dmin) as usize).min(above)],
        };
        self.compose(view, (levels, paint), lo, dmax as f32, status);
        self.palette = palette;
        &self.image
    }

    /// Draws the panels (the disparity map painted by its `paint`), the
    /// colour bar over `[dmin, dmax]` and the status.
    fn compose<T: Copy>(
        &mut self,
        view: &RgbImage,
        disparity: (&Plane<T>, impl Fn(T) -> Rgb),
        dmin: f32,
        dmax: f32,
        status: &ScreenStatus,
    ) {
        let turbo = colormap::turbo_table();
        let paint = |t: f32| turbo[colormap::turbo_index(t)];
        let img = &mut self.image;
        fill_rgb(img.as_mut_slice(), BACKGROUND);
        draw_text(img, MARGIN + 2, MARGIN + 1, "3-D VIEW", ACCENT);
        draw_text(
            img,
            PANEL_W + 3 * MARGIN + 2,
            MARGIN + 1,
            "DISPARITY",
            ACCENT,
        );
        let top = MARGIN + GLYPH_H + 3;
        blit_scaled(img, (view, |p| p), (MARGIN, top, PANEL_W, PANEL_H));
        let dx = PANEL_W + 3 * MARGIN;
        blit_scaled(img, disparity, (dx, top, PANEL_W - BAR_W - 16, PANEL_H));
        // Colour bar with its range.
        let bx = dx + PANEL_W - BAR_W - 14;
        for y in 0..PANEL_H {
            let c = paint(1.0 - y as f32 / (PANEL_H - 1) as f32);
            img.row_mut(top + y)[bx..bx + BAR_W].fill(c);
        }
        let text = &mut self.text;
        text.clear();
        let _ = write!(text, "{dmax:.0}");
        draw_text(
            img,
            SCREEN_WIDTH - MARGIN - text_width(text),
            top,
            text,
            TEXT,
        );
        text.clear();
        let _ = write!(text, "{dmin:.0}");
        draw_text(
            img,
            SCREEN_WIDTH - MARGIN - text_width(text),
            top + PANEL_H - GLYPH_H,
            text,
            TEXT,
        );
        // Status area.
        let sy = top + PANEL_H + 6;
        text.clear();
        let _ = write!(text, "FRAME {}   LINK ", status.frame_id);
        // What the link measures: quality, signal, retransmissions.
        let before = text.len();
        if let Some(q) = status.link_quality {
            let _ = write!(text, "{:.0}% ", q * 100.0);
        }
        if let Some(r) = status.rssi_dbm {
            let _ = write!(text, "{r} DBM ");
        }
        if let Some(n) = status.retransmitted {
            let _ = write!(text, "{n} RTX ");
        }
        if let Some(r) = status.retransmit_rate {
            let _ = write!(text, "{:.1}% ", r * 100.0);
        }
        match text.len() == before {
            true => text.push_str("--"),
            false => {
                text.pop();
            }
        }
        let _ = match status.distance_m {
            Some(d) => write!(text, "   DIST {d:.3} M"),
            None => write!(text, "   DIST --"),
        };
        let _ = match status.axis_mm {
            Some(a) => write!(text, "   AXIS {a:.1} MM"),
            None => write!(text, "   AXIS --"),
        };
        if status.axis_held {
            text.push_str(" HELD");
        }
        draw_text(img, MARGIN + 2, sy, text, TEXT);
        let x = draw_text(
            img,
            MARGIN + 2,
            sy + GLYPH_H + 5,
            &status.message,
            [160, 200, 255],
        );
        draw_text(
            img,
            x + 12,
            sy + GLYPH_H + 5,
            &status.security,
            [255, 200, 120],
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fill_rgb_is_fill() {
        // Every length up to ten words, from each alignment of the pixels.
        for (len, skip) in (0..40).flat_map(|n| (0..4).map(move |k| (n, k))) {
            let mut pixels: Vec<Rgb> = (0..len + skip).map(|i| [i as u8, 7, 9]).collect();
            let mut want = pixels.clone();
            fill_rgb(&mut pixels[skip..], BACKGROUND);
            want[skip..].fill(BACKGROUND);
            assert_eq!(pixels, want, "{len} pixels after {skip}");
        }
    }

    #[test]
    fn nearest_indices_are_the_divisions() {
        for n in 1..70 {
            for len in 1..70 {
                let stepped: Vec<usize> = nearest(n, len).collect();
                let divided: Vec<usize> = (0..len).map(|i| i * n / len).collect();
                assert_eq!(stepped, divided, "{n} into {len}");
            }
        }
    }

    /// Integer levels give the screen that their `f32` values give, in and
    /// out of the range and without a disparity.
    #[test]
    fn integer_levels_paint_the_float_screen() {
        const NONE: u16 = u16::MAX;
        let view = RgbImage::from_fn(480, 272, |x, y| [x as u8, y as u8, 90]);
        let levels = Plane::from_fn(480, 272, |x, y| match (x + 3 * y) % 41 {
            40 => NONE,
            v => v as u16,
        });
        let floats = levels.map(|l| if l == NONE { f32::INFINITY } else { l as f32 });
        let status = ScreenStatus {
            frame_id: 3,
            ..Default::default()
        };
        for (dmin, dmax) in [(0, 31), (2, 31), (5, 5), (0, 63)] {
            let a = Screen::new()
                .render(&view, &floats, dmin as f32, dmax as f32, &status)
                .clone();
            let b = Screen::new()
                .render_levels(&view, &levels, NONE, (dmin, dmax), &status)
                .clone();
            assert!(a == b, "range {dmin}..={dmax}");
        }
    }

    #[test]
    fn renders_the_fixed_size_layout_and_reuses_its_buffer() {
        let mut s = Screen::new();
        let view = RgbImage::new(384, 288, [200, 0, 0]);
        let disp = DisparityMap::from_fn(384, 288, |x, _| x as f32 / 12.0);
        let status = ScreenStatus {
            frame_id: 7,
            distance_m: Some(1.5),
            ..Default::default()
        };
        let ptr = s.image().as_slice().as_ptr();
        let img = s.render(&view, &disp, 0.0, 32.0, &status).clone();
        assert_eq!(img.dims(), (SCREEN_WIDTH, SCREEN_HEIGHT));
        assert_eq!(img.get(100, 100), [200, 0, 0]); // inside the 3-D panel
        assert_ne!(img.get(300, 100), BACKGROUND); // disparity panel painted
        assert!(img.as_slice().contains(&TEXT));
        s.render(&view, &disp, 0.0, 32.0, &status);
        assert_eq!(s.image().as_slice().as_ptr(), ptr);
        // The link's measures, where known, replace the `--`.
        let measured = ScreenStatus {
            rssi_dbm: Some(-45),
            retransmitted: Some(3),
            ..status.clone()
        };
        let plain = s.render(&view, &disp, 0.0, 32.0, &status).clone();
        let counted = s.render(&view, &disp, 0.0, 32.0, &measured).clone();
        assert_ne!(counted, plain);
        let rated = ScreenStatus {
            retransmit_rate: Some(0.012),
            ..measured
        };
        let rated = s.render(&view, &disp, 0.0, 32.0, &rated).clone();
        assert_ne!(rated, counted);
        let held = ScreenStatus {
            axis_mm: Some(12.5),
            axis_held: true,
            ..status.clone()
        };
        let moving = ScreenStatus {
            axis_held: false,
            ..held.clone()
        };
        let moving = s.render(&view, &disp, 0.0, 32.0, &moving).clone();
        assert_ne!(s.render(&view, &disp, 0.0, 32.0, &held), &moving);
    }
}
