//! The road loop's centre line and the ego vehicle's drive along it.
//!
//! Entry points: [`Centerline`] (straights, clothoids and arcs; position, heading and curvature at an arc
//! length), [`Trajectory`] (laps, U-turns, speed profile; [`Trajectory::state`] gives the exact ego state
//! at a time), [`EgoState`], [`LapInfo`].
//!
//! The centre line is built from the corner polygon of [`RouteConfig`]: each corner is a clothoid, a
//! circular arc and a clothoid, placed so that it is tangent to both polygon edges; the straights fill the
//! rest. Heading and curvature are analytic; positions are closed-form on straights and arcs and
//! Gauss-Legendre integrated (with Hermite interpolation between 0.25 m nodes) on clothoids.
//!
//! The ego drives in the outermost lane on the right of its direction of travel, a constant offset `o`
//! (positive left) from the centre line: `p = c(s) + o n(s)`. Its own arc length is
//! `u = integral (1 - o kappa) ds`, its curvature `kappa / (1 - o kappa)` and its yaw rate curvature
//! times speed. The speed profile is piecewise constant acceleration in `u` (forward-backward passes over
//! the lap cruise speed, the corner speed `sqrt(a_lat / |kappa|)` and the acceleration limits).

use crate::math::{Iso2, Vec2};
use crate::sim::config::{DriveConfig, LapConfig, RouteConfig};
use crate::validate::ConfigError;
use std::f64::consts::PI;

/// Node spacing of the speed profile, m.
const STEP: f64 = 0.5;
/// Node spacing of clothoid position tables, m (Hermite interpolation: position error < 1e-9 m, tangent
/// error < 1e-7).
const CLOTHOID_STEP: f64 = 0.25;

#[derive(Debug, Clone)]
struct Piece {
    /// Arc length at the start, m.
    s0: f64,
    len: f64,
    /// Curvature at start and end (linear in between), 1/m.
    k0: f64,
    k1: f64,
    theta0: f64,
    p0: Vec2,
    /// Clothoids only: positions every `len / (nodes.len() - 1)`.
    nodes: Vec<Vec2>,
}

impl Piece {
    fn heading(&self, sig: f64) -> f64 {
        self.theta0 + self.k0 * sig + 0.5 * (self.k1 - self.k0) * sig * sig / self.len
    }
    fn curvature(&self, sig: f64) -> f64 {
        self.k0 + (self.k1 - self.k0) * sig / self.len
    }
    fn point(&self, sig: f64) -> Vec2 {
        if self.k0 == self.k1 {
            let k = self.k0;
            if k == 0.0 {
                return self.p0 + Vec2::new(self.theta0.cos(), self.theta0.sin()) * sig;
            }
            let t1 = self.theta0 + k * sig;
            return self.p0
                + Vec2::new(t1.sin() - self.theta0.sin(), self.theta0.cos() - t1.cos()) / k;
        }
        // Cubic Hermite between tabulated nodes, tangents from the analytic heading.
        let m = self.nodes.len() - 1;
        let h = self.len / m as f64;
        let j = ((sig / h).floor() as usize).min(m - 1);
        let x = sig / h - j as f64;
        let (a, b) = (self.nodes[j], self.nodes[j + 1]);
        let ta = self.heading(j as f64 * h);
        let tb = self.heading((j + 1) as f64 * h);
        let (ma, mb) = (
            Vec2::new(ta.cos(), ta.sin()) * h,
            Vec2::new(tb.cos(), tb.sin()) * h,
        );
        let (x2, x3) = (x * x, x * x * x);
        a * (2.0 * x3 - 3.0 * x2 + 1.0)
            + ma * (x3 - 2.0 * x2 + x)
            + b * (-2.0 * x3 + 3.0 * x2)
            + mb * (x3 - x2)
    }
    fn end(&self) -> Vec2 {
        match self.nodes.last() {
            Some(p) => *p,
            None => self.point(self.len),
        }
    }

    fn new(s0: f64, len: f64, k0: f64, k1: f64, theta0: f64, p0: Vec2) -> Self {
        let mut piece = Piece {
            s0,
            len,
            k0,
            k1,
            theta0,
            p0,
            nodes: Vec::new(),
        };
        if k0 != k1 {
            let m = ((len / CLOTHOID_STEP).ceil() as usize).max(2);
            let h = len / m as f64;
            let mut nodes = Vec::with_capacity(m + 1);
            let mut p = p0;
            nodes.push(p);
            for j in 0..m {
                p += gauss_legendre_chord(&piece, j as f64 * h, h);
                nodes.push(p);
            }
            piece.nodes = nodes;
        }
        piece
    }
}

/// Appends a piece starting at the running pose and advances it; zero-length pieces are skipped.
fn push_piece(
    pieces: &mut Vec<Piece>,
    len: f64,
    k0: f64,
    k1: f64,
    p: &mut Vec2,
    th: &mut f64,
    s: &mut f64,
) {
    if len <= 0.0 {
        return;
    }
    let piece = Piece::new(*s, len, k0, k1, *th, *p);
    *p = piece.end();
    *th = piece.heading(len);
    *s += len;
    pieces.push(piece);
}

/// Integral of the unit tangent over `[a, a + h]` (5-point Gauss-Legendre, exact to ~1e-13 m here).
fn gauss_legendre_chord(piece: &Piece, a: f64, h: f64) -> Vec2 {
    const X: [f64; 5] = [
        0.0,
        -0.538_469_310_105_683_1,
        0.538_469_310_105_683_1,
        -0.906_179_845_938_664,
        0.906_179_845_938_664,
    ];
    const W: [f64; 5] = [
        0.568_888_888_888_888_9,
        0.478_628_670_499_366_5,
        0.478_628_670_499_366_5,
        0.236_926_885_056_189_1,
        0.236_926_885_056_189_1,
    ];
    let mut acc = Vec2::zeros();
    for (x, w) in X.iter().zip(W) {
        let th = piece.heading(a + 0.5 * h * (1.0 + x));
        acc += Vec2::new(th.cos(), th.sin()) * w;
    }
    acc * 0.5 * h
}

/// A corner of the loop as built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CornerInfo {
    /// Arc length where the corner starts and ends, m.
    pub s_start: f64,
    /// Arc length where the corner ends, m (may exceed the loop length for the last corner: wrap it).
    pub s_end: f64,
    /// The polygon vertex.
    pub vertex: Vec2,
    /// Unit direction of the incoming and outgoing straight.
    pub d_in: Vec2,
    /// Unit direction of the outgoing straight.
    pub d_out: Vec2,
    /// Both streets continue past the corner.
    pub junction: bool,
    /// Radius of the constant-curvature part, m.
    pub radius: f64,
}

/// The closed road centre line, parametrised by arc length `s` in `[0, length)` (wrapped outside).
#[derive(Debug, Clone)]
pub struct Centerline {
    pieces: Vec<Piece>,
    length: f64,
    total_turn: f64,
    corners: Vec<CornerInfo>,
}

impl Centerline {
    /// Builds the loop; `ConfigError` when the corners do not form a simple loop or two corners overlap
    /// (a straight would get a negative length).
    pub fn new(route: &RouteConfig) -> Result<Self, ConfigError> {
        route.validate()?;
        let n = route.corners.len();
        let vtx = |i: usize| {
            let c = &route.corners[i % n];
            Vec2::new(c.x, c.y)
        };
        // Per corner: the pieces in a local frame (start at origin, heading 0) and the tangent length.
        struct Local {
            turn: f64,
            tangent: f64,
            parts: Vec<(f64, f64, f64)>, // (len, k0, k1)
        }
        let mut locals = Vec::with_capacity(n);
        for i in 0..n {
            let d_in = vtx(i + n) - vtx(i + n - 1);
            let d_out = vtx(i + 1) - vtx(i);
            let turn = d_in.perp(&d_out).atan2(d_in.dot(&d_out));
            let r = route.corners[i].radius;
            let k = turn.signum() / r;
            let lt = route.transition_length.min(0.5 * r * turn.abs());
            let arc = r * turn.abs() - lt;
            let mut parts = Vec::new();
            if lt > 0.0 {
                parts.push((lt, 0.0, k));
            }
            parts.push((arc, k, k));
            if lt > 0.0 {
                parts.push((lt, k, 0.0));
            }
            // Integrate the corner in its local frame.
            let (mut p, mut th, mut s) = (Vec2::zeros(), 0.0, 0.0);
            for &(len, k0, k1) in &parts {
                let piece = Piece::new(s, len, k0, k1, th, p);
                p = piece.end();
                th = piece.heading(len);
                s += len;
            }
            // p = a e_x + b (cos turn, sin turn); symmetric corners give a = b.
            let b = p.y / turn.sin();
            let a = p.x - b * turn.cos();
            if (a - b).abs() > 1e-6 * (1.0 + a.abs()) {
                return Err(ConfigError::new(
                    format!("route.corners[{i}]"),
                    "internal error: asymmetric corner",
                ));
            }
            locals.push(Local {
                turn,
                tangent: a,
                parts,
            });
        }
        let mut straight_len = Vec::with_capacity(n);
        for i in 0..n {
            let len =
                (vtx(i + 1) - vtx(i)).norm() - locals[i].tangent - locals[(i + 1) % n].tangent;
            if len < 1.0 {
                return Err(ConfigError::new(
                    format!("route.corners[{}]", (i + 1) % n),
                    format!(
                        "corners {i} and {} overlap: the straight between them would be {len:.1} m; \
                         use smaller radii or move the corners apart",
                        (i + 1) % n
                    ),
                ));
            }
            straight_len.push(len);
        }
        // Start in the middle of straight 0 (corner 0 to corner 1).
        let d0 = (vtx(1) - vtx(0)).normalize();
        let start = vtx(0) + d0 * (locals[0].tangent + 0.5 * straight_len[0]);
        let theta_start = d0.y.atan2(d0.x);
        let mut pieces = Vec::new();
        let mut corners = Vec::with_capacity(n);
        let (mut p, mut th, mut s) = (start, theta_start, 0.0);
        push_piece(
            &mut pieces,
            0.5 * straight_len[0],
            0.0,
            0.0,
            &mut p,
            &mut th,
            &mut s,
        );
        for step in 1..=n {
            let i = step % n;
            let s_start = s;
            for &(len, k0, k1) in &locals[i].parts {
                push_piece(&mut pieces, len, k0, k1, &mut p, &mut th, &mut s);
            }
            corners.push(CornerInfo {
                s_start,
                s_end: s,
                vertex: vtx(i),
                d_in: (vtx(i + n) - vtx(i + n - 1)).normalize(),
                d_out: (vtx(i + 1) - vtx(i)).normalize(),
                junction: route.corners[i].junction,
                radius: route.corners[i].radius,
            });
            let len = if i == 0 {
                0.5 * straight_len[0]
            } else {
                straight_len[i]
            };
            push_piece(&mut pieces, len, 0.0, 0.0, &mut p, &mut th, &mut s);
        }
        let total_turn: f64 = locals.iter().map(|l| l.turn).sum();
        if (p - start).norm() > 1e-6 || (th - theta_start - total_turn).abs() > 1e-9 {
            return Err(ConfigError::new(
                "route.corners",
                format!(
                    "internal error: the loop does not close ({:.3e} m)",
                    (p - start).norm()
                ),
            ));
        }
        Ok(Centerline {
            pieces,
            length: s,
            total_turn,
            corners,
        })
    }

    /// Loop length, m.
    pub fn length(&self) -> f64 {
        self.length
    }
    /// Heading change over one loop: +2 pi counter-clockwise, -2 pi clockwise.
    pub fn total_turn(&self) -> f64 {
        self.total_turn
    }
    /// The corners in driving order, starting with corner 1.
    pub fn corners(&self) -> &[CornerInfo] {
        &self.corners
    }

    /// Piece and local arc length at `s` wrapped into the loop; also the number of whole loops removed.
    fn locate(&self, s: f64) -> (&Piece, f64, f64) {
        let laps = (s / self.length).floor();
        let sw = s - laps * self.length;
        let i = self
            .pieces
            .partition_point(|p| p.s0 <= sw)
            .saturating_sub(1);
        let p = &self.pieces[i];
        (p, (sw - p.s0).clamp(0.0, p.len), laps)
    }
    /// Centre-line point at arc length `s`, m.
    pub fn point(&self, s: f64) -> Vec2 {
        let (p, sig, _) = self.locate(s);
        p.point(sig)
    }
    /// Heading at `s`, rad, continuous in `s` (grows by `total_turn` per loop).
    pub fn heading(&self, s: f64) -> f64 {
        let (p, sig, laps) = self.locate(s);
        p.heading(sig) + laps * self.total_turn
    }
    /// Signed curvature at `s` (positive turning left), 1/m.
    pub fn curvature(&self, s: f64) -> f64 {
        let (p, sig, _) = self.locate(s);
        p.curvature(sig)
    }
    /// Point `offset` to the left of the centre line at `s` (negative: right), m.
    pub fn offset_point(&self, s: f64, offset: f64) -> Vec2 {
        let (p, sig, _) = self.locate(s);
        let th = p.heading(sig);
        p.point(sig) + Vec2::new(-th.sin(), th.cos()) * offset
    }
    /// Whether `s` lies within `margin` of a corner (clothoid or arc), m.
    pub fn near_corner(&self, s: f64, margin: f64) -> bool {
        let l = self.length;
        let sw = s.rem_euclid(l);
        self.corners.iter().any(|c| {
            [-l, 0.0, l]
                .iter()
                .any(|o| sw + o >= c.s_start - margin && sw + o <= c.s_end + margin)
        })
    }
    /// The straight stretches as `(s_start, s_end)`, in order (the one through `s = 0` split in two).
    pub fn straights(&self) -> Vec<(f64, f64)> {
        self.pieces
            .iter()
            .filter(|p| p.k0 == 0.0 && p.k1 == 0.0)
            .map(|p| (p.s0, p.s0 + p.len))
            .collect()
    }
}

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
    /// Plans the drive: `laps` in order, with a left U-turn around the start point whenever the
    /// direction changes; `ego_offset` is the lane offset to the right of the direction of travel, m.
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
        let th0 = line.heading(0.0);
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
                        center: line.point(0.0),
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
            LegKind::Lap { offset, reverse } => {
                let line = &self.line;
                let l = line.length();
                // Progress sig along the centre line; u(sig) = sig - offset * (turned curvature integral).
                let (s_of, dir) = if reverse { (l, -1.0) } else { (0.0, 1.0) };
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

#[cfg(test)]
mod tests {
    use super::*;

    fn line() -> Centerline {
        Centerline::new(&RouteConfig::default()).unwrap()
    }

    /// The heading is the direction of the position's derivative and the curvature its rate (central
    /// differences), everywhere along the loop; the loop closes.
    #[test]
    fn centerline_is_self_consistent_and_closed() {
        let c = line();
        let l = c.length();
        assert!((c.total_turn() - 2.0 * PI).abs() < 1e-9);
        assert!((c.point(0.0) - c.point(l - 1e-9)).norm() < 1e-6);
        let h = 1e-3;
        let mut s = 0.37;
        while s < l - 1.0 {
            let d = (c.point(s + h) - c.point(s - h)) / (2.0 * h);
            let th = c.heading(s);
            assert!((d.norm() - 1.0).abs() < 1e-6, "speed at {s}: {}", d.norm());
            assert!(
                (d - Vec2::new(th.cos(), th.sin())).norm() < 1e-6,
                "tangent at {s}"
            );
            let dk = (c.heading(s + h) - c.heading(s - h)) / (2.0 * h);
            assert!((dk - c.curvature(s)).abs() < 1e-6, "curvature at {s}");
            s += 0.731;
        }
    }

    #[test]
    fn corners_have_their_radius_and_straights_are_straight() {
        let c = line();
        let cfg = RouteConfig::default();
        for (i, corner) in c.corners().iter().enumerate() {
            let idx = (i + 1) % cfg.corners.len();
            let mid = 0.5 * (corner.s_start + corner.s_end);
            let r = 1.0 / c.curvature(mid).abs();
            assert!(
                (r - cfg.corners[idx].radius).abs() < 1e-9,
                "corner {idx}: {r}"
            );
            // The arc is tangent to both polygon edges: the edge lines pass through the corner ends.
            let a = c.point(corner.s_start) - corner.vertex;
            assert!(a.perp(&corner.d_in).abs() < 1e-6);
            let b = c.point(corner.s_end) - corner.vertex;
            assert!(b.perp(&corner.d_out).abs() < 1e-6);
        }
        for (a, b) in c.straights() {
            assert_eq!(c.curvature(0.5 * (a + b)), 0.0);
        }
    }
}
