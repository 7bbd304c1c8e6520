//! The receiver's linear axis: it moves "exactly the calculated distance".
//!
//! * [`policy`] turns a validated depth report into a target position
//!   (distance minus a stand-off, clamped to soft limits, at a bounded
//!   speed) and holds the watchdog that stops the axis when reports stop.
//! * [`Axis`] is what a driver offers; [`grbl::GrblAxis`] drives a GRBL
//!   controller over a serial port, [`sim::SimAxis`] simulates a DC motor
//!   with an encoder and a PID position loop.
//!
//! This crate knows nothing of images: distances come in metres.

pub mod grbl;
pub mod policy;
pub mod sim;

/// Errors of the axis drivers.
#[derive(Debug, thiserror::Error)]
pub enum AxisError {
    /// The port failed.
    #[error("axis port: {0}")]
    Io(std::io::Error),
    /// GRBL answered `error:N`.
    #[error("GRBL error:{0}")]
    Grbl(u32),
    /// GRBL raised `ALARM:N`; the axis must be unlocked by the operator.
    #[error("GRBL ALARM:{0}: the axis is locked; check it and unlock ($X)")]
    Alarm(u32),
    /// No answer in time.
    #[error("axis did not answer {0} in time")]
    Timeout(&'static str),
    /// An unexpected answer.
    #[error("unexpected answer from the axis: {0}")]
    Protocol(String),
}

impl From<std::io::Error> for AxisError {
    fn from(e: std::io::Error) -> Self {
        AxisError::Io(e)
    }
}

/// A linear axis, positions in millimetres from its home.
pub trait Axis: Send {
    /// Starts moving to `position_mm` at `speed_mm_s` (returns at once; a new
    /// call retargets a move in progress).
    fn move_to(&mut self, position_mm: f64, speed_mm_s: f64) -> Result<(), AxisError>;
    /// Current position.
    fn position(&mut self) -> Result<f64, AxisError>;
    /// True while moving.
    fn is_moving(&mut self) -> Result<bool, AxisError>;
    /// Stops at once (feed hold).
    fn stop(&mut self) -> Result<(), AxisError>;
    /// A short description.
    fn describe(&self) -> String;
}

/// Polls `axis` until it is idle (at most `max_polls` times; a GRBL poll is a
/// serial round trip, a simulated one advances 10 ms) and returns its
/// position, or `None` if it was still moving.
pub fn wait_until_idle(axis: &mut dyn Axis, max_polls: usize) -> Result<Option<f64>, AxisError> {
    for _ in 0..max_polls {
        if !axis.is_moving()? {
            return axis.position().map(Some);
        }
    }
    Ok(None)
}

/// Opens an axis from its spec: `sim` or `grbl:/dev/ttyACM0[?baud=115200]`.
pub fn open_axis(spec: &str) -> Result<Box<dyn Axis>, AxisError> {
    if spec == "sim" {
        return Ok(Box::new(sim::SimAxis::new(sim::MotorParams::default())));
    }
    let Some(rest) = spec.strip_prefix("grbl:") else {
        return Err(AxisError::Protocol(format!(
            "axis {spec:?}: use sim or grbl:/dev/ttyACM0"
        )));
    };
    let (path, query) = rest.split_once('?').unwrap_or((rest, ""));
    let baud = query
        .strip_prefix("baud=")
        .map(|b| {
            b.parse()
                .map_err(|_| AxisError::Protocol(format!("baud={b} is not a number")))
        })
        .transpose()?
        .unwrap_or(115_200);
    let port = serialport::new(path, baud)
        .timeout(std::time::Duration::from_millis(20))
        .open()
        .map_err(|e| {
            AxisError::Io(std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("cannot open {path}: {e}"),
            ))
        })?;
    Ok(Box::new(grbl::GrblAxis::new(port, path)?))
}
