//! What the receiver shows: a 3-D view of the rebuilt pair (anaglyphs or
//! side-by-side, the paper's "concatenation"), the disparity map with a
//! colour bar, and a status line, laid out on the board's 480x272 TFT; and
//! where it shows it: the Linux framebuffer, PNG snapshots, or a local web
//! viewer.

pub mod anaglyph;
pub mod font;
pub mod screen;
pub mod sinks;
pub mod web;

pub use anaglyph::{
    anaglyph, anaglyph_into, anaglyph_labels_into, anaglyph_labels_shown_into, side_by_side,
    Anaglyph,
};
pub use screen::{Screen, ScreenStatus, SCREEN_HEIGHT, SCREEN_WIDTH};
pub use sinks::{open_sink, FramebufferSink, PixelFormat, PngSink, Sink};
