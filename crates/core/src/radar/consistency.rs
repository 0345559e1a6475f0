//! The radars' Doppler against the odometry: two independent measurements of the same motion. Each
//! scan's radar velocity fitted from its radial velocities alone (no odometry prior) is compared with
//! the velocity the odometry predicts at the radar ([`compare`]); a radar whose scans disagree in most
//! of its recent scans is misconfigured, and the way they disagree names the likely cause
//! ([`DopplerMonitor`]): a flipped radial-velocity sign, a wrong extrinsic yaw, a velocity scale far
//! off.

use std::collections::VecDeque;

use crate::math::Vec3;

/// Slowest predicted radar speed whose scans are compared, m/s: slower, noise and moving objects
/// say more than the motion.
pub const MIN_SPEED: f64 = 2.0;
/// Recent informative scans per radar that are judged together.
const WINDOW: usize = 20;
/// Of those, how many must disagree for the radar to be flagged.
const FLAG_AT: usize = 15;

/// How one scan's Doppler velocity compares with the odometry's prediction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict {
    /// They agree (within 0.5 m/s or 15 %).
    Agrees,
    /// The Doppler says the opposite: the radial velocity has the other sign.
    Flipped,
    /// Same speed, another direction: the extrinsic yaw is off by about this angle, rad.
    Rotated(f64),
    /// Same direction, another speed: the ratio Doppler / odometry.
    Scaled(f64),
    /// They disagree with no simple cause.
    Other,
}

/// Compares a radar velocity fitted from the Doppler alone with the one the odometry predicts (both
/// in the radar frame, planar).
pub fn compare(fit: &Vec3, predicted: &Vec3) -> Verdict {
    let (f, p) = (fit.xy(), predicted.xy());
    let tolerance = (0.15 * p.norm()).max(0.5);
    if (f - p).norm() <= tolerance {
        return Verdict::Agrees;
    }
    if (f + p).norm() <= tolerance {
        return Verdict::Flipped;
    }
    let ratio = f.norm() / p.norm().max(1e-9);
    let angle = p.perp(&f).atan2(p.dot(&f));
    match (angle.abs() > 10f64.to_radians(), (ratio - 1.0).abs() < 0.15) {
        (true, true) => Verdict::Rotated(angle),
        (false, false) => Verdict::Scaled(ratio),
        _ => Verdict::Other,
    }
}

/// One radar's recent verdicts.
#[derive(Debug, Clone, Default)]
struct RadarRecord {
    recent: VecDeque<Verdict>,
    flagged: bool,
}

/// Watches every radar's Doppler against the odometry.
#[derive(Debug, Clone, Default)]
pub struct DopplerMonitor {
    radars: Vec<RadarRecord>,
}

impl DopplerMonitor {
    /// Takes one informative scan of radar `radar`; the first time the radar's recent scans mostly
    /// disagree, returns the likely cause (the radar is flagged from then on).
    pub fn observe(&mut self, radar: usize, verdict: Verdict) -> Option<String> {
        if self.radars.len() <= radar {
            self.radars.resize_with(radar + 1, RadarRecord::default);
        }
        let r = &mut self.radars[radar];
        r.recent.push_back(verdict);
        if r.recent.len() > WINDOW {
            r.recent.pop_front();
        }
        let disagree: Vec<Verdict> = r
            .recent
            .iter()
            .copied()
            .filter(|v| *v != Verdict::Agrees)
            .collect();
        if r.flagged || disagree.len() < FLAG_AT {
            return None;
        }
        r.flagged = true;
        Some(format!(
            "its Doppler speeds disagree with the odometry in {} of its last {} scans: {}",
            disagree.len(),
            r.recent.len(),
            likely_cause(&disagree)
        ))
    }

    /// Whether radar `radar` has been flagged.
    pub fn flagged(&self, radar: usize) -> bool {
        self.radars.get(radar).is_some_and(|r| r.flagged)
    }
}

/// The most common way the disagreeing scans disagree, as advice.
fn likely_cause(disagree: &[Verdict]) -> String {
    let count = |f: &dyn Fn(&Verdict) -> bool| disagree.iter().filter(|v| f(v)).count();
    let flipped = count(&|v| matches!(v, Verdict::Flipped));
    let rotated: Vec<f64> = disagree
        .iter()
        .filter_map(|v| match v {
            Verdict::Rotated(a) => Some(*a),
            _ => None,
        })
        .collect();
    let scaled: Vec<f64> = disagree
        .iter()
        .filter_map(|v| match v {
            Verdict::Scaled(k) => Some(*k),
            _ => None,
        })
        .collect();
    let half = disagree.len() / 2;
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    if flipped > half {
        "the radial velocity looks sign-flipped (dc_loc expects it positive for a target moving away; \
         negate the driver's field)"
            .into()
    } else if rotated.len() > half {
        format!(
            "the radar looks turned by about {:.0} degrees from its extrinsic (check radars.<name>.extrinsic's yaw)",
            median(rotated).to_degrees()
        )
    } else if scaled.len() > half {
        format!(
            "the Doppler speed is {:.2} times the odometry's (check the velocity field's unit and the odometry's scale)",
            median(scaled)
        )
    } else {
        "no single cause (check the velocity fields, the extrinsic and the odometry)".into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verdicts_name_the_way_the_velocities_differ() {
        let p = Vec3::new(10.0, 0.5, 0.0);
        assert_eq!(compare(&Vec3::new(10.2, 0.4, 0.0), &p), Verdict::Agrees);
        assert_eq!(compare(&-p, &p), Verdict::Flipped);
        let turned = Vec3::new(10.0 * 0.5f64.cos(), 10.0 * 0.5f64.sin(), 0.0);
        match compare(&turned, &Vec3::new(10.0, 0.0, 0.0)) {
            Verdict::Rotated(a) => assert!((a - 0.5).abs() < 1e-9),
            v => panic!("{v:?}"),
        }
        match compare(&(p * 0.5), &p) {
            Verdict::Scaled(k) => assert!((k - 0.5).abs() < 1e-9),
            v => panic!("{v:?}"),
        }
    }

    #[test]
    fn a_radar_is_flagged_once_when_most_recent_scans_disagree() {
        let mut m = DopplerMonitor::default();
        for _ in 0..30 {
            assert!(m.observe(0, Verdict::Agrees).is_none());
        }
        let mut warnings = Vec::new();
        for k in 0..40 {
            let v = if k % 10 == 0 {
                Verdict::Agrees
            } else {
                Verdict::Flipped
            };
            warnings.extend(m.observe(1, v));
            assert!(m.observe(0, Verdict::Agrees).is_none());
        }
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].contains("sign-flipped"), "{}", warnings[0]);
        assert!(m.flagged(1) && !m.flagged(0));
    }
}
