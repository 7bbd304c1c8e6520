//! stereolink-codec (in progress).
