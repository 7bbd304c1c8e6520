//! stereolink-segment (in progress).
