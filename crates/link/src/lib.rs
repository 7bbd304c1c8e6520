//! The radio link: XBee API frames, AT-mode framing, fragmentation and
//! selective-repeat ARQ in a `no_std` + `alloc` core; serial, UDP and
//! simulated 802.15.4 transports and fallback under the `std` feature.
//!
//! # Layers (sender to receiver)
//!
//! 1. **Radio frame** ([`xbee`], [`slip`]): XBee API frames (modes 1 and 2) or,
//!    in transparent mode, SLIP frames with a CRC-16; [`radio`] asks the local
//!    radio its firmware and payload size and picks the transmit request;
//!    [`pacing`] keeps a few requests at the radio, paced by their status.
//! 2. **Link segment** ([`arq`], wire version 3): DATA fragments (sender
//!    session, message id, index, and a mark on the last fragment, from
//!    which the receiver learns the count), cumulative + bitmap ACKs naming
//!    both sessions and the count, FAIL. ACK and FAIL carry a CRC-16; DATA
//!    carries none, as every transport below checks each frame and the
//!    message's CRC-32 covers its bytes.
//! 3. **Session and message**: a random session per endpoint start (and, with
//!    keys, per handshake), so a restarted peer is never mistaken for the old
//!    one; the message, sealed by [`secure`] when keys are set, followed by
//!    its CRC-32 end to end.
//!
//! The ARQ machines do no I/O and read no clock; [`endpoint`] drives them over
//! a [`transport::Transport`] with a real clock, and [`sim`] drives them in
//! simulated time for tests and the loss sweep.

#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![deny(unsafe_code)]

extern crate alloc;

pub mod arq;
pub mod crc;
pub mod pacing;
pub mod secure;
pub mod slip;
pub mod xbee;

#[cfg(feature = "std")]
pub mod bond;
#[cfg(feature = "std")]
pub mod endpoint;
#[cfg(feature = "std")]
pub mod radio;
#[cfg(feature = "std")]
pub mod serial;
#[cfg(feature = "std")]
pub mod sim;
#[cfg(feature = "std")]
pub mod spec;
#[cfg(feature = "std")]
pub mod throughput;
#[cfg(feature = "std")]
pub mod transport;
