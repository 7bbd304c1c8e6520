//! A simulated DC-motor linear axis: a motor with inertia, viscous and
//! Coulomb friction driving a lead screw, a quadrature encoder, and a PID
//! position loop following a speed-limited setpoint, integrated with a fixed
//! 0.5 ms step.
//!
//! `J·dω/dt = k_t·i − b·ω − τ_c·sign(ω)`, `i = u / R` (inductance neglected),
//! `u = clamp(PID(x_set − x_enc), ±V_max)`; the encoder counts
//! `4·CPR` edges per revolution, and the position is `counts / (4·CPR) · pitch`.

use crate::{Axis, AxisError};

/// Motor, screw and controller constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorParams {
    /// Rotor and load inertia, kg·m².
    pub inertia: f64,
    /// Torque constant, N·m/A.
    pub kt: f64,
    /// Winding resistance, Ω.
    pub resistance: f64,
    /// Viscous friction, N·m·s/rad.
    pub viscous: f64,
    /// Coulomb friction, N·m.
    pub coulomb: f64,
    /// Supply voltage limit, V.
    pub v_max: f64,
    /// Encoder lines per revolution (×4 in quadrature).
    pub cpr: u32,
    /// Lead-screw pitch, mm per revolution.
    pub pitch_mm: f64,
    /// PID gains on position error in mm → volts.
    pub kp: f64,
    /// Integral gain.
    pub ki: f64,
    /// Derivative gain.
    pub kd: f64,
}

impl Default for MotorParams {
    fn default() -> Self {
        MotorParams {
            inertia: 2e-5,
            kt: 0.05,
            resistance: 2.0,
            viscous: 1e-4,
            coulomb: 4e-3,
            v_max: 12.0,
            cpr: 500,
            pitch_mm: 4.0,
            kp: 4.0,
            ki: 2.0,
            kd: 0.08,
        }
    }
}

const DT: f64 = 0.0005;

/// The simulated axis; time advances when [`SimAxis::step_for`] is called or
/// through the [`Axis`] queries (each advances 10 ms, as a control tick).
pub struct SimAxis {
    p: MotorParams,
    theta: f64,
    omega: f64,
    setpoint: f64,
    target: f64,
    speed: f64,
    integral: f64,
    last_error: f64,
    time: f64,
}

impl SimAxis {
    /// An axis at home, at rest.
    pub fn new(p: MotorParams) -> Self {
        SimAxis {
            p,
            theta: 0.0,
            omega: 0.0,
            setpoint: 0.0,
            target: 0.0,
            speed: 0.0,
            integral: 0.0,
            last_error: 0.0,
            time: 0.0,
        }
    }

    /// Encoder reading in quadrature counts.
    pub fn encoder_counts(&self) -> i64 {
        (self.theta / std::f64::consts::TAU * 4.0 * self.p.cpr as f64).floor() as i64
    }

    fn encoder_mm(&self) -> f64 {
        self.encoder_counts() as f64 / (4.0 * self.p.cpr as f64) * self.p.pitch_mm
    }

    /// Simulated time, seconds.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Advances the simulation by `seconds`.
    pub fn step_for(&mut self, seconds: f64) {
        let steps = (seconds / DT).round() as usize;
        for _ in 0..steps {
            // Speed-limited setpoint.
            let d = self.target - self.setpoint;
            let max_step = self.speed * DT;
            self.setpoint += d.clamp(-max_step, max_step);
            // PID on the encoder position.
            let error = self.setpoint - self.encoder_mm();
            self.integral = (self.integral + error * DT).clamp(-2.0, 2.0);
            let derivative = (error - self.last_error) / DT;
            self.last_error = error;
            let u = (self.p.kp * error + self.p.ki * self.integral + self.p.kd * derivative)
                .clamp(-self.p.v_max, self.p.v_max);
            // Motor dynamics (back-EMF included: i = (u − k_t ω) / R).
            let current = (u - self.p.kt * self.omega) / self.p.resistance;
            let drive = self.p.kt * current - self.p.viscous * self.omega;
            let friction = if self.omega.abs() > 1e-6 {
                self.p.coulomb * self.omega.signum()
            } else {
                drive.clamp(-self.p.coulomb, self.p.coulomb) // static friction holds up to τ_c
            };
            let torque = drive - friction;
            self.omega += torque / self.p.inertia * DT;
            self.theta += self.omega * DT;
            self.time += DT;
        }
    }

    /// Runs until the axis has settled near its target or `max_seconds` passed;
    /// returns the final position (mm).
    pub fn settle(&mut self, max_seconds: f64) -> f64 {
        let start = self.time;
        while self.time - start < max_seconds {
            self.step_for(0.05);
            if (self.setpoint - self.target).abs() < 1e-9
                && self.omega.abs() < 0.05
                && (self.encoder_mm() - self.target).abs() < 0.05
            {
                break;
            }
        }
        self.encoder_mm()
    }
}

impl Axis for SimAxis {
    fn move_to(&mut self, position_mm: f64, speed_mm_s: f64) -> Result<(), AxisError> {
        self.target = position_mm;
        self.speed = speed_mm_s.max(0.1);
        Ok(())
    }

    fn position(&mut self) -> Result<f64, AxisError> {
        self.step_for(0.01);
        Ok(self.encoder_mm())
    }

    /// Moving until the setpoint has arrived and the encoder is within
    /// 0.05 mm of it, at rest (GRBL's "Idle" after a move).
    fn is_moving(&mut self) -> Result<bool, AxisError> {
        self.step_for(0.01);
        Ok((self.setpoint - self.target).abs() > 1e-9
            || self.omega.abs() > 0.05
            || (self.encoder_mm() - self.target).abs() > 0.05)
    }

    fn stop(&mut self) -> Result<(), AxisError> {
        self.target = self.encoder_mm();
        self.setpoint = self.target;
        Ok(())
    }

    fn describe(&self) -> String {
        "simulated DC-motor axis".into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ends_within_half_a_millimetre_of_the_command() {
        for target in [12.5, 150.0, 487.3] {
            let mut axis = SimAxis::new(MotorParams::default());
            axis.move_to(target, 50.0).unwrap();
            let end = axis.settle(60.0);
            assert!((end - target).abs() <= 0.5, "{target}: ended at {end}");
            // The speed limit holds: the move took at least distance / speed.
            assert!(axis.time() >= target / 50.0 * 0.95, "{}", axis.time());
        }
    }

    #[test]
    fn retargets_while_moving_and_stops() {
        let mut axis = SimAxis::new(MotorParams::default());
        axis.move_to(300.0, 50.0).unwrap();
        axis.step_for(1.0);
        axis.move_to(100.0, 50.0).unwrap();
        let end = axis.settle(30.0);
        assert!((end - 100.0).abs() <= 0.5, "{end}");
        axis.move_to(200.0, 50.0).unwrap();
        axis.step_for(0.5);
        axis.stop().unwrap();
        let held = axis.position().unwrap();
        axis.step_for(2.0);
        assert!((axis.position().unwrap() - held).abs() < 2.0);
    }
}
