"""A fleet of dc_loc nodes sharing keyframes over DDS, as real ROS 2 users see it. Run by tests/fleet_nodes.rs
with the venv's interpreter:

    test_fleet_nodes.py --node BIN --fleet DIR --out RESULT.json [--rate R]
                        [--concurrent 0,1] [--late 2] [--backend]
                        [--fleet-history H --fleet-rate F] [--flood ROBOT] [-- EXTRA NODE ARGS...]

DIR is what ``dc_loc sim --fleet N`` writes: ``DIR/robot_<k>/`` holds robot k's bag and ``dc_loc.yaml``.

1. Reserves a ROS domain id of its own; everything stays on loopback (dcloc_testlib).
2. Starts one node per robot of ``--concurrent``: ``BIN --ros-args --params-file robot_<k>.yaml
   -r __ns:=/robot_<k> -p node.robot_id:=k -p node.fleet:=true -r <input>:=/robot_<k><input> ...`` (every
   radar and odometry topic of the bag remapped into the robot's namespace), ``--fleet-history H``:
   ``-p node.fleet_history:=H``, ``--fleet-rate F``: ``-p node.fleet_rate:=F``, then EXTRA NODE ARGS.
   ``robot_<k>.yaml`` (beside RESULT.json) is ``DIR/robot_<k>/dc_loc.yaml`` with its ``dc_loc:`` section
   renamed ``/robot_<k>/dc_loc:``: as in ROS 2, a bare ``dc_loc:`` means ``/dc_loc``, not a namespaced node.
3. rclpy (one participant): publishers of each robot's inputs (reliable, volatile, depth 1000), a
   ``dc_loc/msg/LoopClosure`` subscriber on each node's ``/robot_<k>/dc_loc/loop_closures``, a
   ``dc_loc/msg/Keyframe`` subscriber on ``/dc_loc/keyframes`` (reliable, transient local, depth 5000),
   ``/diagnostics`` (told apart by ``hardware_id``, the node's fully qualified name).
4. Replays the bags of ``--concurrent`` together (raw CDR, original stamps, each from its own start, at
   ``--rate`` times real time; test_backend_replay.replay), waits until each node has received and
   processed every message, every closure it counts has arrived and nothing changes over two more
   diagnostics messages of every node.
   Each node's diagnostics must also count every keyframe the other running robots published as
   received (``fleet.robot_<j>: "received N, added N, ..."``).
   ``--flood ROBOT``: meanwhile, a quarter into that replay, an rclpy publisher on ``/dc_loc/keyframes``
   (``dc_loc/msg/Keyframe``, reliable, transient local, depth 1000) floods the running nodes as a fake robot
   of id ROBOT: first a handful of malformed keyframes (``FLOOD_MALFORMED``: covariances not 3 a point, a
   quaternion of zeros, ...), and once every running node counts them as ``bad_keyframe``, as fast as it
   can H + 500 well-formed ones (H ``--fleet-history``, default the node's 1000; 20 random points each,
   ids and stamps increasing, stamps an hour after the last robot's start, a finite pose). Then it waits
   until each node's ``fleet.robot_<ROBOT>`` counts every flood message (received + over rate + bad) or
   stop changing over two diagnostics messages, and notes the time since the first well-formed one was
   sent (``summary.flood``: per node the counts, the dropped counters, those seconds). The publisher is
   destroyed once the robots of ``--concurrent`` settled, before the late joiners start. The flood's
   keyframes are kept out of ``keyframes``, and closures naming its robot out of ``closures`` (they are
   ``flood_closures``, not judged).
5. The late joiner (``--late``): only now its node starts; it has to take the earlier robots' keyframes from
   the transient-local history of ``/dc_loc/keyframes``: once its diagnostics count them all received, its
   bag is replayed, and step 4's wait again.
6. Stops the nodes, alternating SIGINT and SIGTERM (robot 0 SIGINT, robot 1 SIGTERM, ...): each must exit 0.
7. Judges (below) and writes RESULT.json: ``summary`` (what tests/fleet_nodes.rs asserts), ``closures``
   (dc_loc's ClosureRecord JSON objects with ``query_robot``, ``match_robot``, ``topic_robot`` and the
   judged errors), ``keyframes`` ([robot, session, id, stamp, x, y, yaw] of every Keyframe message, odometry
   frame), ``robots`` (per robot: messages sent, replay time, exit code, its last diagnostics).
   ``--backend``: also optimises every robot's keyframes in one pose graph with examples/backend_gtsam.py
   (``optimise_fleet``: one odometry chain per robot, robot ``--concurrent[0]`` anchored, the others placed
   by their first closure onto an already placed robot) and reports the absolute trajectory error of all
   robots together against the ground truth after one rigid alignment (``summary.backend``).
Exit code 0 when the run went through (the checks are the Rust test's), 1 otherwise.

Judging, as ``judge`` in crates/lab/src/eval/revisits.rs with crates/lab/src/eval/fleet.rs's robots for passes:
- ground truth: each bag's ``/ground_truth/odom`` (frame ``map``, one world frame for the whole fleet),
  interpolated linearly (heading unwrapped) at a keyframe's stamp;
- a closure is correct when the translation of ``relative_pose`` (T_match_query) is within 2.0 m of the
  ground truth's ``T_map_match^-1 T_map_query`` (crates/lab/src/eval/revisits.rs FALSE_CLOSURE_THRESHOLD); its
  rotation error is reported, not used;
- an opportunity is a keyframe whose ground-truth pose lies within 5.0 m (SAME_RADIUS) of a keyframe of
  another robot with an older stamp, the two headings within 90 degrees; it is found when the keyframe is
  the newer keyframe of a correct inter-robot closure (its query, or its match when the other keyframe is
  older: the pair is registered by the node that already held the other's keyframe when it made its own,
  which may be the older keyframe's node). Recall = found / opportunities. Precision = correct
  inter-robot closures / inter-robot closures.
Where this differs from the offline evaluation:
- offline, a robot's pass is its index, its keyframes reach the others 0.5 s (of drive time) after they
  are made, and the robots' drives are interleaved by the time since each one's start, the last of three
  joining after the others; here "earlier" is an older stamp (the same order for ``dc_loc sim --fleet``:
  robot k's clock starts 3600 k s later), keyframes arrive when DDS delivers them, and the interleaving is
  the replay's at ``--rate``;
- offline, keyframes' truth is the simulator's exact state at the stamp (``SimDrive::state_at``); here it is
  interpolated from the bag's ground-truth samples (tests/fleet_nodes.rs compares both);
- offline also counts opposite-direction opportunities (within 5 m plus twice the lane offset) and their
  recall; here opposite-direction closures count in precision only, and recall is same-direction only;
- offline, an opportunity is closed by any correct closure in which it is the later pass's keyframe (also
  one within its own robot); here only by a correct inter-robot closure. Keyframes in a U-turn are
  excluded offline (a fleet drive has none);
- offline precision is per direction over all closures; here it is over the inter-robot closures (the
  closures within one robot are judged and reported separately).
Also reported: pairs published more than once across the fleet (as an unordered pair of (robot, id)
keyframes), inter-robot closures registered by the node whose keyframe is the older one (allowed: it held
the other's keyframe when it made its own), closures naming a keyframe that was not seen on
``/dc_loc/keyframes`` (or with another stamp), closures with ``query_robot`` other than the publishing
node's id, the late joiner's closures onto the earlier robots, and the accepted alignments the Keyframe
messages carry, each against the ground truth at the two keyframes of the closure that gave it
(``shared_alignments``, ``judge_shared_alignments``).
"""

import argparse
import json
import math
import random
import re
import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dcloc_testlib as tl
from test_backend_replay import replay
from test_node_replay import read_bag, record

FLEET_TOPIC = "/dc_loc/keyframes"
GROUND_TRUTH_TOPIC = "/ground_truth/odom"
FALSE_CLOSURE_THRESHOLD = 2.0  # m, crates/lab/src/eval/revisits.rs
SAME_RADIUS = 5.0  # m, crates/lab/src/eval/revisits.rs
SAME_DIRECTION = 0.5 * math.pi  # headings closer than this are the same direction (is_reverse)
STAMP_TOLERANCE = 1e-6  # s, a Keyframe's stamp against a closure's
FLOOD_EXTRA = 500  # well-formed flood keyframes beyond node.fleet_history
FLOOD_POINTS = 20  # points of a flood keyframe
FLOOD_START = 0.25  # of the concurrent replay's duration
NODE_FLEET_HISTORY, NODE_FLEET_RATE = 1000, 10.0  # the node's defaults
# The malformed keyframes of a flood: what crates/core/src/fleet/wire.rs decode refuses (bad_keyframe).
FLOOD_MALFORMED = ("covariances 2 a point", "quaternion of zeros", "odd point coordinates", "NaN position",
                   "heard robots without ids", "negative path length", "alignment without its paths")


def secs(t) -> float:
    return t.sec + t.nanosec * 1e-9


def wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float:
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def robot_ns(k: int) -> str:
    return f"/robot_{k}"


# ---- ground truth ----------------------------------------------------------------------------------------


class GroundTruth:
    """One robot's ``/ground_truth/odom`` (map frame), interpolated at any stamp inside it."""

    def __init__(self, bag: Path) -> None:
        import numpy as np
        from nav_msgs.msg import Odometry
        from rclpy.serialization import deserialize_message
        from rosbags.rosbag2 import Reader

        rows = []
        with Reader(bag) as reader:
            conns = [c for c in reader.connections if c.topic == GROUND_TRUTH_TOPIC]
            for _, _, raw in reader.messages(connections=conns):
                m = deserialize_message(bytes(raw), Odometry)
                p, q = m.pose.pose.position, m.pose.pose.orientation
                rows.append((secs(m.header.stamp), p.x, p.y, yaw_of(q.x, q.y, q.z, q.w)))
        if len(rows) < 2:
            raise RuntimeError(f"{bag}: fewer than two {GROUND_TRUTH_TOPIC} messages")
        rows.sort()
        a = np.array(rows)
        self.t, self.x, self.y = a[:, 0], a[:, 1], a[:, 2]
        self.yaw = np.unwrap(a[:, 3])

    def at(self, stamp: float) -> tuple[float, float, float]:
        """(x, y, yaw) at ``stamp``; ValueError outside the samples (beyond 0.1 s)."""
        import numpy as np

        if stamp < self.t[0] - 0.1 or stamp > self.t[-1] + 0.1:
            raise ValueError(f"stamp {stamp:.3f} outside the ground truth {self.t[0]:.3f}..{self.t[-1]:.3f}")
        return (float(np.interp(stamp, self.t, self.x)), float(np.interp(stamp, self.t, self.y)),
                wrap(float(np.interp(stamp, self.t, self.yaw))))


def relative(m: tuple, q: tuple) -> tuple[float, float, float]:
    """``m^-1 * q`` of planar poses (x, y, yaw)."""
    dx, dy = q[0] - m[0], q[1] - m[1]
    c, s = math.cos(m[2]), math.sin(m[2])
    return (c * dx + s * dy, -s * dx + c * dy, wrap(q[2] - m[2]))


# ---- judging ---------------------------------------------------------------------------------------------


def judge(closures: list[dict], keyframes: list[dict], truth: dict[int, GroundTruth], late: list[int]) -> dict:
    """The summary (module documentation); annotates each closure with its errors in place.

    ``closures``: records with ``query_robot``, ``match_robot``, ``topic_robot``; ``keyframes``: dicts with
    ``robot``, ``id``, ``stamp`` (the Keyframe messages)."""
    kf_stamp = {}
    for k in keyframes:
        kf_stamp.setdefault((k["robot"], k["id"]), k["stamp"])
    kf_truth = {}
    for k in keyframes:
        key = (k["robot"], k["id"])
        if key not in kf_truth and k["robot"] in truth:
            kf_truth[key] = truth[k["robot"]].at(k["stamp"])

    inter, intra = [], []
    unknown, wrong_robot, older_query = [], [], []
    seen_pairs: dict = {}
    for c in closures:
        qk, mk = (c["query_robot"], c["query_id"]), (c["match_robot"], c["match_id"])
        for key, stamp in ((qk, c["query_stamp"]), (mk, c["match_stamp"])):
            if key not in kf_stamp or abs(kf_stamp[key] - stamp) > STAMP_TOLERANCE:
                unknown.append({"keyframe": list(key), "stamp": stamp, "seen_stamp": kf_stamp.get(key)})
        if c["query_robot"] != c["topic_robot"]:
            wrong_robot.append([c["topic_robot"], c["query_robot"]])
        pair = tuple(sorted([qk, mk]))
        seen_pairs.setdefault(pair, []).append(c["topic_robot"])
        tq = truth[c["query_robot"]].at(c["query_stamp"])
        tm = truth[c["match_robot"]].at(c["match_stamp"])
        want = relative(tm, tq)
        r = c["relative_pose"]
        got_yaw = yaw_of(r["qx"], r["qy"], r["qz"], r["qw"])
        c["translation_error"] = math.hypot(want[0] - r["x"], want[1] - r["y"])
        c["rotation_error"] = abs(wrap(want[2] - got_yaw))
        c["truth_distance"] = math.hypot(want[0], want[1])
        c["reverse"] = abs(wrap(tq[2] - tm[2])) > SAME_DIRECTION
        c["correct"] = c["translation_error"] <= FALSE_CLOSURE_THRESHOLD
        if c["query_robot"] != c["match_robot"]:
            inter.append(c)
            if c["query_stamp"] < c["match_stamp"]:
                older_query.append([list(qk), list(mk)])
        else:
            intra.append(c)
    duplicates = [[list(p[0]), list(p[1]), by] for p, by in seen_pairs.items() if len(by) > 1]

    # Opportunities: keyframes with an older keyframe of another robot within 5 m, same direction.
    kfs = sorted(kf_truth.items(), key=lambda kv: kf_stamp[kv[0]])
    opportunities = []
    for key, p in kfs:
        for other, o in kfs:
            if other[0] == key[0] or kf_stamp[other] >= kf_stamp[key]:
                continue
            if (math.hypot(p[0] - o[0], p[1] - o[1]) <= SAME_RADIUS
                    and abs(wrap(p[2] - o[2])) <= SAME_DIRECTION):
                opportunities.append(key)
                break
    found_queries = set()  # the newer keyframe of each correct inter-robot closure
    for c in inter:
        if c["correct"]:
            newer = "query" if c["query_stamp"] >= c["match_stamp"] else "match"
            found_queries.add((c[f"{newer}_robot"], c[f"{newer}_id"]))
    found = [k for k in opportunities if k in found_queries]

    def stats(cs: list[dict]) -> dict:
        good = [c for c in cs if c["correct"]]
        return {
            "published": len(cs),
            "correct": len(good),
            "precision": len(good) / len(cs) if cs else 1.0,
            "reverse": sum(c["reverse"] for c in cs),
            "max_translation_error": max((c["translation_error"] for c in good), default=0.0),
            "max_rotation_error": max((c["rotation_error"] for c in good), default=0.0),
            "median_translation_error": sorted(c["translation_error"] for c in cs)[len(cs) // 2] if cs else 0.0,
            "false": [[c["query_robot"], c["query_id"], c["match_robot"], c["match_id"],
                       round(c["translation_error"], 3), round(c["rotation_error"], 4)]
                      for c in cs if not c["correct"]],
        }

    by_pair: dict = {}
    for c in inter:
        key = f"{c['query_robot']}->{c['match_robot']}"
        by_pair[key] = by_pair.get(key, 0) + 1
    late_cs = [c for c in inter if c["query_robot"] in late and c["match_robot"] not in late]
    opp_by_robot: dict = {}
    for k in opportunities:
        d = opp_by_robot.setdefault(str(k[0]), {"opportunities": 0, "found": 0})
        d["opportunities"] += 1
        d["found"] += k in found_queries
    return {
        "keyframes": {str(r): sum(1 for k in kf_stamp if k[0] == r) for r in sorted({k[0] for k in kf_stamp})},
        "inter_robot": stats(inter),
        "intra_robot": stats(intra),
        "inter_robot_by_robots": by_pair,
        "duplicates": duplicates,
        "published_by_older": older_query,
        "unknown_keyframes": unknown,
        "wrong_query_robot": wrong_robot,
        "opportunities": len(opportunities),
        "found": len(found),
        "recall": len(found) / len(opportunities) if opportunities else float("nan"),
        "by_robot": opp_by_robot,
        "missed": [list(k) for k in opportunities if k not in found_queries],
        "late_joiner": {
            "robots": late,
            "closures": len(late_cs),
            "correct": sum(c["correct"] for c in late_cs),
            "onto": {str(r): sum(1 for c in late_cs if c["match_robot"] == r)
                     for r in sorted({c["match_robot"] for c in late_cs})},
        },
    }


def judge_shared_alignments(keyframes: list[dict], truth: dict[int, GroundTruth]) -> dict:
    """The alignments the Keyframe messages carry (``aligned_*``), each against the ground truth at the two
    keyframes of the closure that gave it: the sender's keyframe at the alignment's first path length and the
    other robot's at its second, both found among the Keyframe messages by robot, session and path length.
    An alignment T (the sender's odometry frame in the other's) says the sender's keyframe lies at
    ``P_other^-1 T P_sender`` from the other's; the truth is ``G_other^-1 G_sender``. ``unmatched``: alignments
    whose keyframes the topic did not carry."""
    by_path = {}
    for k in keyframes:
        by_path.setdefault((k["robot"], k["session"], round(k["path"], 6)), k)
    seen, errors, unmatched = set(), [], []
    for k in keyframes:
        for robot, session, x, y, yaw, path, match_path in k["aligned"]:
            key = (k["robot"], k["session"], robot, session, x, y, yaw, path, match_path)
            if key in seen:
                continue
            seen.add(key)
            q = by_path.get((k["robot"], k["session"], round(path, 6)))
            m = by_path.get((robot, session, round(match_path, 6)))
            if q is None or m is None or robot not in truth:
                unmatched.append(list(key))
                continue
            c, s_ = math.cos(yaw), math.sin(yaw)
            qx, qy = x + c * q["x"] - s_ * q["y"], y + s_ * q["x"] + c * q["y"]
            said = relative((m["x"], m["y"], m["yaw"]), (qx, qy, wrap(yaw + q["yaw"])))
            want = relative(truth[robot].at(m["stamp"]), truth[k["robot"]].at(q["stamp"]))
            errors.append(math.hypot(said[0] - want[0], said[1] - want[1]))
    return {
        "count": len(errors),
        "correct": sum(e <= FALSE_CLOSURE_THRESHOLD for e in errors),
        "max_error": max(errors, default=0.0),
        "unmatched": unmatched,
    }


# ---- the back end over the fleet -------------------------------------------------------------------------


def backend_check(closures: list[dict], truth: dict[int, GroundTruth], fleet: Path, anchor: int) -> dict:
    """examples/backend_gtsam.py's fleet graph of ``closures``, and its ATE after one rigid alignment of all
    robots together (``ate``; ``ate_initial`` that of the starting values: each robot's odometry placed by
    its first closure onto a placed robot; ``per_robot`` each robot aligned on its own)."""
    import numpy as np
    from test_backend_graph import load_backend, odometry_path

    backend = load_backend()
    robots = sorted(truth)
    paths = {k: odometry_path(backend, fleet / f"robot_{k}") for k in robots}
    cs = [backend.Closure.from_record(c) for c in closures]
    rows = backend.optimise_fleet(cs, paths, anchor=anchor)
    if not rows:
        return {"keyframes": 0}
    est = np.array([[x, y] for _, _, _, x, y, _ in rows])
    gt = np.array([truth[r].at(t)[:2] for r, _, t, _, _, _ in rows])
    ate, _ = rigid_ate(est, gt)
    # The starting values: each robot's odometry, placed by its first closure onto a placed robot.
    _, initial, _ = backend.build_fleet_graph(cs, paths, anchor=anchor)
    start = np.array([[initial.atPose2(backend.fleet_key(r, i)).x(), initial.atPose2(backend.fleet_key(r, i)).y()]
                      for r, i, *_ in rows])
    per_robot = {}
    for k in robots:
        idx = [i for i, row in enumerate(rows) if row[0] == k]
        if idx:
            per_robot[str(k)] = {"keyframes": len(idx),
                                 "ate_own_alignment": rigid_ate(est[idx], gt[idx])[0]}
    placed = {r for r, *_ in rows}
    return {"keyframes": len(rows), "robots": sorted(placed), "ate": ate,
            "ate_initial": rigid_ate(start, gt)[0], "per_robot": per_robot,
            "unplaced": [k for k in robots if k not in placed]}


def rigid_ate(est, gt) -> tuple[float, list]:
    """RMS position error of ``est`` against ``gt`` (n x 2) after the best rigid 2D motion; the motion."""
    import numpy as np

    ce, cg = est.mean(axis=0), gt.mean(axis=0)
    e, g = est - ce, gt - cg
    s = float(np.sum(e[:, 0] * g[:, 1] - e[:, 1] * g[:, 0]))
    c = float(np.sum(e[:, 0] * g[:, 0] + e[:, 1] * g[:, 1]))
    a = math.atan2(s, c)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    err = (e @ rot.T) - g
    return float(math.sqrt(np.mean(np.sum(err * err, axis=1)))), [a, *(cg - rot @ ce)]


# ---- the run ---------------------------------------------------------------------------------------------


def replay_ticking(rs, pubs, messages, rate: float, tick) -> float:
    """test_backend_replay.replay, calling ``tick()`` after each message and while waiting."""
    start = time.monotonic()
    for t, topic, _, raw in messages:
        due = start + (t - messages[0][0]) * 1e-9 / rate
        while (left := due - time.monotonic()) > 0:
            rs.executor.spin_once(timeout_sec=min(left, 0.01))
            tick()
        pubs[topic].publish(raw)
        tick()
    return time.monotonic() - start


class Flood:
    """A fake robot flooding ``/dc_loc/keyframes`` (module documentation, step 4), driven by ``tick``."""

    def __init__(self, fleet, robot: int, history: int, base_stamp: float) -> None:
        self.fleet, self.robot, self.history = fleet, robot, history
        self.n = history + FLOOD_EXTRA
        self.base_stamp = base_stamp
        self.state = "idle"
        self.targets: list[int] = []
        self.start_at = 0.0
        self.times: dict[str, float] = {}
        self.observed: dict[int, dict] = {}
        self.snap: dict[int, tuple] = {}
        self.snap_diag: dict[int, int] = {}
        self.wait_note = ""
        self.seen: tuple = ()

    def setup(self, rs) -> None:
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        from dc_loc.msg import Keyframe

        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(1000, self.n + len(FLOOD_MALFORMED)),
                         reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub = rs.node.create_publisher(Keyframe, FLEET_TOPIC, qos)
        self.rs = rs
        rng = random.Random(self.robot)

        def keyframe(i: int):
            m = Keyframe()
            stamp = self.base_stamp + 0.1 * i
            m.header.stamp.sec = int(stamp)
            m.header.stamp.nanosec = int(round((stamp - int(stamp)) * 1e9)) % 1_000_000_000
            m.header.frame_id = f"robot_{self.robot}/base_link"
            m.robot_id, m.session, m.id = self.robot, 0, i
            yaw = 0.01 * i
            m.odom_pose.position.x, m.odom_pose.position.y = 0.5 * i, 0.0
            m.odom_pose.orientation.z, m.odom_pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            m.path_distance = 0.5 * i
            m.points = [rng.randint(-4000, 4000) for _ in range(2 * FLOOD_POINTS)]
            m.covariances = [rng.choice((100, 120, 140)) if j % 3 < 2 else rng.randrange(256)
                             for j in range(3 * FLOOD_POINTS)]
            return m

        self.good = [keyframe(i) for i in range(self.n)]
        bad = []
        for j, what in enumerate(FLOOD_MALFORMED):
            m = keyframe(self.n + j)
            if what == "covariances 2 a point":
                m.covariances = list(m.covariances)[:2 * FLOOD_POINTS]
            elif what == "quaternion of zeros":
                m.odom_pose.orientation.z = m.odom_pose.orientation.w = 0.0
            elif what == "odd point coordinates":
                m.points = list(m.points) + [1]
            elif what == "NaN position":
                m.odom_pose.position.x = float("nan")
            elif what == "heard robots without ids":
                m.heard_robots = [0]
            elif what == "negative path length":
                m.path_distance = -1.0
            elif what == "alignment without its paths":
                m.aligned_robots, m.aligned_sessions, m.aligned_poses = [0], [0], [1.0, 2.0, 0.5]
            bad.append(m)
        self.bad = bad

    def start(self, targets: list[int], after: float) -> None:
        self.targets = list(targets)
        self.start_at = time.monotonic() + after
        self.state = "waiting"

    def counts(self, k: int) -> tuple:
        """Robot k's node: the flood's (received, added, duplicates, refused, over rate) and its dropped
        ``bad_keyframe``, ``keyframe_over_rate``."""
        d = dict(self.fleet.d(k))
        c = self.fleet.fleet_counts(k, d).get(self.robot, {})
        return (tuple(int(c.get(n, 0)) for n in ("received", "added", "duplicates", "refused", "over_rate"))
                + (int(d.get("dc_loc: dropped/bad_keyframe", 0)), int(d.get("dc_loc: dropped/keyframe_over_rate", 0))))

    def delivered(self, k: int) -> bool:
        c = self.counts(k)
        return c[0] + c[4] + c[5] >= self.n + len(self.bad)

    def tick(self) -> bool:
        """Advances the flood; True once done (or never started)."""
        now = time.monotonic()
        if self.state in ("idle", "done"):
            return True
        if self.state in ("waiting", "bad", "settling") and now - self.start_at > 120.0:
            raise TimeoutError(f"the flood did not finish (state {self.state})")
        # The counts change only with a diagnostics message: look again only then.
        seen = tuple(self.fleet.diag_count.get(self.fleet.fqn(k), 0) for k in self.targets)
        if self.state != "waiting" and seen == self.seen:
            return False
        self.seen = seen
        if self.state == "waiting" and now >= self.start_at:
            self.times["malformed"] = now
            self.times["subscriptions"] = self.pub.get_subscription_count()
            for m in self.bad:
                self.pub.publish(m)
            self.state = "bad"
        elif self.state == "bad":
            counted = all(self.counts(k)[5] >= len(self.bad) for k in self.targets)
            if counted or now - self.times["malformed"] > 30.0:
                if not counted:
                    self.wait_note = "the malformed keyframes were not all counted within 30 s"
                self.times["bad_counted"] = now
                self.times["flood"] = time.monotonic()
                for m in self.good:
                    self.pub.publish(m)
                self.times["flood_sent"] = time.monotonic()
                self.state = "settling"
        elif self.state == "settling":
            for k in self.targets:
                if k in self.observed:
                    continue
                c = self.counts(k)
                n = self.fleet.diag_count.get(self.fleet.fqn(k), 0)
                if self.delivered(k):
                    self.observed[k] = {"elapsed_s": now - self.times["flood"], "all_delivered": True,
                                        "added_then": c[1], "over_rate_then": c[4]}
                elif self.snap.get(k) != c:
                    self.snap[k], self.snap_diag[k] = c, n
                elif n >= self.snap_diag[k] + 2:
                    self.observed[k] = {"elapsed_s": now - self.times["flood"], "all_delivered": False,
                                        "added_then": c[1], "over_rate_then": c[4]}
            if all(k in self.observed for k in self.targets):
                self.state = "done"
                return True
        return False

    def stop(self) -> None:
        """Destroys the flood's publisher (its transient-local history with it)."""
        if getattr(self, "pub", None) is not None:
            self.rs.node.destroy_publisher(self.pub)
            self.pub = None

    def summary(self, closures: list[dict]) -> dict:
        nodes = {}
        for k in self.targets:
            r, a, dup, ref, f, bad, over = self.counts(k)
            nodes[str(k)] = {"received": r, "added": a, "duplicates": dup, "refused": ref, "over_rate": f,
                             "bad_keyframe": bad, "keyframe_over_rate": over,
                             **self.observed.get(k, {"elapsed_s": None, "all_delivered": False,
                                                     "added_then": None, "over_rate_then": None})}
        return {"robot": self.robot, "sent": self.n, "malformed": len(self.bad),
                "malformed_kinds": list(FLOOD_MALFORMED), "nodes": nodes,
                "send_seconds": self.times.get("flood_sent", 0.0) - self.times.get("flood", 0.0),
                "bad_wait_seconds": self.times.get("bad_counted", 0.0) - self.times.get("malformed", 0.0),
                "subscriptions": self.times.get("subscriptions"), "note": self.wait_note,
                "closures": closures}


class Fleet:
    """The nodes, the rclpy side and what it received."""

    def __init__(self, a, env: dict) -> None:
        self.a, self.env = a, env
        self.nodes: dict[int, tl.ManagedProcess] = {}
        self.messages: dict[int, list] = {}
        self.radars: dict[int, list[str]] = {}
        self.params: dict[int, Path] = {}
        for k in a.concurrent + a.late:
            bag = a.fleet / f"robot_{k}"
            self.params[k] = namespaced_params(bag / "dc_loc.yaml", a.out.parent / f"robot_{k}.yaml",
                                               f"{robot_ns(k)}/dc_loc")
            self.messages[k] = read_bag(bag)
            self.radars[k] = radar_names(self.params[k])
        self.closures: list[dict] = []
        self.keyframes: list[dict] = []
        self.diag: dict[str, dict] = {}
        self.diag_count: dict[str, int] = {}
        self.sent: dict[int, dict] = {}
        self.replay_seconds: dict[int, float] = {}
        self.robots = set(a.concurrent + a.late)
        self.foreign_keyframes: dict[int, int] = {}  # Keyframe messages of robots not in the fleet (a flood)

    def start_node(self, k: int) -> None:
        remaps = []
        for topic in sorted({m[1] for m in self.messages[k]}):
            remaps += ["-r", f"{topic}:={robot_ns(k)}{topic}"]
        argv = [self.a.node, "--ros-args", "--params-file", str(self.params[k]), "-r", f"__ns:={robot_ns(k)}",
                "-p", f"node.robot_id:={k}", "-p", "node.fleet:=true", *remaps]
        if self.a.fleet_history is not None:
            argv += ["-p", f"node.fleet_history:={self.a.fleet_history}"]
        if self.a.fleet_rate is not None:
            argv += ["-p", f"node.fleet_rate:={self.a.fleet_rate}"]
        argv += self.a.node_args
        node = tl.ManagedProcess(argv, self.env, name=f"dc_loc robot {k}")
        self.nodes[k] = node
        node.wait_for_line(lambda l: "running" in l, 30.0, f"robot {k}'s node running line")

    def fqn(self, k: int) -> str:
        return f"{robot_ns(k)}/dc_loc"

    def d(self, k: int) -> dict:
        return self.diag.get(self.fqn(k), {})

    def setup(self, rs) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import PointCloud2

        from dc_loc.msg import Keyframe, LoopClosure

        self.rs = rs
        types = {"sensor_msgs/msg/PointCloud2": PointCloud2, "nav_msgs/msg/Odometry": Odometry}
        qos_in = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE)
        self.pubs: dict[int, dict] = {}
        self.closure_subs = {}
        for k, msgs in self.messages.items():
            pubs = self.pubs.setdefault(k, {})
            for _, topic, msgtype, _ in msgs:
                t = robot_ns(k) + topic
                if t not in pubs:
                    pubs[t] = rs.node.create_publisher(types[msgtype], t, qos_in)

            def on_closure(m, k=k):
                r = record(m)
                r["topic_robot"] = k
                self.closures.append(r)

            self.closure_subs[k] = rs.node.create_subscription(
                LoopClosure, f"{self.fqn(k)}/loop_closures", on_closure, tl.rclpy_qos_loop_closure(1000))

        def on_keyframe(m):
            if m.robot_id not in self.robots:
                self.foreign_keyframes[m.robot_id] = self.foreign_keyframes.get(m.robot_id, 0) + 1
                return
            p, q = m.odom_pose.position, m.odom_pose.orientation
            aligned = [[int(m.aligned_robots[i]), int(m.aligned_sessions[i]), *m.aligned_poses[3 * i:3 * i + 3],
                        *m.aligned_paths[2 * i:2 * i + 2]] for i in range(len(m.aligned_robots))]
            self.keyframes.append({"robot": m.robot_id, "session": m.session, "id": m.id,
                                   "stamp": secs(m.header.stamp), "x": p.x, "y": p.y,
                                   "yaw": yaw_of(q.x, q.y, q.z, q.w), "points": len(m.points) // 2,
                                   "path": m.path_distance, "aligned": aligned})

        self.keyframe_sub = rs.node.create_subscription(
            Keyframe, FLEET_TOPIC, on_keyframe,
            QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))

        def on_diag(m):
            for st in m.status:
                d = self.diag.setdefault(st.hardware_id, {})
                for kv in st.values:
                    d[f"{st.name}/{kv.key}"] = kv.value
            for hw in {st.hardware_id for st in m.status}:
                self.diag_count[hw] = self.diag_count.get(hw, 0) + 1

        self.diag_sub = rs.node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)

    def wait_matched(self, robots: list[int]) -> None:
        rs = self.rs
        for k in robots:
            for p in self.pubs[k].values():
                rs.wait_for_subscriptions(p, 1)
            rs.wait_for_publishers(self.closure_subs[k], 1)

        def matched():
            for k in robots:
                n = {key: int(v) for key, v in self.d(k).items() if key.endswith(".publishers")}
                if len(n) < 2 or not all(v >= 1 for v in n.values()):
                    return False
            return True

        rs.spin_until(matched, 30.0, f"the readers of robots {robots} to match the publishers")
        rs.spin_until(lambda: self.keyframe_sub.get_publisher_count() >= len(self.nodes), 30.0,
                      f"{len(self.nodes)} publishers on {FLEET_TOPIC}")

    def replay(self, robots: list[int], tick=None) -> None:
        """Replays ``robots``' bags together, each from its own start, at ``--rate`` (calling ``tick()``
        meanwhile when given)."""
        merged = []
        for k in robots:
            msgs = self.messages[k]
            t0 = msgs[0][0]
            merged += [(t - t0, robot_ns(k) + topic, ty, raw) for t, topic, ty, raw in msgs]
            self.sent[k] = {"radar": sum(1 for m in msgs if m[2] != "nav_msgs/msg/Odometry"),
                            "odometry": sum(1 for m in msgs if m[2] == "nav_msgs/msg/Odometry")}
        merged.sort(key=lambda m: m[0])
        pubs = {t: p for k in robots for t, p in self.pubs[k].items()}
        if tick is None:
            seconds = replay(self.rs, pubs, merged, self.a.rate)
        else:
            seconds = replay_ticking(self.rs, pubs, merged, self.a.rate, tick)
        for k in robots:
            self.replay_seconds[k] = seconds

    def processed(self, k: int) -> bool:
        """Robot k's node received and processed everything sent to it, and every closure it counts arrived."""
        d = self.d(k)
        if not d or k not in self.sent:
            return False
        odo = int(d.get("dc_loc: input/odometry.received", -1))
        radar = sum(int(d.get(f"dc_loc: input/{r}.received", 0)) for r in self.radars[k])
        queued = (int(d.get("dc_loc: processing/queue_depth", -1))
                  + int(d.get("dc_loc: processing/held_for_order", -1)))
        published = int(d.get("dc_loc: processing/closures", -1))
        got = sum(1 for c in self.closures if c["topic_robot"] == k)
        return (odo == self.sent[k]["odometry"] and radar == self.sent[k]["radar"] and queued == 0
                and got == published and self.all_delivered(k))

    def settle(self, robots: list[int], timeout: float) -> None:
        """Waits until every robot in ``robots`` is ``processed`` and nothing (closures, keyframes, counters)
        changes over two more diagnostics messages of every running node."""
        deadline = time.monotonic() + timeout
        running = sorted(self.nodes)

        def snapshot():
            counters = ("processing/closures", "processing/keyframes", "processing/queue_depth", "fleet.robot_")
            return (len(self.closures), len(self.keyframes),
                    tuple(tuple(sorted((key, v) for key, v in self.d(k).items() if any(c in key for c in counters)))
                          for k in running))

        while True:
            left = deadline - time.monotonic()
            try:
                self.rs.spin_until(lambda: all(self.processed(k) for k in robots), max(left, 0.1),
                                   f"robots {robots}' nodes to process everything and their closures to arrive")
            except TimeoutError:
                print(json.dumps({k: self.d(k) for k in robots}, indent=1)[:4000], file=sys.stderr)
                raise
            before = snapshot()
            counts = {k: self.diag_count.get(self.fqn(k), 0) for k in running}
            self.rs.spin_until(lambda: all(self.diag_count.get(self.fqn(k), 0) >= counts[k] + 2 for k in running),
                               max(deadline - time.monotonic(), 5.0), "two more diagnostics messages")
            if snapshot() == before and all(self.processed(k) for k in robots):
                return

    def replay_duration(self, robots: list[int]) -> float:
        """Wall seconds the replay of ``robots`` takes at ``--rate``."""
        return max((self.messages[k][-1][0] - self.messages[k][0][0]) * 1e-9 for k in robots) / self.a.rate

    def fleet_counts(self, k: int, d: dict | None = None) -> dict[int, dict[str, float]]:
        """Robot k's diagnostics (or ``d``) of the other robots' keyframes: robot -> received, added,
        duplicates, refused, over rate (``fleet.robot_<j>: "received N, added N, duplicates N, refused N,
        over rate N"``)."""
        out = {}
        for key, v in (self.d(k) if d is None else d).items():
            m = re.search(r"fleet\.robot_(\d+)$", key)
            if m:
                out[int(m.group(1))] = {name.strip().replace(" ", "_"): float(n)
                                        for name, n in re.findall(r"([a-z ]+?) (\d+(?:\.\d+)?)", v)}
        return out

    def all_delivered(self, k: int) -> bool:
        """Robot k's node took in every keyframe the other running robots published (as its diagnostics
        count them)."""
        counts = self.fleet_counts(k)
        for j in self.nodes:
            n = sum(1 for kf in self.keyframes if kf["robot"] == j)
            if j != k and n and counts.get(j, {}).get("received", 0) < n:
                return False
        return True

    def stop_all(self) -> dict[int, dict]:
        out = {}
        for i, k in enumerate(sorted(self.nodes)):
            sig = signal.SIGINT if i % 2 == 0 else signal.SIGTERM
            node = self.nodes[k]
            node.proc.send_signal(sig)
            try:
                code = node.proc.wait(timeout=30)
            except Exception:
                code = None
            out[k] = {"signal": sig.name, "exit": code}
        return out


def namespaced_params(src: Path, dst: Path, fqn: str) -> Path:
    """``src`` with its ``dc_loc:`` section renamed ``fqn:``, written to ``dst``."""
    text, n = re.subn(r"^dc_loc:", f"{fqn}:", src.read_text(), count=1, flags=re.M)
    if n != 1:
        raise RuntimeError(f"{src}: no top-level 'dc_loc:' section")
    dst.write_text(text)
    return dst


def radar_names(params: Path) -> list[str]:
    """``radar_names`` of a dc_loc params file (dc_loc sim's: ``dc_loc: ros__parameters: radar_names``)."""
    import yaml

    doc = yaml.safe_load(params.read_text())
    for section in doc.values():
        names = (section or {}).get("ros__parameters", {}).get("radar_names")
        if names:
            return list(names)
    raise RuntimeError(f"{params}: no radar_names")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--node", required=True)
    ap.add_argument("--fleet", required=True, type=Path, help="dc_loc sim --fleet N output directory")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--rate", type=float, default=5.0)
    ap.add_argument("--concurrent", default="0,1", help="robots replayed together first (default 0,1)")
    ap.add_argument("--late", default="2", help="robots whose nodes start after those finished (default 2)")
    ap.add_argument("--backend", action="store_true", help="optimise the fleet with examples/backend_gtsam.py")
    ap.add_argument("--fleet-history", type=int, help="-p node.fleet_history:=H on every node")
    ap.add_argument("--fleet-rate", type=float, help="-p node.fleet_rate:=F on every node")
    ap.add_argument("--flood", type=int, metavar="ROBOT",
                    help="flood /dc_loc/keyframes as fake robot ROBOT during the concurrent replay")
    ap.add_argument("node_args", nargs="*")
    a = ap.parse_args()
    a.concurrent = [int(k) for k in a.concurrent.split(",") if k]
    a.late = [int(k) for k in a.late.split(",") if k]
    robots = a.concurrent + a.late

    truth = {k: GroundTruth(a.fleet / f"robot_{k}") for k in robots}
    reservation = tl.reserve_domain_id()
    domain = reservation.domain_id
    tl.apply_loopback_env(domain)
    env = tl.loopback_env(domain)
    fleet = Fleet(a, env)
    flood = None
    if a.flood is not None:
        if a.flood in robots:
            raise SystemExit(f"--flood {a.flood}: a robot of the fleet")
        base = max(fleet.messages[k][0][0] for k in robots) * 1e-9 + 3600.0
        flood = Flood(fleet, a.flood, a.fleet_history or NODE_FLEET_HISTORY, base)
    result = {"domain_id": domain, "rate": a.rate, "concurrent": a.concurrent, "late": a.late,
              "fleet_history": a.fleet_history or NODE_FLEET_HISTORY, "fleet_rate": a.fleet_rate or NODE_FLEET_RATE}
    started = time.monotonic()
    try:
        for k in a.concurrent:
            fleet.start_node(k)
        with tl.RclpySession("dc_loc_fleet_replay") as rs:
            fleet.setup(rs)
            if flood:
                flood.setup(rs)
            fleet.wait_matched(a.concurrent)
            if flood:
                flood.start(a.concurrent, FLOOD_START * fleet.replay_duration(a.concurrent))
                fleet.replay(a.concurrent, flood.tick)
                rs.spin_until(flood.tick, 120.0, f"the flood of robot {a.flood} to be counted")
            else:
                fleet.replay(a.concurrent)
            fleet.settle(a.concurrent, 120.0)
            if flood:
                # Before the late joiners start: they get no flood from the topic's history.
                flood.stop()
            before_late = {k: len([kf for kf in fleet.keyframes if kf["robot"] == k]) for k in a.concurrent}
            result["phases"] = {"concurrent_done_s": time.monotonic() - started}
            for k in a.late:
                fleet.start_node(k)
            if a.late:
                fleet.wait_matched(a.late)
                # The late nodes take the history of the earlier robots' keyframes before their drives.
                for k in a.late:
                    rs.spin_until(lambda k=k: fleet.all_delivered(k), 60.0,
                                  f"robot {k}'s node to take the earlier robots' {before_late} keyframes")
                    result.setdefault("history_received", {})[str(k)] = fleet.fleet_counts(k)
                fleet.replay(a.late)
                fleet.settle(robots, 120.0)
            result["phases"]["late_done_s"] = time.monotonic() - started
            result["robots"] = {str(k): {"sent": fleet.sent[k], "replay_seconds": fleet.replay_seconds[k],
                                         "diagnostics": fleet.d(k)} for k in robots}
            stops = fleet.stop_all()
            rs.spin_until(lambda: True, 0.5, "spin")
            for k, s in stops.items():
                result["robots"][str(k)].update(s)
    finally:
        for node in fleet.nodes.values():
            node.stop()
        reservation.release()

    # Closures naming a robot outside the fleet (the flood's) are not judged: they are reported apart.
    def in_fleet(c: dict) -> bool:
        return c["query_robot"] in truth and c["match_robot"] in truth

    flood_closures = [c for c in fleet.closures if not in_fleet(c)]
    closures = [c for c in fleet.closures if in_fleet(c)]
    summary = judge(closures, fleet.keyframes, truth, a.late)
    summary["shared_alignments"] = judge_shared_alignments(fleet.keyframes, truth)
    summary["exits"] = {str(k): result["robots"][str(k)]["exit"] for k in robots}
    summary["signals"] = {str(k): result["robots"][str(k)]["signal"] for k in robots}
    summary["diag_keyframes"] = {str(k): int(fleet.d(k).get("dc_loc: processing/keyframes", -1)) for k in robots}
    summary["queue_full"] = {str(k): sum(int(v) for key, v in fleet.d(k).items()
                                         if key.endswith("queue_full") and v.lstrip("-").isdigit())
                             for k in robots}
    summary["foreign_keyframes"] = {str(r): n for r, n in sorted(fleet.foreign_keyframes.items())}
    summary["fleet_counts"] = {str(k): {str(j): c for j, c in sorted(fleet.fleet_counts(k).items())} for k in robots}
    if flood:
        summary["flood"] = flood.summary(flood_closures)
    if a.backend:
        summary["backend"] = backend_check(closures, truth, a.fleet, a.concurrent[0])
    result["summary"] = summary
    result["closures"] = closures
    result["flood_closures"] = flood_closures
    result["keyframes"] = [[k["robot"], k["session"], k["id"], k["stamp"], k["x"], k["y"], k["yaw"]]
                           for k in fleet.keyframes]
    result["wall_seconds"] = time.monotonic() - started
    a.out.write_text(json.dumps(result, indent=1))
    print_summary(summary, result)
    return 0


def print_summary(s: dict, result: dict) -> None:
    i = s["inter_robot"]
    print(f"fleet: keyframes {s['keyframes']}, inter-robot closures {i['published']} "
          f"({s['inter_robot_by_robots']}), correct {i['correct']} ({100 * i['precision']:.1f} %), "
          f"{i['reverse']} opposite-direction, median error {i['median_translation_error']:.3f} m, "
          f"worst correct {i['max_translation_error']:.3f} m / {i['max_rotation_error']:.4f} rad")
    print(f"fleet: same-direction opportunities {s['opportunities']}, found {s['found']} "
          f"({100 * s['recall']:.1f} %) by robot {s['by_robot']}; late joiner {s['late_joiner']}")
    print(f"fleet: within one robot {s['intra_robot']['published']} closures, {s['intra_robot']['correct']} correct; "
          f"pairs published twice {len(s['duplicates'])}, by the older keyframe's node {len(s['published_by_older'])}, "
          f"unknown keyframes {len(s['unknown_keyframes'])}, wrong query_robot {len(s['wrong_query_robot'])}")
    print(f"fleet: exits {s['exits']} ({s['signals']}), queue_full {s['queue_full']}, "
          f"wall {result['wall_seconds']:.1f} s")
    if "flood" in s:
        f = s["flood"]
        print(f"fleet: flood of robot {f['robot']}: {f['sent']} keyframes sent in {f['send_seconds']:.2f} s after "
              f"{f['malformed']} malformed ones (counted in {f['bad_wait_seconds']:.2f} s), "
              f"node.fleet_history {result['fleet_history']}, node.fleet_rate {result['fleet_rate']}; "
              f"closures naming it {len(f['closures'])}; the flood's keyframes seen on the topic "
              f"{s['foreign_keyframes']}")
        for k, n in f["nodes"].items():
            print(f"fleet: flood at robot {k}'s node: received {n['received']}, added {n['added']}, duplicates "
                  f"{n['duplicates']}, refused {n['refused']}, over rate {n['over_rate']}; dropped bad_keyframe "
                  f"{n['bad_keyframe']}, keyframe_over_rate {n['keyframe_over_rate']}; counted "
                  f"{n['elapsed_s']:.2f} s after the flood began (all delivered: {n['all_delivered']})")
    if "backend" in s:
        print(f"fleet: back end {s['backend']}")


if __name__ == "__main__":
    tl.run_main(main)
