"""Replays a rosbag2 drive into the running dc_loc node with rclpy publishers, as a real ROS 2 user would.

Run by tests/node.rs with the venv's interpreter:

    test_node_replay.py --node BIN --bag DIR --out RESULT.json [--rate R] [--malformed]
                        [--stop-after FRACTION --kill] [--skip-before FRACTION] [--tf-static]
                        [--radar-scan] [--no-odom] [--imu] [--record-odometry [--record-tf]]
                        [-- NODE ARGS...]

1. Reserves a ROS domain id of its own; everything stays on loopback (dcloc_testlib).
2. Starts the node (``BIN --ros-args NODE ARGS``) and waits for its "running" line. ``--tf-static``
   first starts tf_static_pub.py, which publishes the bag's /tf_static (transient local).
3. rclpy publishers (reliable, keep-all-ish depth 1000) for the bag's radar and odometry topics; an rclpy
   subscriber typed ``dc_loc.msg.LoopClosure`` and a Cyclone DDS subscriber on ``/dc_loc/loop_closures``
   (reliable, transient-local); an rclpy ``/diagnostics`` subscriber. Waits for every match.
4. Publishes the bag's messages (their raw CDR, original stamps) in log-time order at ``--rate`` times
   real time. ``--malformed`` interleaves bad messages (rclpy-built) on the same topics: each kind
   ``MALFORMED_REPEAT`` times (see ``malformed``). ``--radar-scan`` publishes each cloud as the
   radar_msgs/RadarScan of the same detections (``as_radar_scans``). ``--no-odom`` leaves /odom out (a
   robot without wheel odometry); ``--imu`` publishes the bag's sensor_msgs/Imu gyro (/imu).
5. Waits until the node's diagnostics show every message received and processed and both subscribers have
   as many closures as the node published; then SIGINT, and the node must exit 0.
   ``--stop-after F --kill``: publishes only the first fraction F of the drive, waits for it to be
   processed, then SIGKILLs the node (map persistence test). ``--skip-before F``: publishes only from
   fraction F on.
6. Writes RESULT.json: the closures each subscriber received (as dc_loc's ClosureRecord JSON objects),
   the last diagnostics (key -> value), the node's exit code, message counts; with ``--record-odometry``
   the node's ``~/odometry`` messages (stamp, pose, frames, covariances), subscribed before the replay
   and waited for as the closures are; with ``--record-tf`` also the /tf transforms (stamp, frames,
   translation).
Exit code 0 when the run went through (the checks on the closures are the Rust test's), 1 otherwise.
"""

import argparse
import json
import math
import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dcloc_testlib as tl

CLOSURES = "/dc_loc/loop_closures"
MALFORMED_REPEAT = 3


def secs(t) -> float:
    return t.sec + t.nanosec * 1e-9


def record(msg) -> dict:
    """A LoopClosure (rclpy or cyclone) as dc_loc's ClosureRecord JSON object."""
    p = tl.to_plain(msg)

    def pose(q):
        return {"x": q["position"]["x"], "y": q["position"]["y"], "z": q["position"]["z"],
                "qx": q["orientation"]["x"], "qy": q["orientation"]["y"], "qz": q["orientation"]["z"],
                "qw": q["orientation"]["w"]}

    def s(t):
        return t["sec"] + t["nanosec"] * 1e-9

    return {
        "stamp": s(p["header"]["stamp"]), "frame_id": p["header"]["frame_id"],
        "query_id": p["query_id"], "match_id": p["match_id"],
        "query_robot": p["query_robot"], "match_robot": p["match_robot"],
        "query_stamp": s(p["query_stamp"]), "match_stamp": s(p["match_stamp"]),
        "query_odom_pose": pose(p["query_odom_pose"]), "match_odom_pose": pose(p["match_odom_pose"]),
        "relative_pose": pose(p["relative_pose"]["pose"]),
        "covariance": list(p["relative_pose"]["covariance"]),
        "inliers": p["inliers"], "score": p["score"],
    }


def set_parameter(rs, node_ns: str, assignment: str) -> str:
    """Sets ``NAME:=VALUE`` on the running node with rcl_interfaces/SetParameters; returns "ok" or the
    refusal's reason."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    name, text = assignment.split(":=", 1)
    if text in ("true", "false"):
        v = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=text == "true")
    elif text.lstrip("-").isdigit():
        v = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=int(text))
    else:
        try:
            v = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(text))
        except ValueError:
            v = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=text)
    client = rs.node.create_client(SetParameters, node_ns + "/set_parameters")
    rs.spin_until(client.service_is_ready, 20.0, "the set_parameters service")
    future = client.call_async(SetParameters.Request(parameters=[Parameter(name=name, value=v)]))
    rs.spin_until(future.done, 20.0, "the set_parameters reply")
    r = future.result().results[0]
    return "ok" if r.successful else r.reason


ODOMETRY = "nav_msgs/msg/Odometry"
IMU = "sensor_msgs/msg/Imu"


def read_bag(bag: Path, odom: bool = True, imu: bool = False):
    """(log_time_ns, topic, type, raw CDR) of the radar topics, /odom (``odom``) and the gyro (``imu``), in
    log-time order."""
    from rosbags.rosbag2 import Reader

    out = []
    with Reader(bag) as reader:
        conns = [c for c in reader.connections
                 if c.msgtype == "sensor_msgs/msg/PointCloud2"
                 or (odom and c.msgtype == ODOMETRY and c.topic == "/odom")
                 or (imu and c.msgtype == IMU)]
        for conn, t, raw in reader.messages(connections=conns):
            out.append((t, conn.topic, conn.msgtype, bytes(raw)))
    out.sort(key=lambda m: m[0])
    return out


def as_radar_scans(messages):
    """``messages`` with every PointCloud2 (fields x, y, z, v_r) turned into the radar_msgs/RadarScan of the
    same detections (range, azimuth, elevation, doppler_velocity = v_r), serialized, on the same topic."""
    import numpy as np
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud2

    from radar_msgs.msg import RadarReturn, RadarScan

    kinds = {7: "f4", 8: "f8"}
    out = []
    for t, topic, msgtype, raw in messages:
        if msgtype != "sensor_msgs/msg/PointCloud2":
            out.append((t, topic, msgtype, raw))
            continue
        c = deserialize_message(raw, PointCloud2)
        order = ">" if c.is_bigendian else "<"
        dtype = np.dtype({"names": [f.name for f in c.fields],
                          "formats": [order + kinds[f.datatype] for f in c.fields],
                          "offsets": [f.offset for f in c.fields], "itemsize": c.point_step})
        pts = np.frombuffer(bytes(c.data), dtype=dtype, count=c.width * c.height)
        x, y, z = (pts[k].astype(float) for k in ("x", "y", "z"))
        r = np.sqrt(x * x + y * y + z * z)
        scan = RadarScan()
        scan.header = c.header
        for i in range(len(pts)):
            el = float(np.arcsin(z[i] / r[i])) if r[i] > 0 else 0.0
            scan.returns.append(RadarReturn(range=float(r[i]), azimuth=float(np.arctan2(y[i], x[i])),
                                            elevation=el, doppler_velocity=float(pts["v_r"][i]),
                                            amplitude=0.0))
        out.append((t, topic, "radar_msgs/msg/RadarScan", serialize_message(scan)))
    return out


def odometry_record(m) -> dict:
    """A nav_msgs/Odometry as a plain dict: stamp, frames, pose, twist and both covariances."""
    p, q = m.pose.pose.position, m.pose.pose.orientation
    t = m.twist.twist
    return {"sec": m.header.stamp.sec, "nanosec": m.header.stamp.nanosec, "frame_id": m.header.frame_id,
            "child_frame_id": m.child_frame_id,
            "x": p.x, "y": p.y, "z": p.z, "qx": q.x, "qy": q.y, "qz": q.z, "qw": q.w,
            "twist": [t.linear.x, t.linear.y, t.angular.z],
            "covariance": list(m.pose.covariance), "twist_covariance": list(m.twist.covariance)}


def malformed(good_cloud, last_odom):
    """(kind, topic role, message, expected diagnostics key) of each bad input, built with rclpy types from
    the newest good cloud (same topic, frame and stamp, so that nothing else changes)."""
    import copy

    from sensor_msgs.msg import PointField

    out = []

    def variant(kind, key, edit):
        c = copy.deepcopy(good_cloud)
        edit(c)
        out.append((kind, "radar", c, key))

    def drop_field(c):
        c.fields = [f for f in c.fields if f.name != "v_r"]

    def mistype(c):
        for f in c.fields:
            if f.name == "x":
                f.datatype = 42

    def step(c):
        c.point_step = 4
        c.row_step = 4 * c.width

    def truncate(c):
        c.data = bytes(c.data)[: len(c.data) // 2]

    def nan(c):
        import struct

        n = c.width * c.height
        c.data = struct.pack("<f", math.nan) * (len(c.data) // 4)
        assert n > 0

    def empty(c):
        c.width = 0
        c.row_step = 0
        c.data = b""

    def huge(c):
        n = 6000
        c.width = n
        c.row_step = n * c.point_step
        c.data = bytes(n * c.point_step)

    def frame(c):
        c.header.frame_id = "no_such_radar"

    def backwards(c):
        c.header.stamp.sec -= 30

    variant("missing field", "bad_cloud", drop_field)
    variant("mistyped field", "bad_cloud", mistype)
    variant("wrong point_step", "bad_cloud", step)
    variant("truncated data", "bad_cloud", truncate)
    variant("NaN points", "empty_clouds", nan)
    variant("empty cloud", "empty_clouds", empty)
    variant("huge cloud", "cloud_too_large", huge)
    variant("unknown frame", "unknown_frame", frame)
    variant("stamp backwards", "stamp_backwards", backwards)
    o = copy.deepcopy(last_odom)
    o.pose.pose.position.x = math.nan
    out.append(("NaN odometry", "odom", o, "bad_odometry"))
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--node", required=True)
    ap.add_argument("--bag", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--rate", type=float, default=5.0)
    ap.add_argument("--malformed", action="store_true")
    ap.add_argument("--stop-after", type=float, default=1.0)
    ap.add_argument("--skip-before", type=float, default=0.0)
    ap.add_argument("--kill", action="store_true")
    ap.add_argument("--node-name", default="/dc_loc")
    ap.add_argument("--save-map", action="store_true", help="call ~/save_map before stopping the node")
    ap.add_argument("--set-at", nargs=2, metavar=("FRACTION", "NAME:=VALUE"),
                    help="set a parameter of the running node (set_parameters) at this fraction of the drive")
    ap.add_argument("--tf-static", action="store_true",
                    help="publish the bag's /tf_static (transient local) before the node starts")
    ap.add_argument("--radar-scan", action="store_true",
                    help="publish the radars as radar_msgs/RadarScan instead of PointCloud2")
    ap.add_argument("--no-odom", action="store_true", help="leave /odom out of the replay")
    ap.add_argument("--imu", action="store_true", help="publish the bag's sensor_msgs/Imu gyro too")
    ap.add_argument("--record-odometry", action="store_true",
                    help="subscribe the node's ~/odometry and write its messages to RESULT.json")
    ap.add_argument("--record-tf", action="store_true",
                    help="subscribe /tf and write its transforms to RESULT.json")
    ap.add_argument("node_args", nargs="*")
    a = ap.parse_args()

    messages = read_bag(a.bag, odom=not a.no_odom, imu=a.imu)
    t0, t1 = messages[0][0], messages[-1][0]
    # In integer nanoseconds: a float of today's epoch in ns is 256 ns coarse and would cut the ends.
    lo = t0 + round(a.skip_before * (t1 - t0))
    hi = t0 + round(a.stop_after * (t1 - t0))
    messages = [m for m in messages if lo <= m[0] <= hi]
    if a.radar_scan:
        messages = as_radar_scans(messages)

    reservation = tl.reserve_domain_id()
    domain = reservation.domain_id
    tl.apply_loopback_env(domain)
    env = tl.loopback_env(domain)
    closures_topic = a.node_name.rstrip("/") + "/loop_closures"

    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import PointCloud2

    from dc_loc.msg import LoopClosure

    tf_pub = None
    if a.tf_static:
        tf_pub = tl.ManagedProcess([sys.executable, str(Path(__file__).resolve().parent / "tf_static_pub.py"),
                                    "--bag", str(a.bag)], env, name="tf_static_pub")
        tf_pub.wait_for_line(lambda l: l.startswith("tf_static published"), 60.0, "/tf_static published")
    node = tl.ManagedProcess([a.node, "--ros-args", *a.node_args], env, name="dc_loc")
    result = {"domain_id": domain}
    try:
        node.wait_for_line(lambda l: "running" in l, 30.0, "the node's running line")
        with tl.RclpySession("dc_loc_replay") as rs, tl.CycloneSession() as cs:
            qos_pub = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                                 reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.VOLATILE)
            from sensor_msgs.msg import Imu

            types = {"sensor_msgs/msg/PointCloud2": PointCloud2, ODOMETRY: Odometry, IMU: Imu}
            if a.radar_scan:
                from radar_msgs.msg import RadarScan
                types["radar_msgs/msg/RadarScan"] = RadarScan
            pubs = {}
            for _, topic, msgtype, _ in messages:
                if topic not in pubs:
                    pubs[topic] = rs.node.create_publisher(types[msgtype], topic, qos_pub)
            got_rclpy, got_cyclone, diag = [], [], {}
            diag_count = [0]

            def on_closure(m):
                got_rclpy.append(record(m))

            def on_diag(m):
                diag_count[0] += 1
                for st in m.status:
                    for kv in st.values:
                        diag[f"{st.name}/{kv.key}"] = kv.value

            rs.node.create_subscription(LoopClosure, closures_topic, on_closure,
                                        tl.rclpy_qos_loop_closure())
            diag_sub = rs.node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
            # ~/markers (transient local, the latest) and ~/submap.
            from visualization_msgs.msg import MarkerArray

            outputs = {"markers": None, "submaps": 0, "submap_points": 0, "submap_fields": [],
                       "relocalized": []}

            def on_markers(m):
                outputs["markers"] = {mk.ns: len(mk.points) for mk in m.markers}

            def on_submap(c):
                outputs["submaps"] += 1
                outputs["submap_points"] = c.width * c.height
                outputs["submap_fields"] = [f.name for f in c.fields]

            node_ns = a.node_name.rstrip("/")
            rs.node.create_subscription(
                MarkerArray, node_ns + "/markers", on_markers,
                QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL))
            rs.node.create_subscription(PointCloud2, node_ns + "/submap", on_submap, 10)
            # ~/relocalized: the pose in a loaded map, as (stamp, x, y, frame, covariance xx, yy).
            from geometry_msgs.msg import PoseWithCovarianceStamped

            def on_relocalized(m):
                p = m.pose.pose.position
                outputs["relocalized"].append({
                    "stamp": secs(m.header.stamp), "x": p.x, "y": p.y, "frame_id": m.header.frame_id,
                    "cov_xx": m.pose.covariance[0], "cov_yy": m.pose.covariance[7]})

            rs.node.create_subscription(
                PoseWithCovarianceStamped, node_ns + "/relocalized", on_relocalized,
                QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE))
            # ~/odometry: the radar odometry, every message kept.
            odometry_msgs = []
            if a.record_odometry:
                odom_sub = rs.node.create_subscription(
                    Odometry, node_ns + "/odometry", lambda m: odometry_msgs.append(odometry_record(m)),
                    QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                               reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE))
            # /tf: the radar odometry's transforms (node.odometry_tf), as tf2's listeners subscribe.
            tf_msgs = []
            if a.record_tf:
                from tf2_msgs.msg import TFMessage

                def on_tf(m):
                    for t in m.transforms:
                        v = t.transform.translation
                        tf_msgs.append({"sec": t.header.stamp.sec, "nanosec": t.header.stamp.nanosec,
                                        "frame_id": t.header.frame_id, "child_frame_id": t.child_frame_id,
                                        "x": v.x, "y": v.y, "z": v.z})

                tf_sub = rs.node.create_subscription(
                    TFMessage, "/tf", on_tf,
                    QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                               reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE))
            reader = cs.reader(closures_topic, tl.LoopClosure, tl.cyclone_qos_loop_closure())

            def poll_cyclone():
                for s in reader.take(N=100):
                    if isinstance(s, tl.LoopClosure):
                        got_cyclone.append(record(s))

            for p in pubs.values():
                rs.wait_for_subscriptions(p, 1)
            rs.wait_for_publishers(diag_sub, 1)
            if a.record_odometry:
                rs.wait_for_publishers(odom_sub, 1)
            if a.record_tf:
                rs.wait_for_publishers(tf_sub, 1)
            tl.wait_for_matched(reader, 1, what="cyclone closure reader matched")

            # The node's readers must have matched the publishers too (matching is not symmetric in time):
            # its diagnostics count the matched publishers per input.
            def node_matched():
                n = {k: int(v) for k, v in diag.items() if k.endswith(".publishers")}
                return len(n) >= 2 and all(v >= 1 for v in n.values())

            rs.spin_until(node_matched, 30.0, "the node's readers to match the publishers")
            # Who reads /odom (a node without wheel odometry must not).
            outputs["odom_subscribers"] = rs.node.count_subscribers("/odom")

            # Replay at --rate, malformed messages interleaved.
            radar_topic = next(t for _, t, ty, _ in messages if ty not in (ODOMETRY, IMU))
            bad_plan = []
            sent = {"radar": 0, "odometry": 0, "imu": 0, "malformed": {}}
            start = time.monotonic()
            last_cloud = last_odom = None
            set_index = int(float(a.set_at[0]) * len(messages)) if a.set_at else -1
            for i, (t, topic, msgtype, raw) in enumerate(messages):
                if i == set_index:
                    result["set_at_stamp"] = t * 1e-9
                    result["set_result"] = set_parameter(rs, a.node_name.rstrip("/"), a.set_at[1])
                due = start + (t - messages[0][0]) * 1e-9 / a.rate
                while True:
                    left = due - time.monotonic()
                    if left <= 0:
                        break
                    rs.executor.spin_once(timeout_sec=min(left, 0.01))
                poll_cyclone()
                pubs[topic].publish(raw)
                if msgtype == IMU:
                    sent["imu"] += 1
                elif msgtype != ODOMETRY:
                    sent["radar"] += 1
                    if a.malformed:
                        last_cloud = raw
                else:
                    sent["odometry"] += 1
                    if a.malformed:
                        last_odom = raw
                # Malformed inputs spread over the middle of the drive.
                if a.malformed and last_cloud and last_odom and i % 97 == 50 and len(bad_plan) < 100:
                    if not bad_plan:
                        bad_plan = malformed(deserialize_message(last_cloud, PointCloud2),
                                             deserialize_message(last_odom, Odometry)) * MALFORMED_REPEAT
                        bad_plan = [list(b) + [False] for b in bad_plan]
                    for b in bad_plan:
                        if not b[4]:
                            kind, role, msg, key, _ = b
                            if role == "radar":
                                c = deserialize_message(last_cloud, PointCloud2)
                                # Same stamp as the newest good cloud: nothing else changes.
                                if kind != "stamp backwards":
                                    msg.header.stamp = c.header.stamp
                                else:
                                    msg.header.stamp.sec = c.header.stamp.sec - 30
                                    msg.header.stamp.nanosec = c.header.stamp.nanosec
                                pubs[radar_topic].publish(msg)
                            else:
                                o = deserialize_message(last_odom, Odometry)
                                msg.header.stamp = o.header.stamp
                                pubs["/odom"].publish(msg)
                            sent["malformed"][key] = sent["malformed"].get(key, 0) + 1
                            b[4] = True
                            break
            replay_s = time.monotonic() - start
            result["replay_seconds"] = replay_s
            result["sent"] = sent
            bad_sent = sum(sent["malformed"].values())
            if a.malformed and bad_sent != len(bad_plan):
                raise RuntimeError(f"only {bad_sent} of {len(bad_plan)} malformed messages sent")

            # Wait until everything is received and processed, and both subscribers caught up.
            def radar_received():
                return sum(int(v) for k, v in diag.items() if k.endswith(".received")
                           and not k.endswith("odometry.received") and not k.endswith("/imu.received"))

            def done():
                poll_cyclone()
                if not diag:
                    return False
                # An input never received has no key: none of it was sent (--no-odom, no --imu).
                odo = int(diag.get("dc_loc: input/odometry.received", 0))
                imu = int(diag.get("dc_loc: input/imu.received", 0))
                odometry_out = int(diag.get("dc_loc: processing/odometry_published", 0))
                queued = (int(diag.get("dc_loc: processing/queue_depth", -1))
                          + int(diag.get("dc_loc: processing/held_for_order", -1)))
                closures = int(diag.get("dc_loc: processing/closures", -1))
                bad_radar = sum(v for k, v in sent["malformed"].items()
                                if k not in ("bad_odometry", "unknown_frame"))
                return (odo == sent["odometry"] + sent["malformed"].get("bad_odometry", 0)
                        and imu == sent["imu"]
                        and (not a.record_odometry or len(odometry_msgs) == odometry_out)
                        and (not a.record_tf or len(tf_msgs) == odometry_out)
                        and radar_received() == sent["radar"] + bad_radar
                        and queued == 0 and len(got_rclpy) == closures and len(got_cyclone) == closures)

            try:
                rs.spin_until(done, 60.0, "the node to process everything and both subscribers to catch up")
            except TimeoutError as e:
                result["diagnostics"] = diag
                print(json.dumps(result, indent=1)[:3000], file=sys.stderr)
                raise e
            # One more diagnostics message after the last closure, so the counts are final.
            n = diag_count[0]
            rs.spin_until(lambda: diag_count[0] > n, 10.0, "one more diagnostics message")
            result["diagnostics"] = dict(diag)
            if a.save_map:
                from std_srvs.srv import Trigger

                client = rs.node.create_client(Trigger, node_ns + "/save_map")
                rs.spin_until(client.service_is_ready, 20.0, "the ~/save_map service")
                future = client.call_async(Trigger.Request())
                rs.spin_until(future.done, 20.0, "the ~/save_map reply")
                outputs["save_map"] = {"success": future.result().success,
                                      "message": future.result().message}
            if a.kill:
                node.proc.send_signal(signal.SIGKILL)
                result["node_exit"] = node.proc.wait(timeout=10)
            else:
                node.proc.send_signal(signal.SIGINT)
                result["node_exit"] = node.proc.wait(timeout=30)
            # What the node published while it shut down (its last ~/odometry samples) is taken for 1 s;
            # no closure may come then (the node flushed them before the stop).
            end = time.monotonic() + 1.0
            while time.monotonic() < end:
                rs.executor.spin_once(timeout_sec=0.05)
            poll_cyclone()
            result["outputs"] = outputs
            result["odometry"] = odometry_msgs
            result["tf"] = tf_msgs
            result["rclpy"] = got_rclpy
            result["cyclone"] = got_cyclone
    finally:
        node.stop()
        if tf_pub is not None:
            tf_pub.stop()
        reservation.release()
    a.out.write_text(json.dumps(result, indent=1))
    print(f"replay: {result['sent']} in {result['replay_seconds']:.1f} s, "
          f"{len(result['rclpy'])} closures (rclpy), {len(result['cyclone'])} (cyclone), "
          f"node exit {result['node_exit']}")
    return 0


if __name__ == "__main__":
    tl.run_main(main)
