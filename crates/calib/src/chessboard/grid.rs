//! From candidate corners to a board: seed, grow, check, order.
//!
//! A seed is a candidate with its four grid neighbours and four diagonal
//! neighbours (a 3x3 grid whose four squares alternate dark and light). The
//! grid then grows, as in Geiger et al. 2012 (§III-B): a new row or column
//! beyond a side is predicted from the last three lines by second-order
//! extrapolation (the spacing shrinks or grows under perspective), each
//! predicted corner takes the nearest free candidate within
//! [`ChessboardOptions::match_tolerance`] of the local square side, and the
//! line is added only if every corner is found and every new square has the
//! colour the checkerboard demands, with
//! [`ChessboardOptions::min_contrast`] to its neighbours. Growth ends when no
//! side can grow.

use nalgebra::{Point2, Vector2};

use super::saddle::Smooth;
use super::{BoardSize, ChessboardOptions, NotFound};

/// Nearest neighbours of a seed tried as its first grid neighbour.
const SEED_FIRST: usize = 4;
/// Nearest neighbours of a seed considered at all.
const SEED_NEIGHBOURS: usize = 10;

/// A uniform-bucket index of candidate positions for radius queries.
struct Index<'a> {
    candidates: &'a [Point2<f64>],
    cell: f64,
    cols: usize,
    rows: usize,
    buckets: Vec<Vec<usize>>,
}

impl<'a> Index<'a> {
    fn new(candidates: &'a [Point2<f64>], (width, height): (usize, usize)) -> Self {
        let cell = 16.0;
        let cols = (width as f64 / cell).ceil().max(1.0) as usize;
        let rows = (height as f64 / cell).ceil().max(1.0) as usize;
        let mut buckets = vec![Vec::new(); cols * rows];
        let mut index = Index {
            candidates,
            cell,
            cols,
            rows,
            buckets: Vec::new(),
        };
        for (i, c) in candidates.iter().enumerate() {
            let (bx, by) = index.bucket(*c);
            buckets[by * cols + bx].push(i);
        }
        index.buckets = buckets;
        index
    }

    fn bucket(&self, p: Point2<f64>) -> (usize, usize) {
        let bx = (p.x / self.cell).floor().clamp(0.0, (self.cols - 1) as f64) as usize;
        let by = (p.y / self.cell).floor().clamp(0.0, (self.rows - 1) as f64) as usize;
        (bx, by)
    }

    fn pos(&self, i: usize) -> Point2<f64> {
        self.candidates[i]
    }

    /// The candidate nearest `target` within `radius`, skipping `taken`.
    fn nearest(&self, target: Point2<f64>, radius: f64, taken: &[usize]) -> Option<usize> {
        if !(radius > 0.0 && target.x.is_finite() && target.y.is_finite()) {
            return None;
        }
        let (x0, y0) = self.bucket(target - Vector2::new(radius, radius));
        let (x1, y1) = self.bucket(target + Vector2::new(radius, radius));
        let mut best = None;
        let mut best_d = radius * radius;
        for by in y0..=y1 {
            for bx in x0..=x1 {
                for &i in &self.buckets[by * self.cols + bx] {
                    let d = (self.pos(i) - target).norm_squared();
                    if d <= best_d && !taken.contains(&i) {
                        best_d = d;
                        best = Some(i);
                    }
                }
            }
        }
        best
    }

    /// Up to `k` candidates nearest `seed`, nearest first, within `radius`.
    fn k_nearest(&self, seed: usize, k: usize, radius: f64) -> Vec<usize> {
        let p = self.pos(seed);
        let (x0, y0) = self.bucket(p - Vector2::new(radius, radius));
        let (x1, y1) = self.bucket(p + Vector2::new(radius, radius));
        let mut near: Vec<(f64, usize)> = Vec::new();
        for by in y0..=y1 {
            for bx in x0..=x1 {
                for &i in &self.buckets[by * self.cols + bx] {
                    let d = (self.pos(i) - p).norm_squared();
                    if i != seed && d <= radius * radius {
                        near.push((d, i));
                    }
                }
            }
        }
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        near.into_iter().take(k).map(|(_, i)| i).collect()
    }
}

/// A grown grid: candidate indices, row-major, and the colour of its first
/// square.
struct Growing {
    rows: Vec<Vec<usize>>,
    /// Whether the square between corners (0,0) and (1,1) is dark.
    dark00: bool,
}

/// The side of a grid where a line is added.
#[derive(Clone, Copy)]
enum Side {
    Top,
    Bottom,
    Left,
    Right,
}

impl Growing {
    fn width(&self) -> usize {
        self.rows[0].len()
    }

    fn height(&self) -> usize {
        self.rows.len()
    }

    fn members(&self) -> Vec<usize> {
        self.rows.iter().flatten().copied().collect()
    }

    /// The `k`-th line from `side` (0 = the outermost), its corners in
    /// increasing grid index along the side.
    fn line(&self, side: Side, k: usize) -> Vec<usize> {
        match side {
            Side::Top => self.rows[k].clone(),
            Side::Bottom => self.rows[self.height() - 1 - k].clone(),
            Side::Left => self.rows.iter().map(|r| r[k]).collect(),
            Side::Right => self.rows.iter().map(|r| r[r.len() - 1 - k]).collect(),
        }
    }

    /// Whether square `j` along the new line beyond `side` must be dark.
    fn new_square_dark(&self, side: Side, j: usize) -> bool {
        // Squares are indexed (row, col) by their top-left corner; the new
        // line's squares sit at row -1 (top), height-1 (bottom), and so on.
        let parity = match side {
            Side::Top => 1 + j,
            Side::Bottom => self.height() - 1 + j,
            Side::Left => j + 1,
            Side::Right => j + self.width() - 1,
        };
        self.dark00 ^ (parity % 2 == 1)
    }

    fn add(&mut self, side: Side, line: Vec<usize>) {
        match side {
            Side::Top => {
                self.rows.insert(0, line);
                self.dark00 = !self.dark00;
            }
            Side::Bottom => self.rows.push(line),
            Side::Left => {
                for (r, i) in self.rows.iter_mut().zip(line) {
                    r.insert(0, i);
                }
                self.dark00 = !self.dark00;
            }
            Side::Right => {
                for (r, i) in self.rows.iter_mut().zip(line) {
                    r.push(i);
                }
            }
        }
    }
}

/// A detected grid of corners (unrefined), any orientation.
pub(super) struct Grid {
    rows: Vec<Vec<Point2<f64>>>,
}

impl Grid {
    /// The grid's size, `cols` the length of its rows.
    fn size(&self) -> BoardSize {
        BoardSize::new(self.rows[0].len(), self.rows.len())
    }

    /// The size oriented like `pattern` (both landscape or both portrait).
    fn size_like(&self, pattern: BoardSize) -> BoardSize {
        let s = self.size();
        if (s.cols >= s.rows) == (pattern.cols >= pattern.rows) {
            s
        } else {
            s.transposed()
        }
    }

    /// The corners in the documented order (module doc of `chessboard`);
    /// `self` must have `pattern`'s size in some orientation.
    pub(super) fn ordered(mut self, smooth: &Smooth, pattern: BoardSize) -> Vec<Point2<f64>> {
        if self.rows[0].len() != pattern.cols {
            let (w, h) = (self.rows[0].len(), self.rows.len());
            self.rows = (0..w)
                .map(|c| (0..h).map(|r| self.rows[r][c]).collect())
                .collect();
        }
        let u = self.rows[0][1] - self.rows[0][0];
        let v = self.rows[1][0] - self.rows[0][0];
        if u.x * v.y - u.y * v.x < 0.0 {
            self.rows.reverse();
        }
        let (w, h) = (pattern.cols, pattern.rows);
        let first = square_mean(smooth, &self.rows, 0, 0);
        let last = square_mean(smooth, &self.rows, h - 2, w - 2);
        let rotate = if (w + h) % 2 == 1 {
            last < first
        } else {
            let (a, b) = (self.rows[0][0], self.rows[h - 1][w - 1]);
            b.x + b.y < a.x + a.y
        };
        if rotate {
            self.rows.reverse();
            for r in &mut self.rows {
                r.reverse();
            }
        }
        self.rows.into_iter().flatten().collect()
    }
}

/// Mean intensity of square `(r, c)` (between corners `(r, c)` and
/// `(r+1, c+1)`): five samples, the centre and halfway to each corner.
fn square_mean(smooth: &Smooth, rows: &[Vec<Point2<f64>>], r: usize, c: usize) -> f64 {
    let quad = [
        rows[r][c],
        rows[r][c + 1],
        rows[r + 1][c],
        rows[r + 1][c + 1],
    ];
    square_intensity(smooth, quad)
}

fn square_intensity(smooth: &Smooth, quad: [Point2<f64>; 4]) -> f64 {
    let centre =
        Point2::from((quad[0].coords + quad[1].coords + quad[2].coords + quad[3].coords) / 4.0);
    let mut sum = smooth.sample(centre.x, centre.y);
    for q in quad {
        let p = centre + (q - centre) * 0.5;
        sum += smooth.sample(p.x, p.y);
    }
    sum / 5.0
}

/// Finds the board: seeds in order of response, each grown; returns the
/// first grid of `pattern`'s size, or the reason none is.
pub(super) fn find_grid(
    smooth: &Smooth,
    candidates: &[Point2<f64>],
    pattern: BoardSize,
    options: &ChessboardOptions,
) -> Result<Grid, NotFound> {
    let index = Index::new(candidates, smooth.dims());
    let mut used = vec![false; candidates.len()];
    let mut best: Option<Grid> = None;
    for seed in 0..candidates.len() {
        if used[seed] {
            continue;
        }
        let Some(mut growing) = seed_grid(smooth, &index, seed, options) else {
            continue;
        };
        grow(smooth, &index, &mut growing, options);
        for &i in growing.rows.iter().flatten() {
            used[i] = true;
        }
        let grid = Grid {
            rows: growing
                .rows
                .iter()
                .map(|r| r.iter().map(|&i| index.pos(i)).collect())
                .collect(),
        };
        if grid.size_like(pattern) == pattern {
            return Ok(grid);
        }
        if best
            .as_ref()
            .is_none_or(|b| grid.size().count() > b.size().count())
        {
            best = Some(grid);
        }
    }
    Err(match best {
        None => NotFound::NoGrid,
        Some(grid) => {
            let found = grid.size_like(pattern);
            if found.cols <= pattern.cols && found.rows <= pattern.rows {
                NotFound::Partial {
                    found,
                    expected: pattern,
                }
            } else {
                NotFound::WrongSize {
                    found,
                    expected: pattern,
                }
            }
        }
    })
}

/// A 3x3 grid around `seed` whose squares alternate, if there is one.
fn seed_grid(
    smooth: &Smooth,
    index: &Index,
    seed: usize,
    options: &ChessboardOptions,
) -> Option<Growing> {
    let s = index.pos(seed);
    let (w, h) = smooth.dims();
    let near = index.k_nearest(seed, SEED_NEIGHBOURS, 0.25 * w.max(h) as f64);
    let tol = options.match_tolerance;
    for &ia in near.iter().take(SEED_FIRST) {
        let a = index.pos(ia) - s;
        let Some(ia2) = index.nearest(s - a, tol * a.norm(), &[seed, ia]) else {
            continue;
        };
        for &ib in &near {
            let b = index.pos(ib) - s;
            let cos = a.dot(&b) / (a.norm() * b.norm());
            if ib == ia || ib == ia2 || cos.abs() > 0.7 {
                continue;
            }
            let radius = tol * a.norm().min(b.norm());
            let mut taken = vec![seed, ia, ia2, ib];
            let find = |p: Point2<f64>, taken: &mut Vec<usize>| {
                let i = index.nearest(p, radius, taken)?;
                taken.push(i);
                Some(i)
            };
            let Some(ib2) = find(s - b, &mut taken) else {
                continue;
            };
            let (pa, pa2) = (index.pos(ia), index.pos(ia2));
            let (Some(d0), Some(d1), Some(d2), Some(d3)) = (
                find(pa2 + (index.pos(ib2) - s), &mut taken),
                find(pa + (index.pos(ib2) - s), &mut taken),
                find(pa2 + b, &mut taken),
                find(pa + b, &mut taken),
            ) else {
                continue;
            };
            // Rows run along b (from s − b to s + b), columns along a.
            let rows = vec![vec![d0, ib2, d1], vec![ia2, seed, ia], vec![d2, ib, d3]];
            if let Some(grid) = checked_seed(smooth, index, rows, options) {
                return Some(grid);
            }
        }
    }
    None
}

/// The seed grid if its four squares alternate with enough contrast.
fn checked_seed(
    smooth: &Smooth,
    index: &Index,
    rows: Vec<Vec<usize>>,
    options: &ChessboardOptions,
) -> Option<Growing> {
    let pts: Vec<Vec<Point2<f64>>> = rows
        .iter()
        .map(|r| r.iter().map(|&i| index.pos(i)).collect())
        .collect();
    let sq = |r, c| square_mean(smooth, &pts, r, c);
    let (s00, s01, s10, s11) = (sq(0, 0), sq(0, 1), sq(1, 0), sq(1, 1));
    let dark00 = s00 < s01;
    let (dark, light) = if dark00 {
        (s00.max(s11), s01.min(s10))
    } else {
        (s01.max(s10), s00.min(s11))
    };
    (light - dark >= options.min_contrast).then_some(Growing { rows, dark00 })
}

/// Grows `grid` until no side can be extended.
fn grow(smooth: &Smooth, index: &Index, grid: &mut Growing, options: &ChessboardOptions) {
    loop {
        let mut grew = false;
        for side in [Side::Top, Side::Bottom, Side::Left, Side::Right] {
            if let Some(line) = extension(smooth, index, grid, side, options) {
                grid.add(side, line);
                grew = true;
            }
        }
        if !grew {
            return;
        }
    }
}

/// The line beyond `side`, if every corner is found and the squares fit.
fn extension(
    smooth: &Smooth,
    index: &Index,
    grid: &Growing,
    side: Side,
    options: &ChessboardOptions,
) -> Option<Vec<usize>> {
    let depth = match side {
        Side::Top | Side::Bottom => grid.height(),
        Side::Left | Side::Right => grid.width(),
    };
    let l0 = grid.line(side, 0);
    let l1 = grid.line(side, 1);
    let l2 = (depth >= 3).then(|| grid.line(side, 2));
    let mut taken = grid.members();
    let mut new = Vec::with_capacity(l0.len());
    for j in 0..l0.len() {
        let (p0, p1) = (index.pos(l0[j]), index.pos(l1[j]));
        let step = p0 - p1;
        let predicted = match &l2 {
            Some(l2) => p0 + step + (step - (p1 - index.pos(l2[j]))),
            None => p0 + step,
        };
        let i = index.nearest(predicted, options.match_tolerance * step.norm(), &taken)?;
        taken.push(i);
        new.push(i);
    }
    let quad =
        |a: &[usize], b: &[usize], j: usize| [a[j], a[j + 1], b[j], b[j + 1]].map(|i| index.pos(i));
    let mut prev_new = None;
    for j in 0..l0.len() - 1 {
        let new_sq = square_intensity(smooth, quad(&l0, &new, j));
        let old_sq = square_intensity(smooth, quad(&l1, &l0, j));
        let dark = grid.new_square_dark(side, j);
        let contrasted =
            |dark_value: f64, light_value: f64| light_value - dark_value >= options.min_contrast;
        let fits_old = if dark {
            contrasted(new_sq, old_sq)
        } else {
            contrasted(old_sq, new_sq)
        };
        let fits_prev = prev_new.is_none_or(|p| {
            if dark {
                contrasted(new_sq, p)
            } else {
                contrasted(p, new_sq)
            }
        });
        if !(fits_old && fits_prev) {
            return None;
        }
        prev_new = Some(new_sq);
    }
    Some(new)
}
