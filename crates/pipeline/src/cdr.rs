//! A CDR writer for ROS 2 messages: XCDR1, little endian, as ROS 2's
//! middlewares put messages on the wire and rosbag2 stores them. The
//! buffer opens with the encapsulation header `00 01 00 00` (CDR_LE); each
//! primitive is aligned to its own size (at most 8) counted from after
//! that header; a string is its `u32` length with the NUL, its bytes and
//! the NUL; a sequence is its `u32` count and its elements; a fixed array
//! is its elements alone.
//!
//! Written by hand: the recordings ([`crate::record`]) write seven fixed
//! message types, and the serde-based CDR crates would write an image's
//! `uint8[]` one element at a time and need a serde struct per message;
//! this is a few lines, tested against bytes derived from the rules above.

/// A ROS 2 message being encoded.
pub struct Cdr {
    buf: Vec<u8>,
}

/// The encapsulation header's length: alignment counts from after it.
const HEADER: usize = 4;

impl Cdr {
    /// An empty message (its encapsulation header only), with room for
    /// `capacity` bytes more.
    pub fn new(capacity: usize) -> Cdr {
        let mut buf = Vec::with_capacity(HEADER + capacity);
        buf.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        Cdr { buf }
    }

    /// The encoded message.
    pub fn into_bytes(self) -> Vec<u8> {
        self.buf
    }

    fn align(&mut self, n: usize) {
        let pad = (n - (self.buf.len() - HEADER) % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    /// A `uint8`, `byte` or `char`.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// A `bool`.
    pub fn bool(&mut self, v: bool) {
        self.u8(u8::from(v));
    }

    /// A `uint16`.
    pub fn u16(&mut self, v: u16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A `uint32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// An `int32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A `float32`.
    pub fn f32(&mut self, v: f32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A `float64`.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A `string` (a NUL inside would end it for a reader: none is written
    /// by the recordings).
    pub fn string(&mut self, s: &str) {
        self.len(s.len() + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    /// A sequence's count (its elements follow, each written by the caller).
    pub fn len(&mut self, n: usize) {
        // A message never holds 4 G elements: the recordings' images are
        // bounded by the codec's limits.
        self.u32(u32::try_from(n).unwrap_or(u32::MAX));
    }

    /// A `uint8[]`, its count and its bytes.
    pub fn bytes(&mut self, data: &[u8]) {
        self.len(data.len());
        self.buf.extend_from_slice(data);
    }

    /// A sequence of bytes written by `fill` into the room for `n` bytes
    /// (an image row by row, without a copy of the whole first).
    pub fn bytes_with(&mut self, n: usize, fill: impl FnOnce(&mut Vec<u8>)) {
        self.len(n);
        let start = self.buf.len();
        self.buf.reserve(n);
        fill(&mut self.buf);
        debug_assert_eq!(self.buf.len() - start, n);
    }

    /// A `float64[N]` or the elements of a `float64[]`.
    pub fn f64s(&mut self, v: &[f64]) {
        for &x in v {
            self.f64(x);
        }
    }

    /// A `builtin_interfaces/Time` from µs since the epoch.
    pub fn time(&mut self, stamp_us: u64) {
        let sec = i32::try_from(stamp_us / 1_000_000).unwrap_or(i32::MAX);
        self.i32(sec);
        self.u32((stamp_us % 1_000_000) as u32 * 1000);
    }

    /// A `std_msgs/Header`.
    pub fn header(&mut self, stamp_us: u64, frame_id: &str) {
        self.time(stamp_us);
        self.string(frame_id);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `std_msgs/Header` of 1.5 s and frame `ab`: sec and nanosec, then
    /// the string's length 3 (with the NUL), `a`, `b`, NUL.
    #[test]
    fn header_bytes() {
        let mut c = Cdr::new(0);
        c.header(1_500_000, "ab");
        #[rustfmt::skip]
        let want = [
            0x00, 0x01, 0x00, 0x00, // CDR_LE
            0x01, 0x00, 0x00, 0x00, // sec 1
            0x00, 0x65, 0xcd, 0x1d, // nanosec 500 000 000 = 0x1dcd6500
            0x03, 0x00, 0x00, 0x00, b'a', b'b', 0x00,
        ];
        assert_eq!(c.into_bytes(), want);
    }

    /// Alignment counts from after the encapsulation header: a `uint8`
    /// then a `float64` pads 7 bytes, a `uint16` after a `uint8` pads 1.
    #[test]
    fn alignment_is_relative_to_the_body() {
        let mut c = Cdr::new(0);
        c.u8(7);
        c.f64(1.0);
        c.u8(1);
        c.u16(0x0203);
        c.bool(true);
        c.f32(2.0);
        #[rustfmt::skip]
        let want = [
            0x00, 0x01, 0x00, 0x00,
            0x07, 0, 0, 0, 0, 0, 0, 0,
            0, 0, 0, 0, 0, 0, 0xf0, 0x3f, // 1.0
            0x01, 0x00, 0x03, 0x02,        // u8, pad, u16
            0x01, 0, 0, 0,                 // bool, pad to 4
            0, 0, 0, 0x40,                 // 2.0f32
        ];
        assert_eq!(c.into_bytes(), want);
    }

    /// A 2x1 `mono8` `sensor_msgs/Image` stamped 0, frame `c`, derived by
    /// hand: header, height 1, width 2, encoding `mono8`, is_bigendian 0,
    /// step 2 (aligned to 4 after the byte), data count 2 and the two bytes.
    #[test]
    fn tiny_image_bytes() {
        let mut c = Cdr::new(0);
        c.header(0, "c");
        c.u32(1);
        c.u32(2);
        c.string("mono8");
        c.u8(0);
        c.u32(2);
        c.bytes(&[9, 8]);
        #[rustfmt::skip]
        let want = [
            0x00, 0x01, 0x00, 0x00,
            0, 0, 0, 0, 0, 0, 0, 0,          // stamp
            2, 0, 0, 0, b'c', 0,             // frame_id
            0, 0,                            // pad to 4
            1, 0, 0, 0, 2, 0, 0, 0,          // height, width
            6, 0, 0, 0, b'm', b'o', b'n', b'o', b'8', 0,
            0,                               // is_bigendian (body offset 34)
            0,                               // pad to 36
            2, 0, 0, 0,                      // step
            2, 0, 0, 0, 9, 8,                // data
        ];
        assert_eq!(c.into_bytes(), want);
    }

    #[test]
    fn bytes_with_writes_in_place() {
        let mut a = Cdr::new(0);
        a.u8(1);
        a.bytes(&[1, 2, 3]);
        let mut b = Cdr::new(0);
        b.u8(1);
        b.bytes_with(3, |buf| buf.extend_from_slice(&[1, 2, 3]));
        assert_eq!(a.into_bytes(), b.into_bytes());
    }
}
