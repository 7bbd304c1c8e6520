//! stereolink-robot (in progress).
