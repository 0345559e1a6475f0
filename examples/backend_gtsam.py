#!/usr/bin/env python3
"""A small pose-graph back end for dc_loc's loop closures: GTSAM Pose2 graph, optimised with
Levenberg-Marquardt.

Run it beside the dc_loc node (rclpy, GTSAM 4.x Python wheels, the dc_loc interface package from msg/):

    python3 examples/backend_gtsam.py --odom /odom --closures /dc_loc/loop_closures --out traj.csv

The graph
- Nodes: the keyframes the closures name (query and match), at their odometry poses (the closures carry
  them: ``query_odom_pose``, ``match_odom_pose``), keyed ``x<keyframe id>``; the first (oldest) keyframe is
  anchored where odometry puts it.
- Odometry: a ``BetweenFactorPose2`` between consecutive keyframe nodes (in time), measuring their
  relative odometry pose. Noise model: independent x, y, heading with standard deviations
  ``max(--odom-min-sigma, --odom-sigma * d)`` (m) and ``max(--odom-min-yaw-sigma, --odom-yaw-sigma * d)``
  (rad), ``d`` the path the odometry stream drove between the two keyframes (the straight distance when
  no odometry arrived). The defaults, 3 % of distance and 5e-4 rad/m, are an odometry drifting by about
  3 % (dc_loc's own drift model is 5 % and 5e-4 rad/m, ``loop.drift_rate``, ``loop.drift_yaw_rate``).
- Closures: a ``BetweenFactorPose2`` from the match keyframe to the query keyframe measuring
  ``relative_pose`` (the query body frame in the match body frame). Its covariance is dc_loc's 6 x 6
  (x, y, z, rot x, rot y, rot z, a right perturbation in the query frame: T_true = T_est * Exp(delta)),
  which is GTSAM's Pose2 tangent convention (x, y, theta in the local frame of the between pose) once
  rows and columns 0, 1 and 5 are taken (``planar_covariance``). z, roll and pitch (1e6, unobserved by
  a planar registration) drop out.

The ROS node re-optimises after every ``--every`` closures, publishes the optimised keyframe poses as
``nav_msgs/Path`` on ``~/optimized_path`` (in the odometry frame) and writes them at exit (SIGINT) to
``--out`` (CSV: key, stamp, x, y, yaw) and ``--tum`` (TUM: stamp x y z qx qy qz qw). One session only: a
closure onto a loaded map's keyframe carries that keyframe's pose in the earlier session's odometry frame.

Several robots (``--fleet``; dc_loc nodes with ``node.fleet:=true``, whose closures name the match
keyframe's robot in ``match_robot`` and carry its pose in that robot's odometry frame): keys per
(robot, keyframe id), ``gtsam.Symbol`` with the letter ``ROBOT_LETTERS[robot]``; one odometry chain per
robot (each robot's path lengths from its own odometry: ``--robot-odom ROBOT=TOPIC``); the first robot
(``--anchor``, default the lowest robot id) anchored by a prior at its odometry pose; every other robot
initialised from its first closure onto a robot already placed (robots never linked to the anchor's are
left out until they are). ``--closures`` may then be given once per node. Optimised poses are in the anchor
robot's odometry frame; ``~/optimized_path`` carries every robot's keyframes, ``--out`` adds a ``robot``
column (robot, key, stamp, x, y, yaw).

For scripts and tests: ``Closure`` (``from_msg``, ``from_record`` for ``dc_loc run --out`` JSON lines),
``PathLength`` (odometry path by stamp), ``build_graph``, ``optimise``, ``odometry_poses``; for a fleet
``fleet_key``, ``build_fleet_graph``, ``optimise_fleet``.
``--rotate-covariance DEG`` turns each closure's x-y covariance by DEG degrees before use: a deliberately
wrong frame, to see what a covariance in the wrong frame does to the result.
"""

from __future__ import annotations

import argparse
import bisect
import csv
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np

# Rows and columns of dc_loc's 6 x 6 (x y z rotx roty rotz) that make GTSAM's Pose2 order (x y theta).
PLANAR = [0, 1, 5]


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float:
    """Heading (rotation about z) of a unit quaternion, rad."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def planar_covariance(cov6, rotate_deg: float = 0.0) -> np.ndarray:
    """dc_loc's 6 x 6 (row-major, x y z rotx roty rotz) as GTSAM's Pose2 3 x 3 (x y theta), optionally with
    the x-y axes turned by ``rotate_deg`` degrees (a deliberately wrong frame)."""
    c = np.asarray(cov6, dtype=float).reshape(6, 6)[np.ix_(PLANAR, PLANAR)]
    c = 0.5 * (c + c.T)
    if rotate_deg:
        a = math.radians(rotate_deg)
        j = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
        c = j @ c @ j.T
    return c


@dataclass
class Closure:
    """One dc_loc loop closure, planar: poses as gtsam.Pose2, the covariance as dc_loc's 6 x 6."""

    query_id: int
    match_id: int
    query_stamp: float
    match_stamp: float
    query_odom: gtsam.Pose2
    match_odom: gtsam.Pose2
    relative: gtsam.Pose2
    covariance: np.ndarray
    query_robot: int = 0
    match_robot: int = 0

    @staticmethod
    def from_msg(m) -> "Closure":
        """From a ``dc_loc/msg/LoopClosure`` (rclpy)."""

        def pose2(p):
            o = p.orientation
            return gtsam.Pose2(p.position.x, p.position.y, yaw_of(o.x, o.y, o.z, o.w))

        def secs(t):
            return t.sec + t.nanosec * 1e-9

        return Closure(m.query_id, m.match_id, secs(m.query_stamp), secs(m.match_stamp),
                       pose2(m.query_odom_pose), pose2(m.match_odom_pose), pose2(m.relative_pose.pose),
                       np.array(m.relative_pose.covariance, dtype=float).reshape(6, 6),
                       getattr(m, "query_robot", 0), getattr(m, "match_robot", 0))

    @staticmethod
    def from_record(r: dict) -> "Closure":
        """From a ``dc_loc run --out`` JSON-lines record (poses as x, y, z, qx, qy, qz, qw)."""

        def pose2(p):
            return gtsam.Pose2(p["x"], p["y"], yaw_of(p["qx"], p["qy"], p["qz"], p["qw"]))

        return Closure(r["query_id"], r["match_id"], r["query_stamp"], r["match_stamp"],
                       pose2(r["query_odom_pose"]), pose2(r["match_odom_pose"]), pose2(r["relative_pose"]),
                       np.array(r["covariance"], dtype=float).reshape(6, 6),
                       r.get("query_robot", 0), r.get("match_robot", 0))


class PathLength:
    """The odometry's driven path length by stamp (from its positions), for the odometry noise model."""

    def __init__(self) -> None:
        self.stamps: list[float] = []
        self.lengths: list[float] = []
        self._last: tuple[float, float] | None = None

    def add(self, stamp: float, x: float, y: float) -> None:
        """One odometry sample; samples out of stamp order are skipped."""
        if self.stamps and stamp <= self.stamps[-1]:
            return
        s = 0.0
        if self._last is not None:
            s = self.lengths[-1] + math.hypot(x - self._last[0], y - self._last[1])
        self.stamps.append(stamp)
        self.lengths.append(s)
        self._last = (x, y)

    def at(self, stamp: float) -> float | None:
        """Path length at ``stamp`` (linear between samples), ``None`` outside the samples."""
        if not self.stamps or stamp < self.stamps[0] or stamp > self.stamps[-1]:
            return None
        i = bisect.bisect_left(self.stamps, stamp)
        if self.stamps[i] == stamp:
            return self.lengths[i]
        t0, t1 = self.stamps[i - 1], self.stamps[i]
        return self.lengths[i - 1] + (stamp - t0) / (t1 - t0) * (self.lengths[i] - self.lengths[i - 1])


@dataclass
class OdometryNoise:
    """Odometry noise model: standard deviations growing with the path between two keyframes."""

    sigma_per_m: float = 0.03
    yaw_sigma_per_m: float = 5e-4
    min_sigma: float = 0.01
    min_yaw_sigma: float = 1e-3

    def model(self, distance: float):
        s = max(self.min_sigma, self.sigma_per_m * distance)
        r = max(self.min_yaw_sigma, self.yaw_sigma_per_m * distance)
        return gtsam.noiseModel.Diagonal.Sigmas(np.array([s, s, r]))


def key(keyframe_id: int) -> int:
    return gtsam.symbol("x", keyframe_id)


def odometry_poses(closures: list[Closure]) -> dict[int, tuple[float, gtsam.Pose2]]:
    """Every keyframe the closures name: id -> (stamp, odometry pose)."""
    kfs: dict[int, tuple[float, gtsam.Pose2]] = {}
    for c in closures:
        kfs[c.match_id] = (c.match_stamp, c.match_odom)
        kfs[c.query_id] = (c.query_stamp, c.query_odom)
    return kfs


def add_odometry_chain(graph, order, kfs, path, noise, key) -> None:
    """A ``BetweenFactorPose2`` between consecutive keyframes of ``order`` (keys ``key(k)``), measuring
    their relative odometry pose, with the noise of the path the odometry drove between them (the
    straight distance when ``path`` does not cover them)."""
    for a, b in zip(order, order[1:]):
        (ta, pa), (tb, pb) = kfs[a], kfs[b]
        d = None
        if path is not None:
            sa, sb = path.at(ta), path.at(tb)
            d = sb - sa if sa is not None and sb is not None else None
        if d is None:
            d = math.hypot(pb.x() - pa.x(), pb.y() - pa.y())
        graph.add(gtsam.BetweenFactorPose2(key(a), key(b), pa.between(pb), noise.model(d)))


def build_graph(closures: list[Closure], path: PathLength | None = None,
                noise: OdometryNoise | None = None, rotate_covariance_deg: float = 0.0):
    """The factor graph and its initial values (the odometry poses) from ``closures``; the last closure of a
    (query, match) pair counts. Returns (graph, initial, keyframes) with keyframes as ``odometry_poses``."""
    noise = noise or OdometryNoise()
    unique = {(c.query_id, c.match_id): c for c in closures}
    kfs = odometry_poses(list(unique.values()))
    order = sorted(kfs, key=lambda k: (kfs[k][0], k))
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for k in order:
        initial.insert(key(k), kfs[k][1])
    if not order:
        return graph, initial, kfs
    anchor = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-5]))
    graph.add(gtsam.PriorFactorPose2(key(order[0]), kfs[order[0]][1], anchor))
    add_odometry_chain(graph, order, kfs, path, noise, key)
    for c in unique.values():
        cov = planar_covariance(c.covariance, rotate_covariance_deg)
        graph.add(gtsam.BetweenFactorPose2(key(c.match_id), key(c.query_id), c.relative,
                                           gtsam.noiseModel.Gaussian.Covariance(cov)))
    return graph, initial, kfs


def optimise(closures: list[Closure], path: PathLength | None = None, noise: OdometryNoise | None = None,
             rotate_covariance_deg: float = 0.0) -> list[tuple[int, float, float, float, float]]:
    """The optimised keyframe poses, oldest first: (id, stamp, x, y, yaw)."""
    graph, initial, kfs = build_graph(closures, path, noise, rotate_covariance_deg)
    if initial.size() == 0:
        return []
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    rows = []
    for k in sorted(kfs, key=lambda k: (kfs[k][0], k)):
        p = result.atPose2(key(k))
        rows.append((k, kfs[k][0], p.x(), p.y(), p.theta()))
    return rows


# ---- several robots ---------------------------------------------------------------------------------------

# Key letter of each robot id (gtsam.Symbol: a character and a 56-bit index).
ROBOT_LETTERS = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"


def fleet_key(robot: int, keyframe_id: int) -> int:
    """The key of keyframe ``keyframe_id`` of robot ``robot``: ``Symbol(ROBOT_LETTERS[robot], id)``."""
    if not 0 <= robot < len(ROBOT_LETTERS):
        raise ValueError(f"robot id {robot} outside 0..{len(ROBOT_LETTERS) - 1}")
    return gtsam.symbol(ROBOT_LETTERS[robot], keyframe_id)


def fleet_odometry_poses(closures: list[Closure]) -> dict[tuple[int, int], tuple[float, gtsam.Pose2]]:
    """Every keyframe the closures name: (robot, id) -> (stamp, pose in that robot's odometry frame)."""
    kfs: dict[tuple[int, int], tuple[float, gtsam.Pose2]] = {}
    for c in closures:
        kfs[(c.match_robot, c.match_id)] = (c.match_stamp, c.match_odom)
        kfs[(c.query_robot, c.query_id)] = (c.query_stamp, c.query_odom)
    return kfs


def place_robots(closures: list[Closure], anchor: int) -> dict[int, gtsam.Pose2]:
    """Each robot's odometry frame in the anchor robot's, from its first closure (by query stamp) onto a
    robot already placed; robots not linked to the anchor are missing."""
    frames = {anchor: gtsam.Pose2()}
    ordered = sorted(closures, key=lambda c: (c.query_stamp, c.match_stamp))
    changed = True
    while changed:
        changed = False
        for c in ordered:
            q, m = c.query_robot, c.match_robot
            if q == m or (q in frames) == (m in frames):
                continue
            if m in frames:  # T_w_oq = T_w_om * match_odom * relative * query_odom^-1
                frames[q] = frames[m].compose(c.match_odom).compose(c.relative).compose(c.query_odom.inverse())
            else:  # T_w_om = T_w_oq * query_odom * relative^-1 * match_odom^-1
                frames[m] = (frames[q].compose(c.query_odom).compose(c.relative.inverse())
                             .compose(c.match_odom.inverse()))
            changed = True
    return frames


def build_fleet_graph(closures: list[Closure], paths: dict[int, PathLength] | None = None,
                      noise: OdometryNoise | None = None, anchor: int | None = None,
                      rotate_covariance_deg: float = 0.0):
    """The fleet's factor graph and initial values (module documentation); the last closure of a pair
    counts. Returns (graph, initial, keyframes) with keyframes (robot, id) -> (stamp, odometry pose) of the
    placed robots only."""
    noise = noise or OdometryNoise()
    paths = paths or {}
    unique = {(c.query_robot, c.query_id, c.match_robot, c.match_id): c for c in closures}
    all_kfs = fleet_odometry_poses(list(unique.values()))
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    if not all_kfs:
        return graph, initial, {}
    if anchor is None:
        anchor = min(r for r, _ in all_kfs)
    frames = place_robots(list(unique.values()), anchor)
    kfs = {k: v for k, v in all_kfs.items() if k[0] in frames}
    for robot in sorted(frames):
        order = sorted((k for k in kfs if k[0] == robot), key=lambda k: (kfs[k][0], k[1]))
        for k in order:
            initial.insert(fleet_key(*k), frames[robot].compose(kfs[k][1]))
        if robot == anchor and order:
            prior = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-5]))
            graph.add(gtsam.PriorFactorPose2(fleet_key(*order[0]), kfs[order[0]][1], prior))
        path = paths.get(robot)
        add_odometry_chain(graph, order, kfs, path, noise, lambda k: fleet_key(*k))
    for c in unique.values():
        if c.query_robot not in frames or c.match_robot not in frames:
            continue
        cov = planar_covariance(c.covariance, rotate_covariance_deg)
        graph.add(gtsam.BetweenFactorPose2(fleet_key(c.match_robot, c.match_id),
                                           fleet_key(c.query_robot, c.query_id), c.relative,
                                           gtsam.noiseModel.Gaussian.Covariance(cov)))
    return graph, initial, kfs


def optimise_fleet(closures: list[Closure], paths: dict[int, PathLength] | None = None,
                   noise: OdometryNoise | None = None, anchor: int | None = None,
                   rotate_covariance_deg: float = 0.0) -> list[tuple[int, int, float, float, float, float]]:
    """The optimised keyframe poses of the placed robots in the anchor's odometry frame, by robot, oldest
    first: (robot, id, stamp, x, y, yaw)."""
    graph, initial, kfs = build_fleet_graph(closures, paths, noise, anchor, rotate_covariance_deg)
    if initial.size() == 0:
        return []
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    rows = []
    for k in sorted(kfs, key=lambda k: (k[0], kfs[k][0], k[1])):
        p = result.atPose2(fleet_key(*k))
        rows.append((k[0], k[1], kfs[k][0], p.x(), p.y(), p.theta()))
    return rows


def write_csv(path: Path, rows) -> None:
    """Rows (key, stamp, x, y, yaw), or a fleet's (robot, key, stamp, x, y, yaw)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        fleet = bool(rows) and len(rows[0]) == 6
        w.writerow((["robot"] if fleet else []) + ["key", "stamp", "x", "y", "yaw"])
        for row in rows:
            *ids, t, x, y, yaw = row
            w.writerow([*ids, repr(t), repr(x), repr(y), repr(yaw)])


def write_tum(path: Path, rows) -> None:
    with open(path, "w") as f:
        for *_, t, x, y, yaw in rows:
            f.write(f"{t:.9f} {x!r} {y!r} 0.0 0.0 0.0 {math.sin(yaw / 2)!r} {math.cos(yaw / 2)!r}\n")


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--odom", default="/odom", help="nav_msgs/Odometry topic (default /odom)")
    ap.add_argument("--closures", action="append",
                    help="dc_loc/msg/LoopClosure topic (default /dc_loc/loop_closures); with --fleet, "
                         "repeat it for each node")
    ap.add_argument("--fleet", action="store_true",
                    help="several robots: keys per (robot, keyframe id), one odometry chain per robot")
    ap.add_argument("--robot-odom", action="append", default=[], metavar="ROBOT=TOPIC",
                    help="with --fleet: robot ROBOT's nav_msgs/Odometry topic (path lengths), repeatable")
    ap.add_argument("--anchor", type=int, help="with --fleet: the robot anchored (default the lowest id)")
    ap.add_argument("--out", type=Path, help="CSV written at exit: key, stamp, x, y, yaw")
    ap.add_argument("--tum", type=Path, help="TUM trajectory written at exit")
    ap.add_argument("--every", type=int, default=1, help="re-optimise after this many closures (default 1)")
    ap.add_argument("--odom-sigma", type=float, default=0.03, help="odometry x, y sigma per metre (0.03)")
    ap.add_argument("--odom-yaw-sigma", type=float, default=5e-4,
                    help="odometry heading sigma per metre, rad (5e-4)")
    ap.add_argument("--odom-min-sigma", type=float, default=0.01, help="smallest odometry x, y sigma, m")
    ap.add_argument("--odom-min-yaw-sigma", type=float, default=1e-3,
                    help="smallest odometry heading sigma, rad")
    ap.add_argument("--rotate-covariance", type=float, default=0.0, metavar="DEG",
                    help="turn each closure's x-y covariance by DEG degrees (a deliberately wrong frame)")
    ap.add_argument("--node-name", default="dc_loc_backend_gtsam")
    a = ap.parse_args(argv)
    a.closures = a.closures or ["/dc_loc/loop_closures"]
    if len(a.closures) > 1 and not a.fleet:
        ap.error("several --closures topics need --fleet")
    if (a.robot_odom or a.anchor is not None) and not a.fleet:
        ap.error("--robot-odom and --anchor need --fleet")
    try:
        a.robot_odom = {int(r): t for r, t in (x.split("=", 1) for x in a.robot_odom)}
    except ValueError:
        ap.error("--robot-odom takes ROBOT=TOPIC")
    return a


class BackendNode:
    """The ROS side: odometry and closures in, the optimised keyframes out (``~/optimized_path``)."""

    def __init__(self, node, a: argparse.Namespace) -> None:
        from nav_msgs.msg import Odometry, Path as PathMsg
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        from dc_loc.msg import LoopClosure

        self.node, self.a = node, a
        self.path = PathLength()
        self.paths = {robot: PathLength() for robot in a.robot_odom}
        self.closures: list[Closure] = []
        self.rows: list = []
        self.odom_frame = "odom"
        self.noise = OdometryNoise(a.odom_sigma, a.odom_yaw_sigma, a.odom_min_sigma, a.odom_min_yaw_sigma)
        # The node publishes closures reliable and transient local: a late start still gets the history.
        closures_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                                  reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.TRANSIENT_LOCAL)
        odom_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                              reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        if a.fleet:
            for robot, topic in a.robot_odom.items():
                node.create_subscription(Odometry, topic, lambda m, r=robot: self.on_robot_odometry(r, m),
                                         odom_qos)
        else:
            node.create_subscription(Odometry, a.odom, self.on_odometry, odom_qos)
        for topic in a.closures:
            node.create_subscription(LoopClosure, topic, self.on_closure, closures_qos)
        self.path_pub = node.create_publisher(PathMsg, "~/optimized_path", 1)

    def on_odometry(self, m) -> None:
        self.odom_frame = m.header.frame_id or self.odom_frame
        p = m.pose.pose.position
        self.path.add(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, p.x, p.y)

    def on_robot_odometry(self, robot: int, m) -> None:
        p = m.pose.pose.position
        self.paths[robot].add(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, p.x, p.y)

    def optimise(self) -> list:
        if self.a.fleet:
            return optimise_fleet(self.closures, self.paths, self.noise, self.a.anchor, self.a.rotate_covariance)
        return optimise(self.closures, self.path, self.noise, self.a.rotate_covariance)

    def on_closure(self, m) -> None:
        self.closures.append(Closure.from_msg(m))
        if len(self.closures) % max(1, self.a.every) == 0:
            self.update()

    def update(self) -> None:
        self.rows = self.optimise()
        self.publish()
        self.node.get_logger().info(f"optimised {len(self.rows)} keyframes, {len(self.closures)} closures")

    def publish(self) -> None:
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Path as PathMsg

        msg = PathMsg()
        msg.header.frame_id = self.odom_frame
        for *_, t, x, y, yaw in self.rows:
            ps = PoseStamped()
            ps.header.frame_id = self.odom_frame
            ps.header.stamp.sec = int(math.floor(t))
            ps.header.stamp.nanosec = min(999_999_999, int(round((t - math.floor(t)) * 1e9)))
            ps.pose.position.x, ps.pose.position.y = x, y
            ps.pose.orientation.z, ps.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            msg.poses.append(ps)
        if msg.poses:
            msg.header.stamp = msg.poses[-1].header.stamp
        self.path_pub.publish(msg)

    def finish(self) -> None:
        """The final optimisation, written to --out and --tum."""
        self.rows = self.optimise()
        if self.a.out:
            write_csv(self.a.out, self.rows)
        if self.a.tum:
            write_tum(self.a.tum, self.rows)
        odometry = sum(len(p.stamps) for p in self.paths.values()) if self.a.fleet else len(self.path.stamps)
        print(f"backend_gtsam: {len(self.rows)} keyframes, {len(self.closures)} closures, "
              f"{odometry} odometry messages", flush=True)


# The longest the back end waits for ROS traffic before it looks at SIGINT / SIGTERM again (s).
SIGNAL_POLL_SECONDS = 0.2


def main(argv=None) -> int:
    """Spins until SIGINT or SIGTERM, then optimises once more and writes ``--out`` / ``--tum`` (a second
    signal interrupts that).

    The signals are this script's, not rclpy's: rclpy's wake-up of a blocked wait on SIGINT is
    sometimes lost, leaving the back end waiting for traffic that never comes. Here a handler only sets
    a flag, and each wait lasts at most ``SIGNAL_POLL_SECONDS``, so the flag is seen within that time."""
    import signal

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    a = parse_args(argv)
    stop = []

    def on_signal(signum, frame) -> None:
        if stop:  # a second signal abandons the final optimisation
            raise KeyboardInterrupt
        stop.append(signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(a.node_name)
    backend = BackendNode(node, a)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    print("backend_gtsam: running", flush=True)
    try:
        while not stop:
            executor.spin_once(timeout_sec=SIGNAL_POLL_SECONDS)
    finally:
        backend.finish()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
