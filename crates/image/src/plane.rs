//! Dense row-major image buffers, generic over the pixel type.

use crate::{Error, Result};

/// An RGB pixel, 8 bits per channel.
pub type Rgb = [u8; 3];

/// A dense row-major 2-D buffer of `T`: pixel `(x, y)` is `data[y * width + x]`.
///
/// One type for every kind of image keeps the crates' signatures uniform; the
/// aliases below name the instances.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane<T> {
    width: usize,
    height: usize,
    data: Vec<T>,
}

/// An 8-bit RGB image.
pub type RgbImage = Plane<Rgb>;
/// An 8-bit gray image.
pub type GrayImage = Plane<u8>;
/// A disparity map in pixels; `f32::INFINITY` marks invalid or unknown values.
pub type DisparityMap = Plane<f32>;
/// A label map: one class index per pixel.
pub type LabelMap = Plane<u16>;
/// A boolean mask (for example the non-occluded pixels of a scene).
pub type Mask = Plane<bool>;

/// The empty (0×0) plane, a buffer to fill with the `_into` functions.
impl<T> Default for Plane<T> {
    fn default() -> Self {
        Plane {
            width: 0,
            height: 0,
            data: Vec::new(),
        }
    }
}

impl<T: Copy> Plane<T> {
    /// A `width`×`height` plane filled with `value`.
    pub fn new(width: usize, height: usize, value: T) -> Self {
        Plane {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// A plane whose pixel `(x, y)` is `f(x, y)`.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> T) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Plane {
            width,
            height,
            data,
        }
    }

    /// Wraps row-major `data`; fails unless `data.len() == width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Result<Self> {
        if width.checked_mul(height) != Some(data.len()) {
            return Err(Error::InvalidParameter(format!(
                "{} pixels cannot form a {width}x{height} image",
                data.len()
            )));
        }
        Ok(Plane {
            width,
            height,
            data,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// `(width, height)`.
    pub fn dims(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// True for a plane without pixels.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// The pixel at `(x, y)`.
    ///
    /// # Panics
    /// If `(x, y)` is outside the plane.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> T {
        assert!(x < self.width, "x = {x} outside width {}", self.width);
        self.data[y * self.width + x]
    }

    /// Sets the pixel at `(x, y)`.
    ///
    /// # Panics
    /// If `(x, y)` is outside the plane.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, value: T) {
        assert!(x < self.width, "x = {x} outside width {}", self.width);
        self.data[y * self.width + x] = value;
    }

    /// Row `y` as a slice.
    #[inline]
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// Row `y` as a mutable slice.
    #[inline]
    pub fn row_mut(&mut self, y: usize) -> &mut [T] {
        &mut self.data[y * self.width..(y + 1) * self.width]
    }

    /// Iterates over the rows.
    pub fn rows(&self) -> std::slice::ChunksExact<'_, T> {
        self.data.chunks_exact(self.width.max(1))
    }

    /// All pixels, row-major.
    pub fn as_slice(&self) -> &[T] {
        &self.data
    }

    /// All pixels, row-major, mutable.
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// Consumes the plane, returning its row-major pixels.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// A new plane with `f` applied to every pixel.
    pub fn map<U: Copy>(&self, f: impl FnMut(T) -> U) -> Plane<U> {
        Plane {
            width: self.width,
            height: self.height,
            data: self.data.iter().copied().map(f).collect(),
        }
    }

    /// [`map`](Self::map) into `out`, which takes this plane's size and
    /// reuses its storage (no allocation once it is large enough).
    pub fn map_into<U: Copy>(&self, out: &mut Plane<U>, mut f: impl FnMut(T) -> U) {
        out.width = self.width;
        out.height = self.height;
        out.data.clear();
        out.data.extend(self.data.iter().map(|&v| f(v)));
    }

    /// Makes this a `width`×`height` plane filled with `value`, reusing the
    /// storage (no allocation once it is large enough).
    pub fn reset(&mut self, width: usize, height: usize, value: T) {
        self.width = width;
        self.height = height;
        if self.data.capacity() < width * height {
            // New storage: `vec!` takes zeroed memory from the allocator
            // for a zero value instead of filling it.
            self.data = vec![value; width * height];
        } else {
            self.data.clear();
            self.data.resize(width * height, value);
        }
    }

    /// Fails with [`Error::SizeMismatch`] unless `other` has the same size;
    /// `what` names `other` in the message.
    pub fn check_same_size<U>(&self, other: &Plane<U>, what: &str) -> Result<()> {
        if self.dims() == (other.width, other.height) {
            Ok(())
        } else {
            Err(Error::SizeMismatch {
                what: what.to_string(),
                expected_w: self.width,
                expected_h: self.height,
                found_w: other.width,
                found_h: other.height,
            })
        }
    }
}

/// A segmented image: a label per pixel and the colour of each label.
///
/// Invariant (checked by [`IndexedImage::new`]): every label indexes the palette.
#[derive(Clone, Debug, PartialEq)]
pub struct IndexedImage {
    labels: LabelMap,
    palette: Vec<Rgb>,
}

impl IndexedImage {
    /// Pairs `labels` with `palette`; fails if a label has no palette entry.
    pub fn new(labels: LabelMap, palette: Vec<Rgb>) -> Result<Self> {
        // The largest label first (a loop without an early exit, which
        // vectorises); the first bad one only to report it.
        let top = labels.as_slice().iter().fold(0, |m, &l| m.max(l));
        if labels.is_empty() || (top as usize) < palette.len() {
            return Ok(IndexedImage { labels, palette });
        }
        let bad = labels
            .as_slice()
            .iter()
            .find(|&&l| l as usize >= palette.len())
            .expect("the largest label is out of range");
        Err(Error::InvalidParameter(format!(
            "label {bad} has no colour in a palette of {}",
            palette.len()
        )))
    }

    /// The label map.
    pub fn labels(&self) -> &LabelMap {
        &self.labels
    }

    /// The palette: colour of each label.
    pub fn palette(&self) -> &[Rgb] {
        &self.palette
    }

    /// The RGB image the labels and palette describe.
    pub fn to_rgb(&self) -> RgbImage {
        self.labels.map(|l| self.palette[l as usize])
    }

    /// [`to_rgb`](Self::to_rgb) into `out` (resized, storage reused).
    pub fn to_rgb_into(&self, out: &mut RgbImage) {
        self.labels.map_into(out, |l| self.palette[l as usize]);
    }

    /// Splits into label map and palette.
    pub fn into_parts(self) -> (LabelMap, Vec<Rgb>) {
        (self.labels, self.palette)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_vec_checks_length() {
        assert!(Plane::from_vec(2, 2, vec![0u8; 3]).is_err());
        let p = Plane::from_vec(2, 2, vec![1u8, 2, 3, 4]).unwrap();
        assert_eq!(p.get(1, 1), 4);
        assert_eq!(p.row(1), &[3, 4]);
    }

    #[test]
    fn indexed_image_rejects_labels_without_colour() {
        let labels = Plane::from_vec(2, 1, vec![0u16, 2]).unwrap();
        assert!(IndexedImage::new(labels.clone(), vec![[0; 3]; 2]).is_err());
        let ok = IndexedImage::new(labels, vec![[0; 3], [1; 3], [9, 8, 7]]).unwrap();
        assert_eq!(ok.to_rgb().get(1, 0), [9, 8, 7]);
    }

    #[test]
    fn size_check_names_the_input() {
        let a = GrayImage::new(3, 2, 0);
        let b = GrayImage::new(2, 2, 0);
        let msg = a.check_same_size(&b, "right view").unwrap_err().to_string();
        assert!(
            msg.contains("right view") && msg.contains("2x2") && msg.contains("3x2"),
            "{msg}"
        );
    }
}
