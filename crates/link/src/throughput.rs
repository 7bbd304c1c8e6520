//! What the radios carry: Digi's measured data throughput for each firmware,
//! by hops, security and the roles of the two ends, and the air time a
//! packet takes that follows from it.
//!
//! The simulated channel ([`crate::sim`]), the ARQ's first retransmission
//! timeout and the test emulator all take their pace from [`RadioPath`], so
//! that a model carries what the radio it names carries. Digi measured each
//! figure at 115200 baud by timing 100 000 bytes from source to destination,
//! with no route discovery or failure during the test:
//!
//! * XBee/XBee-PRO ZB RF Modules user guide, "Throughput": 1 hop router to
//!   router 35 kb/s (19 with security enabled), router to end device 25
//!   (16), end device to router 21 (16); 4 hops router to router 10 (5).
//! * XBee/XBee-PRO DigiMesh 2.4 user guide, "DigiMesh throughput": 1 hop
//!   27.0 kb/s (20.5 with encryption), 3 hops 10.9 (9.81), 6 hops 5.78
//!   (4.70).
//! * XBee 802.15.4 has no mesh, so no hops. Digi's knowledge base gives about
//!   80 kb/s for a file transfer (Zmodem); the channel's own UART and air
//!   model ([`crate::sim`]) gives that already, so it is not paced here.
//!
//! Between the measured hop counts the time per bit is interpolated
//! linearly (each hop adds the air time of one more transmission), and past
//! the last one extrapolated with the last step. An end device's penalty
//! applies to its one hop, so it is added to the router path's time per bit.

use crate::radio::Firmware;

/// The roles of the sending and receiving radio (ZigBee only; DigiMesh and
/// 802.15.4 nodes are all alike).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Role {
    /// Router to router (or coordinator): the manuals' best case.
    #[default]
    RouterToRouter,
    /// A router sending to a non-sleeping end device.
    RouterToEndDevice,
    /// A non-sleeping end device sending to its parent router.
    EndDeviceToRouter,
}

impl std::str::FromStr for Role {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "rr" | "router" => Ok(Role::RouterToRouter),
            "re" => Ok(Role::RouterToEndDevice),
            "er" => Ok(Role::EndDeviceToRouter),
            _ => Err(format!(
                "role={s}: expected rr (router to router), re (router to end device) or er (end device to router)"
            )),
        }
    }
}

/// The path a packet takes between two radios.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RadioPath {
    /// The radios' firmware.
    pub firmware: Firmware,
    /// Radio hops from source to destination (1: in range of each other).
    pub hops: u8,
    /// Network security (ZigBee `EE=1`, DigiMesh `EE=1`) enabled.
    pub encrypted: bool,
    /// The two ends' roles (ZigBee).
    pub role: Role,
}

/// Measured points (hops, kb/s) for one firmware and security setting,
/// ascending in hops.
type Points = &'static [(u8, f64)];

const ZIGBEE: Points = &[(1, 35.0), (4, 10.0)];
const ZIGBEE_SECURE: Points = &[(1, 19.0), (4, 5.0)];
const DIGIMESH: Points = &[(1, 27.0), (3, 10.9), (6, 5.78)];
const DIGIMESH_SECURE: Points = &[(1, 20.5), (3, 9.81), (6, 4.70)];

/// The most hops a path may have: ZigBee's and DigiMesh's network hop limits
/// (`NH`) stay below this.
pub const MAX_HOPS: u8 = 32;

impl RadioPath {
    /// One hop between two routers, no security: the manuals' first row.
    pub fn direct(firmware: Firmware) -> Self {
        RadioPath {
            firmware,
            hops: 1,
            encrypted: false,
            role: Role::RouterToRouter,
        }
    }

    /// Checks the path against what its firmware can do.
    pub fn validate(&self) -> Result<(), String> {
        if self.hops == 0 || self.hops > MAX_HOPS {
            return Err(format!("hops={}: expected 1 to {MAX_HOPS}", self.hops));
        }
        match self.firmware {
            Firmware::Ieee802154 if self.hops > 1 => Err(format!(
                "hops={}: XBee 802.15.4 has no mesh; only one hop",
                self.hops
            )),
            Firmware::Ieee802154 | Firmware::DigiMesh if self.role != Role::RouterToRouter => {
                Err(format!(
                    "role: end devices are a ZigBee notion, not {}",
                    self.firmware
                ))
            }
            _ => Ok(()),
        }
    }

    /// Digi's measured data throughput on this path, bits per second, or
    /// `None` for 802.15.4 (its UART and air bound it; see the module doc).
    pub fn measured_bps(&self) -> Option<f64> {
        let points = match (self.firmware, self.encrypted) {
            (Firmware::Ieee802154, _) => return None,
            (Firmware::Zigbee, false) => ZIGBEE,
            (Firmware::Zigbee, true) => ZIGBEE_SECURE,
            (Firmware::DigiMesh, false) => DIGIMESH,
            (Firmware::DigiMesh, true) => DIGIMESH_SECURE,
        };
        let mut seconds_per_kbit = interpolate(points, self.hops);
        if self.firmware == Firmware::Zigbee {
            let end_device = match (self.role, self.encrypted) {
                (Role::RouterToRouter, _) => None,
                (Role::RouterToEndDevice, false) => Some(25.0),
                (Role::RouterToEndDevice, true) => Some(16.0),
                (Role::EndDeviceToRouter, false) => Some(21.0),
                (Role::EndDeviceToRouter, true) => Some(16.0),
            };
            if let Some(kbps) = end_device {
                seconds_per_kbit += 1.0 / kbps - 1.0 / points[0].1;
            }
        }
        Some(1000.0 / seconds_per_kbit)
    }

    /// The air time, µs, that one packet of `payload` bytes holds the path
    /// for, acknowledgements, retries of the stack and every hop included,
    /// when full packets carry `np` bytes each; `None` for 802.15.4.
    ///
    /// Digi's transfers sent full packets, so a full one takes `np · 8 /
    /// throughput`; a shorter one saves its missing bytes' air time at 250
    /// kb/s on each hop, and keeps the rest (backoffs, acknowledgements, the
    /// stack's processing), which is most of it.
    pub fn packet_us(&self, payload: usize, np: usize) -> Option<f64> {
        let full = np as f64 * 8.0 / self.measured_bps()? * 1e6;
        let saved = np.saturating_sub(payload) as f64 * 32.0 * f64::from(self.hops);
        Some((full - saved).max(full / 4.0))
    }
}

/// Seconds per kilobit at `hops`, linear between the measured points.
fn interpolate(points: Points, hops: u8) -> f64 {
    let t = |(h, kbps): (u8, f64)| (f64::from(h), 1.0 / kbps);
    let h = f64::from(hops);
    let pair = points
        .windows(2)
        .find(|w| hops <= w[1].0)
        .unwrap_or(&points[points.len() - 2..]);
    let ((h0, t0), (h1, t1)) = (t(pair[0]), t(pair[1]));
    t0 + (t1 - t0) * (h - h0) / (h1 - h0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(firmware: Firmware, hops: u8, encrypted: bool, role: Role) -> RadioPath {
        RadioPath {
            firmware,
            hops,
            encrypted,
            role,
        }
    }

    /// Every row of both manuals' tables comes back as printed.
    #[test]
    fn the_manuals_tables_are_reproduced() {
        use Firmware::*;
        use Role::*;
        let rows = [
            (Zigbee, 1, false, RouterToRouter, 35.0),
            (Zigbee, 1, true, RouterToRouter, 19.0),
            (Zigbee, 1, false, RouterToEndDevice, 25.0),
            (Zigbee, 1, true, RouterToEndDevice, 16.0),
            (Zigbee, 1, false, EndDeviceToRouter, 21.0),
            (Zigbee, 1, true, EndDeviceToRouter, 16.0),
            (Zigbee, 4, false, RouterToRouter, 10.0),
            (Zigbee, 4, true, RouterToRouter, 5.0),
            (DigiMesh, 1, false, RouterToRouter, 27.0),
            (DigiMesh, 3, false, RouterToRouter, 10.9),
            (DigiMesh, 6, false, RouterToRouter, 5.78),
            (DigiMesh, 1, true, RouterToRouter, 20.5),
            (DigiMesh, 3, true, RouterToRouter, 9.81),
            (DigiMesh, 6, true, RouterToRouter, 4.70),
        ];
        for (fw, hops, enc, role, kbps) in rows {
            let got = path(fw, hops, enc, role).measured_bps().unwrap() / 1000.0;
            assert!(
                (got - kbps).abs() < 1e-9,
                "{fw} {hops} {enc} {role:?}: {got}"
            );
        }
    }

    #[test]
    fn more_hops_never_carry_more() {
        for fw in [Firmware::Zigbee, Firmware::DigiMesh] {
            for enc in [false, true] {
                let rates: Vec<f64> = (1..=MAX_HOPS)
                    .map(|h| {
                        path(fw, h, enc, Role::RouterToRouter)
                            .measured_bps()
                            .unwrap()
                    })
                    .collect();
                assert!(rates.windows(2).all(|w| w[1] < w[0]), "{fw} {enc}");
                assert!(rates.iter().all(|&r| r > 0.0 && r.is_finite()));
            }
        }
    }

    #[test]
    fn a_full_packet_takes_its_share_of_the_measured_rate() {
        let zb = RadioPath::direct(Firmware::Zigbee);
        let t = zb.packet_us(84, 84).unwrap();
        assert!((t - 84.0 * 8.0 / 35_000.0 * 1e6).abs() < 1e-6);
        // A short packet saves only its missing bytes' air time.
        let short = zb.packet_us(20, 84).unwrap();
        assert!((t - short - 64.0 * 32.0).abs() < 1e-6);
        assert_eq!(
            RadioPath::direct(Firmware::Ieee802154).packet_us(100, 100),
            None
        );
    }

    #[test]
    fn impossible_paths_are_named() {
        assert!(path(Firmware::Ieee802154, 2, false, Role::RouterToRouter)
            .validate()
            .unwrap_err()
            .contains("no mesh"));
        assert!(path(Firmware::DigiMesh, 1, false, Role::RouterToEndDevice)
            .validate()
            .is_err());
        assert!(path(Firmware::Zigbee, 0, false, Role::RouterToRouter)
            .validate()
            .is_err());
        assert!(path(Firmware::Zigbee, 6, true, Role::RouterToEndDevice)
            .validate()
            .is_ok());
    }
}
