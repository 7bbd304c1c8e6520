//! The board's receiver on its links: the next message from whichever link
//! has one (the frames' link and a separate report link, or a bond), and
//! the line its screen shows about their security.

use std::time::{Duration, Instant};

use stereolink_link::endpoint::{Endpoint, LinkError};
use stereolink_link::secure::Rejections;

/// The next message from any of the links, waiting up to `timeout`.
pub fn next_message(eps: &mut [Endpoint], timeout: Duration) -> Result<Vec<u8>, LinkError> {
    let until = Instant::now() + timeout;
    let slice = Duration::from_millis(20) / eps.len().max(1) as u32;
    loop {
        for ep in eps.iter_mut() {
            match ep.recv_message(slice) {
                Err(LinkError::Timeout) => {}
                other => return other,
            }
        }
        if Instant::now() >= until {
            return Err(LinkError::Timeout);
        }
    }
}

/// The screen's security note: sealed or not, and the refusals by cause
/// over all the links.
pub fn security_line(eps: &[Endpoint]) -> String {
    let all: Option<Vec<Rejections>> = eps.iter().map(Endpoint::rejections).collect();
    match all {
        Some(r) => {
            let sum = |f: fn(&Rejections) -> u64| r.iter().map(f).sum::<u64>();
            format!(
                "SEALED  REJ TAG {} RPL {} SES {} HS {}",
                sum(|r| r.bad_tag),
                sum(|r| r.replay),
                sum(|r| r.unknown_session),
                sum(|r| r.handshake)
            )
        }
        None => "INSECURE".into(),
    }
}
