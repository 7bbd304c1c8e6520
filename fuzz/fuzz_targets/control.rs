//! The Control body ([`stereolink_codec::control`]): the commands and
//! replies that come up and down the link. Any bytes read to a Control or a
//! typed error, never a panic, and what reads re-encodes to the same bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use stereolink_codec::control::Control;

fuzz_target!(|data: &[u8]| {
    if let Ok(control) = Control::decode(data) {
        let again = control.encode();
        assert_eq!(again, data, "{control:?} re-encodes to other bytes");
        assert_eq!(Control::decode(&again).as_ref().ok(), Some(&control));
    }
});
