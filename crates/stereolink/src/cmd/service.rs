//! Readiness and liveness for systemd: a unit of `Type=notify` learns that
//! the command is ready (its links, display and axis open) and, with
//! `WatchdogSec=`, that its loop still turns; a loop that hangs is
//! restarted by systemd. Outside systemd (no `NOTIFY_SOCKET`) both are
//! no-ops. The unit files are in `deploy/systemd/`.

use std::time::{Duration, Instant};

use sd_notify::NotifyState;

/// The pings of one running command.
pub struct Service {
    /// How often to say the loop turns: half of systemd's watchdog
    /// period, when it has one.
    every: Option<Duration>,
    last: Option<Instant>,
}

impl Service {
    /// Reads systemd's watchdog period from the environment.
    pub fn new() -> Service {
        let mut usec = 0;
        let every =
            sd_notify::watchdog_enabled(false, &mut usec).then(|| Duration::from_micros(usec) / 2);
        Service { every, last: None }
    }

    /// Tells systemd the command is ready, with `status` as its status line.
    pub fn ready(&mut self, status: &str) {
        self.notify(&[NotifyState::Ready, NotifyState::Status(status)]);
        self.last = Some(Instant::now());
    }

    /// Tells systemd's watchdog the loop turns (at most every half period).
    pub fn alive(&mut self) {
        let Some(every) = self.every else {
            return;
        };
        if self.last.is_some_and(|t| t.elapsed() < every) {
            return;
        }
        self.notify(&[NotifyState::Watchdog]);
        self.last = Some(Instant::now());
    }

    /// Tells systemd the command is stopping.
    pub fn stopping(&mut self) {
        self.notify(&[NotifyState::Stopping]);
    }

    fn notify(&self, states: &[NotifyState]) {
        if let Err(e) = sd_notify::notify(false, states) {
            eprintln!("systemd: cannot notify: {e}");
        }
    }
}

impl Default for Service {
    fn default() -> Self {
        Service::new()
    }
}
