//! A GRBL controller over a serial port (GRBL 1.1 protocol).
//!
//! Moves are relative in millimetres: `G21` (mm) and `G91` (relative) once,
//! then `G1 X<delta> F<mm/min>` per move; every line waits for `ok`, and
//! `error:N` / `ALARM:N` become errors. `?` polls the status report
//! (`<Idle|MPos:x,y,z|…>`), and `!` (feed hold) stops the axis at once.

use std::io::{BufRead, BufReader, Read, Write};
use std::time::{Duration, Instant};

use crate::{Axis, AxisError};

/// Machine state from a status report.
#[derive(Clone, Debug, PartialEq)]
pub struct Status {
    /// `Idle`, `Run`, `Hold:0`, `Alarm`, …
    pub state: String,
    /// Machine X position, mm.
    pub x_mm: f64,
}

/// Parses `<Idle|MPos:1.000,0.000,0.000|FS:0,0>` (also `WPos`).
pub fn parse_status(line: &str) -> Option<Status> {
    let body = line.trim().strip_prefix('<')?.strip_suffix('>')?;
    let mut parts = body.split('|');
    let state = parts.next()?.to_string();
    let x_mm = parts
        .find_map(|p| p.strip_prefix("MPos:").or_else(|| p.strip_prefix("WPos:")))?
        .split(',')
        .next()?
        .parse()
        .ok()?;
    Some(Status { state, x_mm })
}

/// A GRBL-driven axis.
pub struct GrblAxis<P: Read + Write + Send> {
    port: BufReader<P>,
    name: String,
    timeout: Duration,
}

impl<P: Read + Write + Send> GrblAxis<P> {
    /// Wakes the controller and sets millimetres and relative moves.
    pub fn new(port: P, name: &str) -> Result<Self, AxisError> {
        let mut axis = GrblAxis {
            port: BufReader::new(port),
            name: name.to_string(),
            timeout: Duration::from_secs(5),
        };
        axis.port.get_mut().write_all(b"\r\n")?;
        axis.command("G21")?;
        axis.command("G91")?;
        Ok(axis)
    }

    fn read_line(&mut self, deadline: Instant) -> Result<String, AxisError> {
        let mut line = String::new();
        loop {
            match self.port.read_line(&mut line) {
                Ok(_) if line.ends_with('\n') => return Ok(line.trim().to_string()),
                Ok(_) => {}
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock
                    ) => {}
                Err(e) => return Err(e.into()),
            }
            if line.len() > 256 {
                return Err(AxisError::Protocol("overlong line".into()));
            }
            if Instant::now() > deadline {
                return Err(AxisError::Timeout("a command"));
            }
        }
    }

    /// Sends one line and waits for `ok`.
    pub fn command(&mut self, line: &str) -> Result<(), AxisError> {
        self.port
            .get_mut()
            .write_all(format!("{line}\n").as_bytes())?;
        let deadline = Instant::now() + self.timeout;
        loop {
            let reply = self.read_line(deadline)?;
            if reply == "ok" {
                return Ok(());
            }
            if let Some(n) = reply.strip_prefix("error:") {
                return Err(AxisError::Grbl(n.trim().parse().unwrap_or(0)));
            }
            if let Some(n) = reply.strip_prefix("ALARM:") {
                return Err(AxisError::Alarm(n.trim().parse().unwrap_or(0)));
            }
            // Status reports, welcome banners and [MSG:…] lines are not answers.
        }
    }

    /// Polls the status report.
    pub fn status(&mut self) -> Result<Status, AxisError> {
        self.port.get_mut().write_all(b"?")?;
        let deadline = Instant::now() + self.timeout;
        loop {
            let reply = self.read_line(deadline)?;
            if let Some(s) = parse_status(&reply) {
                return Ok(s);
            }
            if let Some(n) = reply.strip_prefix("ALARM:") {
                return Err(AxisError::Alarm(n.trim().parse().unwrap_or(0)));
            }
        }
    }
}

impl<P: Read + Write + Send> Axis for GrblAxis<P> {
    fn move_to(&mut self, position_mm: f64, speed_mm_s: f64) -> Result<(), AxisError> {
        let here = self.status()?.x_mm;
        let delta = position_mm - here;
        if delta.abs() < 1e-3 {
            return Ok(());
        }
        self.command(&format!("G1 X{delta:.3} F{:.0}", speed_mm_s * 60.0))
    }

    fn position(&mut self) -> Result<f64, AxisError> {
        Ok(self.status()?.x_mm)
    }

    fn is_moving(&mut self) -> Result<bool, AxisError> {
        Ok(self.status()?.state.starts_with("Run"))
    }

    fn stop(&mut self) -> Result<(), AxisError> {
        self.port.get_mut().write_all(b"!")?;
        Ok(())
    }

    fn describe(&self) -> String {
        format!("GRBL on {}", self.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serialport::{SerialPort, TTYPort};

    #[test]
    fn parses_status_reports() {
        let s = parse_status("<Run|MPos:12.500,0.000,0.000|FS:500,0>").unwrap();
        assert_eq!((s.state.as_str(), s.x_mm), ("Run", 12.5));
        assert!(parse_status("ok").is_none());
    }

    /// A fake GRBL on the other end of a pty pair: it tracks G91 moves,
    /// answers `?`, rejects an unknown command with error:20 and raises an
    /// alarm past +800 mm.
    fn fake_grbl(mut port: TTYPort) -> std::thread::JoinHandle<Vec<String>> {
        std::thread::spawn(move || {
            let mut seen = Vec::new();
            let mut x = 0.0f64;
            let mut line = String::new();
            let mut buf = [0u8; 64];
            let deadline = Instant::now() + Duration::from_secs(10);
            while Instant::now() < deadline {
                let Ok(n) = port.read(&mut buf) else { continue };
                for &b in &buf[..n] {
                    match b {
                        b'?' => port
                            .write_all(
                                format!("<Idle|MPos:{x:.3},0.000,0.000|FS:0,0>\r\n").as_bytes(),
                            )
                            .unwrap(),
                        b'!' => seen.push("!".into()),
                        b'\n' => {
                            let cmd = line.trim().to_string();
                            line.clear();
                            if cmd.is_empty() {
                                continue;
                            }
                            let reply = if cmd == "G21" || cmd == "G91" {
                                "ok".to_string()
                            } else if let Some(rest) = cmd.strip_prefix("G1 X") {
                                let d: f64 =
                                    rest.split_whitespace().next().unwrap().parse().unwrap();
                                if x + d > 800.0 {
                                    "ALARM:2".into()
                                } else {
                                    x += d;
                                    "ok".into()
                                }
                            } else if cmd == "QUIT" {
                                return seen;
                            } else {
                                "error:20".into()
                            };
                            seen.push(cmd);
                            port.write_all(format!("{reply}\r\n").as_bytes()).unwrap();
                        }
                        b'\r' => {}
                        _ => line.push(b as char),
                    }
                }
            }
            seen
        })
    }

    #[test]
    fn drives_a_fake_grbl_over_a_pty() {
        let (mut a, mut b) = TTYPort::pair().unwrap();
        a.set_timeout(Duration::from_millis(10)).unwrap();
        b.set_timeout(Duration::from_millis(10)).unwrap();
        let grbl = fake_grbl(b);
        let mut axis = GrblAxis::new(a, "pty").unwrap();
        axis.move_to(250.0, 40.0).unwrap();
        assert!((axis.position().unwrap() - 250.0).abs() < 1e-6);
        axis.move_to(100.0, 40.0).unwrap();
        assert!((axis.position().unwrap() - 100.0).abs() < 1e-6);
        assert!(matches!(axis.command("M999"), Err(AxisError::Grbl(20))));
        assert!(matches!(
            axis.move_to(900.0, 40.0),
            Err(AxisError::Alarm(2))
        ));
        axis.stop().unwrap();
        axis.command("QUIT").ok();
        let seen = grbl.join().unwrap();
        assert_eq!(
            &seen[..4],
            &["G21", "G91", "G1 X250.000 F2400", "G1 X-150.000 F2400"]
        );
        assert!(seen.contains(&"!".to_string()));
    }
}
