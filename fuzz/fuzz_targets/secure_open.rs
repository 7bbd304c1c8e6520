//! The secure layer's parser and handshake fed arbitrary messages from a
//! few sessions (see `stereolink_link::secure::fuzz`): no panic, nothing
//! opens that was not sealed by the peer, nothing opens twice.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| stereolink_link::secure::fuzz::drive(data));
