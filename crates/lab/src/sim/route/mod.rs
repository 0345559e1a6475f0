//! The road loop's centre line and the ego vehicle's drive along it.
//!
//! The centre line ([`centerline`]) joins the corners of the polygon of
//! [`RouteConfig`](crate::sim::config::RouteConfig) by straights, each corner a clothoid, a circular arc
//! and a clothoid; the ego drives its outermost lane on the right at a constant offset, with a speed
//! profile bounded by the corner speeds and the acceleration limits. docs/algorithm.md, "The route", has
//! the geometry and the speed profile.
//!
//! Entry points: [`Centerline`] (straights, clothoids and arcs; position, heading and curvature at an arc
//! length), [`Trajectory`] (laps, U-turns, speed profile; [`Trajectory::state`] gives the exact ego state
//! at a time), [`EgoState`], [`LapInfo`].

pub mod centerline;

pub use centerline::{Centerline, CornerInfo};

use crate::sim::config::{DriveConfig, LapConfig};
use dc_loc_core::math::{Iso2, Vec2};
use dc_loc_core::validate::ConfigError;
use std::f64::consts::PI;

/// Node spacing of the speed profile, m.
const STEP: f64 = 0.5;

/// Where in the drive a moment lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct LapInfo {
    /// Lap index into `SimConfig::laps` (a U-turn belongs to the lap after it).
    pub lap: usize,
    /// The lap is driven against the loop's direction.
    pub reverse: bool,
    /// The vehicle is in the U-turn before the lap, not on the loop.
    pub turning: bool,
}

/// The exact ego state at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EgoState {
    /// Seconds since the drive started.
    pub t: f64,
    /// Body pose in the map frame (planar).
    pub t_map_body: Iso2,
    /// Heading, rad, continuous over the drive (not wrapped).
    pub heading: f64,
    /// Forward speed, m/s (the body never slips sideways).
    pub speed: f64,
    /// Forward acceleration, m/s^2.
    pub acceleration: f64,
    /// Yaw rate, rad/s (= curvature x speed).
    pub yaw_rate: f64,
    /// Signed curvature of the ego path, 1/m.
    pub curvature: f64,
    /// Distance driven since the start, m.
    pub distance: f64,
    /// Lap and direction.
    pub lap: LapInfo,
    /// Arc length of the centre-line point abeam the ego, m in `[0, loop length)` (U-turn: 0).
    pub loop_position: f64,
}

#[derive(Debug, Clone, Copy)]
enum LegKind {
    Lap {
        offset: f64,
        reverse: bool,
        /// Centre-line arc length where the lap starts and ends, m.
        start: f64,
    },
    UTurn {
        center: Vec2,
        radius: f64,
        alpha0: f64,
    },
}

#[derive(Debug, Clone, Copy)]
struct Leg {
    kind: LegKind,
    lap: LapInfo,
    /// Ego arc length at the leg start (global) and the leg's own length, m.
    u0: f64,
    len: f64,
    /// Unwrapped heading at the leg start, rad.
    heading0: f64,
}

/// The whole drive: legs (laps and U-turns) and a speed profile over the driven distance.
#[derive(Debug, Clone)]
pub struct Trajectory {
    line: Centerline,
    legs: Vec<Leg>,
    /// Speed-profile nodes: driven distance, speed, time.
    node_u: Vec<f64>,
    node_v: Vec<f64>,
    node_t: Vec<f64>,
    /// Leg of the cell that starts at each node.
    node_leg: Vec<usize>,
    /// Time each lap starts and ends (U-turn excluded), s.
    lap_times: Vec<(f64, f64)>,
}

impl Trajectory {
    /// Plans the drive: `laps` in order from `drive.start`, with a left U-turn around the start point
    /// whenever the direction changes; `ego_offset` is the lane offset to the right of the direction of travel, m.
    /// The drive starts at the first lap's cruise speed (or slower if it starts in a corner).
    pub fn new(
        line: Centerline,
        laps: &[LapConfig],
        drive: &DriveConfig,
        ego_offset: f64,
    ) -> Result<Self, ConfigError> {
        if laps.is_empty() {
            return Err(ConfigError::new("laps", "at least one lap is required"));
        }
        if let Some(i) = laps
            .iter()
            .position(|l| !(l.speed.is_finite() && l.speed >= 1.0))
        {
            return Err(ConfigError::new(
                format!("laps[{i}].speed"),
                "must be >= 1 m/s",
            ));
        }
        let min_radius = line
            .corners()
            .iter()
            .map(|c| c.radius)
            .fold(f64::INFINITY, f64::min);
        if !(ego_offset.is_finite() && ego_offset > 0.0 && ego_offset < min_radius) {
            return Err(ConfigError::new(
                "world.street",
                format!(
                    "lane offset {ego_offset} m must be > 0 and below the tightest corner radius"
                ),
            ));
        }
        let l = line.length();
        let start = drive.start.rem_euclid(l);
        let th0 = line.heading(start);
        let mut legs: Vec<Leg> = Vec::new();
        let mut u = 0.0;
        let mut heading = th0;
        let mut prev_reverse = laps.first().is_some_and(|l| l.reverse);
        if prev_reverse {
            heading += PI;
        }
        for (k, lap) in laps.iter().enumerate() {
            if k > 0 && lap.reverse != prev_reverse {
                // Left U-turn around the centre-line start point: from one lane to the other.
                let alpha0 = heading - PI / 2.0;
                let len = PI * ego_offset;
                legs.push(Leg {
                    kind: LegKind::UTurn {
                        center: line.point(start),
                        radius: ego_offset,
                        alpha0,
                    },
                    lap: LapInfo {
                        lap: k,
                        reverse: lap.reverse,
                        turning: true,
                    },
                    u0: u,
                    len,
                    heading0: heading,
                });
                u += len;
                heading += PI;
            }
            // Offset positive to the left of the loop direction: right of travel when forward.
            let offset = if lap.reverse { ego_offset } else { -ego_offset };
            // u(L) = L - offset * total_turn for either direction (the lane is longer on the outside).
            let len = l - offset * line.total_turn();
            legs.push(Leg {
                kind: LegKind::Lap {
                    offset,
                    reverse: lap.reverse,
                    start,
                },
                lap: LapInfo {
                    lap: k,
                    reverse: lap.reverse,
                    turning: false,
                },
                u0: u,
                len,
                heading0: heading,
            });
            u += len;
            heading += if lap.reverse {
                -line.total_turn()
            } else {
                line.total_turn()
            };
            prev_reverse = lap.reverse;
        }
        let mut traj = Trajectory {
            line,
            legs,
            node_u: Vec::new(),
            node_v: Vec::new(),
            node_t: Vec::new(),
            node_leg: Vec::new(),
            lap_times: Vec::new(),
        };
        traj.plan_speed(laps, drive);
        Ok(traj)
    }

    fn plan_speed(&mut self, laps: &[LapConfig], drive: &DriveConfig) {
        let a_lat = drive.max_lateral_acceleration;
        let mut u = Vec::new();
        let mut vmax = Vec::new();
        let mut leg_of = Vec::new();
        for (li, leg) in self.legs.iter().enumerate() {
            let m = ((leg.len / STEP).ceil() as usize).max(2);
            let lap_speed = laps[leg.lap.lap].speed;
            let prev_speed = leg.lap.lap.checked_sub(1).map(|k| laps[k].speed);
            for j in 0..m {
                let ul = leg.len * j as f64 / m as f64;
                let kappa = self.leg_local(leg, ul).3;
                let mut v = match leg.kind {
                    LegKind::UTurn { .. } => drive.uturn_speed,
                    LegKind::Lap { .. } => match prev_speed {
                        // Slow down to a lower lap speed after the lap line, not before it.
                        Some(pv) if pv > lap_speed => lap_speed.max(
                            (pv * pv - 2.0 * drive.max_deceleration * ul)
                                .max(0.0)
                                .sqrt(),
                        ),
                        _ => lap_speed,
                    },
                };
                if kappa.abs() > 1e-12 {
                    v = v.min((a_lat / kappa.abs()).sqrt());
                }
                u.push(leg.u0 + ul);
                vmax.push(v);
                leg_of.push(li);
            }
        }
        if let Some(last) = self.legs.last() {
            let lap_speed = laps[last.lap.lap].speed;
            let kappa = self.leg_local(last, last.len).3;
            u.push(last.u0 + last.len);
            vmax.push(if kappa.abs() > 1e-12 {
                lap_speed.min((a_lat / kappa.abs()).sqrt())
            } else {
                lap_speed
            });
            leg_of.push(self.legs.len() - 1);
        }
        let n = u.len();
        let mut v = vmax.clone();
        for j in 0..n - 1 {
            let du = u[j + 1] - u[j];
            v[j + 1] = v[j + 1].min((v[j] * v[j] + 2.0 * drive.max_acceleration * du).sqrt());
        }
        for j in (0..n - 1).rev() {
            let du = u[j + 1] - u[j];
            v[j] = v[j].min((v[j + 1] * v[j + 1] + 2.0 * drive.max_deceleration * du).sqrt());
        }
        let mut t = vec![0.0; n];
        for j in 0..n - 1 {
            t[j + 1] = t[j] + 2.0 * (u[j + 1] - u[j]) / (v[j] + v[j + 1]);
        }
        self.lap_times = self
            .legs
            .iter()
            .filter(|l| matches!(l.kind, LegKind::Lap { .. }))
            .map(|l| {
                let ta = t[u.partition_point(|x| *x < l.u0 - 1e-9)];
                let tb = t[u.partition_point(|x| *x < l.u0 + l.len - 1e-9).min(n - 1)];
                (ta, tb)
            })
            .collect();
        self.node_u = u;
        self.node_v = v;
        self.node_t = t;
        self.node_leg = leg_of;
    }

    /// The centre line driven.
    pub fn centerline(&self) -> &Centerline {
        &self.line
    }
    /// Duration of the drive, s.
    pub fn duration(&self) -> f64 {
        self.node_t.last().copied().unwrap_or(0.0)
    }
    /// Total distance driven, m.
    pub fn distance(&self) -> f64 {
        self.node_u.last().copied().unwrap_or(0.0)
    }
    /// Start and end time of each lap (index = lap), s since the start; U-turns lie between laps.
    pub fn lap_times(&self) -> &[(f64, f64)] {
        &self.lap_times
    }
    /// Driven length of each lap, m (the ego lane is longer than the centre line on the outside).
    pub fn lap_lengths(&self) -> Vec<f64> {
        self.legs
            .iter()
            .filter(|l| matches!(l.kind, LegKind::Lap { .. }))
            .map(|l| l.len)
            .collect()
    }

    /// Within a leg at local driven distance `ul`: (position, unwrapped heading, loop position,
    /// curvature).
    fn leg_local(&self, leg: &Leg, ul: f64) -> (Vec2, f64, f64, f64) {
        match leg.kind {
            LegKind::UTurn {
                center,
                radius,
                alpha0,
            } => {
                let a = alpha0 + ul / radius;
                (
                    center + Vec2::new(a.cos(), a.sin()) * radius,
                    leg.heading0 + ul / radius,
                    0.0,
                    1.0 / radius,
                )
            }
            LegKind::Lap {
                offset,
                reverse,
                start,
            } => {
                let line = &self.line;
                let l = line.length();
                // Progress sig along the centre line; u(sig) = sig - offset * (turned curvature integral).
                let (s_of, dir) = if reverse {
                    (start + l, -1.0)
                } else {
                    (start, 1.0)
                };
                let th_start = line.heading(s_of);
                let u_of = |sig: f64| {
                    let s = s_of + dir * sig;
                    sig - offset * dir * (line.heading(s) - th_start)
                };
                let mut sig = ul;
                for _ in 0..30 {
                    let s = s_of + dir * sig;
                    let f = u_of(sig) - ul;
                    let d = 1.0 - offset * line.curvature(s);
                    let step = f / d;
                    sig -= step;
                    if step.abs() < 1e-12 {
                        break;
                    }
                }
                let s = s_of + dir * sig;
                let th = line.heading(s);
                let k = line.curvature(s);
                let p = line.point(s) + Vec2::new(-th.sin(), th.cos()) * offset;
                let heading = leg.heading0 + (th - th_start);
                (p, heading, s.rem_euclid(l), dir * k / (1.0 - offset * k))
            }
        }
    }

    /// The exact ego state `t` seconds after the start (clamped to the drive).
    pub fn state(&self, t: f64) -> EgoState {
        let n = self.node_t.len();
        let t = t.clamp(0.0, self.duration());
        let j = self.node_t.partition_point(|x| *x <= t).clamp(1, n - 1) - 1;
        let (u0, u1) = (self.node_u[j], self.node_u[j + 1]);
        let (v0, v1) = (self.node_v[j], self.node_v[j + 1]);
        let acc = (v1 * v1 - v0 * v0) / (2.0 * (u1 - u0));
        let tau = t - self.node_t[j];
        let v = v0 + acc * tau;
        let u = (u0 + v0 * tau + 0.5 * acc * tau * tau).min(u1);
        let leg = &self.legs[self.node_leg[j]];
        let (p, heading, loop_position, curvature) = self.leg_local(leg, u - leg.u0);
        EgoState {
            t,
            t_map_body: Iso2::new(p, heading),
            heading,
            speed: v,
            acceleration: acc,
            yaw_rate: curvature * v,
            curvature,
            distance: u,
            lap: leg.lap,
            loop_position,
        }
    }
}
