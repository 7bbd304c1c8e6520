//! stereolink-link (in progress).
