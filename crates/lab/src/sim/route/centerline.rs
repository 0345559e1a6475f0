//! The road loop's centre line: from the corner polygon of [`RouteConfig`], each corner a clothoid, a
//! circular arc and a clothoid tangent to both polygon edges, the straights filling the rest. Heading
//! and curvature are analytic; positions are closed-form on straights and arcs and Gauss-Legendre
//! integrated (with Hermite interpolation between 0.25 m nodes) on clothoids.

use crate::sim::config::RouteConfig;
use dc_loc_core::math::Vec2;
use dc_loc_core::validate::ConfigError;

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

/// A corner built in its local frame (start at the origin, heading 0): its turn, the tangent length
/// from the polygon vertex to where it starts and ends, and its pieces as `(len, k0, k1)`.
struct LocalCorner {
    turn: f64,
    tangent: f64,
    parts: Vec<(f64, f64, f64)>,
}

/// Corner `i` of the route polygon, wrapped.
fn vertex(route: &RouteConfig, i: usize) -> Vec2 {
    let c = &route.corners[i % route.corners.len()];
    Vec2::new(c.x, c.y)
}

/// Corner `i` as a clothoid, an arc and a clothoid tangent to both polygon edges, integrated in its local
/// frame; `ConfigError` when it comes out asymmetric.
fn local_corner(route: &RouteConfig, i: usize) -> Result<LocalCorner, ConfigError> {
    let n = route.corners.len();
    let vtx = |i: usize| vertex(route, i);
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
    Ok(LocalCorner {
        turn,
        tangent: a,
        parts,
    })
}

/// The length of each straight (straight `i` from corner `i` to corner `i + 1`) between the corners'
/// tangent points; `ConfigError` when two corners overlap.
fn straight_lengths(route: &RouteConfig, locals: &[LocalCorner]) -> Result<Vec<f64>, ConfigError> {
    let n = route.corners.len();
    let vtx = |i: usize| vertex(route, i);
    let mut straight_len = Vec::with_capacity(n);
    for i in 0..n {
        let len = (vtx(i + 1) - vtx(i)).norm() - locals[i].tangent - locals[(i + 1) % n].tangent;
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
    Ok(straight_len)
}

/// The loop laid out piece by piece: its pieces and corners, the start pose and the pose where the
/// last piece ends (equal to the start, turned by the total turn, when the loop closes).
struct LaidLoop {
    pieces: Vec<Piece>,
    corners: Vec<CornerInfo>,
    start: Vec2,
    theta_start: f64,
    end: Vec2,
    theta_end: f64,
    length: f64,
}

/// Lays the loop out from the middle of straight 0 (corner 0 to corner 1): half of it, then each corner
/// and the straight after it, ending with the other half of straight 0.
fn lay_out(route: &RouteConfig, locals: &[LocalCorner], straight_len: &[f64]) -> LaidLoop {
    let n = route.corners.len();
    let vtx = |i: usize| vertex(route, i);
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
    LaidLoop {
        pieces,
        corners,
        start,
        theta_start,
        end: p,
        theta_end: th,
        length: s,
    }
}

impl Centerline {
    /// Builds the loop; `ConfigError` when the corners do not form a loop or figure eight, or two corners overlap
    /// (a straight would get a negative length).
    pub fn new(route: &RouteConfig) -> Result<Self, ConfigError> {
        route.validate()?;
        let n = route.corners.len();
        let mut locals = Vec::with_capacity(n);
        for i in 0..n {
            locals.push(local_corner(route, i)?);
        }
        let straight_len = straight_lengths(route, &locals)?;
        let laid = lay_out(route, &locals, &straight_len);
        let total_turn: f64 = locals.iter().map(|l| l.turn).sum();
        let (p, start) = (laid.end, laid.start);
        if (p - start).norm() > 1e-6
            || (laid.theta_end - laid.theta_start - total_turn).abs() > 1e-9
        {
            return Err(ConfigError::new(
                "route.corners",
                format!(
                    "internal error: the loop does not close ({:.3e} m)",
                    (p - start).norm()
                ),
            ));
        }
        Ok(Centerline {
            pieces: laid.pieces,
            length: laid.length,
            total_turn,
            corners: laid.corners,
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

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
