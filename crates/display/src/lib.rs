//! stereolink-display (in progress).
