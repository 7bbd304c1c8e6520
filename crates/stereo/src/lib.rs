//! stereolink-stereo (in progress).
