#!/usr/bin/env python3
"""Reads a bag written by `dc_loc sim` with the rosbags library and checks it against what the
simulated drive says (JSON written by tests/cli.rs).

Usage: check_sim_bag.py BAG EXPECT
  BAG     bag directory
  EXPECT  JSON text, or @path of a JSON file:
    {"start_ns", "end_ns",
     "topics": [{"name", "type", "count", "durability"}],
     "stamps": {topic: {"first_ns", "last_ns"}},           header stamps (= log times) of first and last
     "odometry": {topic: {"frame_id", "child_frame_id", "last_xy": [x, y], "last_speed"}},
     "clouds": {topic: {"frame_id", "detections"}},        total points over all clouds
     "tf_static": [{"parent", "child", "translation": [x, y, z], "rotation": [x, y, z, w]}]}

Checks: topics with types, counts and durability; bag start and end; per topic the first and last log
time and header stamp; odometry frames, last position and speed; cloud frame ids, the x y z v_r rcs
FLOAT32 layout and the number of points; the static transforms. Exits 1 with the first mismatch.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

FLOAT32 = 7


def fail(msg: str) -> None:
    print(f'MISMATCH: {msg}')
    sys.exit(1)


def close(a: float, b: float, tol: float = 1e-9) -> bool:
    return math.isclose(a, b, rel_tol=0.0, abs_tol=tol)


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def main() -> None:
    bag = Path(sys.argv[1])
    arg = sys.argv[2]
    expect = json.loads(Path(arg[1:]).read_text() if arg.startswith('@') else arg)
    store = get_typestore(Stores.ROS2_JAZZY)

    with Reader(bag) as reader:
        got_topics = sorted((c.topic, c.msgtype, c.msgcount) for c in reader.connections)
        want_topics = sorted((t['name'], t['type'], t['count']) for t in expect['topics'])
        if got_topics != want_topics:
            fail(f'topics {got_topics} != {want_topics}')
        conns = {c.topic: c for c in reader.connections}
        for t in expect['topics']:
            got = [q.durability.name.lower() for q in conns[t['name']].ext.offered_qos_profiles]
            if got != [t['durability']]:
                fail(f"{t['name']}: durability {got} != {[t['durability']]}")
        if reader.start_time != expect['start_ns']:
            fail(f"bag start {reader.start_time} != {expect['start_ns']}")
        # rosbags reports the end as one past the last message.
        if reader.end_time != expect['end_ns'] + 1:
            fail(f"bag end {reader.end_time} != {expect['end_ns']} + 1")

        first: dict[str, tuple[int, int]] = {}
        last: dict[str, tuple[int, int]] = {}
        last_odom = {}
        points = {t: 0 for t in expect['clouds']}
        tf_static = None
        for conn, t, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            topic = conn.topic
            if conn.msgtype == 'tf2_msgs/msg/TFMessage':
                tf_static = msg
                stamp = stamp_ns(msg.transforms[0].header) if msg.transforms else -1
            else:
                stamp = stamp_ns(msg.header)
            first.setdefault(topic, (t, stamp))
            last[topic] = (t, stamp)
            if topic in expect['odometry']:
                want = expect['odometry'][topic]
                if msg.header.frame_id != want['frame_id'] or msg.child_frame_id != want['child_frame_id']:
                    fail(f'{topic} at {t}: frames {msg.header.frame_id} -> {msg.child_frame_id}')
                last_odom[topic] = msg
            if topic in expect['clouds']:
                want = expect['clouds'][topic]
                if msg.header.frame_id != want['frame_id']:
                    fail(f'{topic} at {t}: frame_id {msg.header.frame_id!r} != {want["frame_id"]!r}')
                layout = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
                want_layout = [(n, 4 * i, FLOAT32, 1) for i, n in enumerate(['x', 'y', 'z', 'v_r', 'rcs'])]
                if layout != want_layout or msg.point_step != 20 or msg.is_bigendian:
                    fail(f'{topic} at {t}: layout {layout}, point_step {msg.point_step}')
                if msg.height != 1 or len(msg.data) != msg.width * 20 or msg.row_step != msg.width * 20:
                    fail(f'{topic} at {t}: {msg.height} x {msg.width} points in {len(msg.data)} bytes')
                points[topic] += msg.width

        for topic, want in expect['stamps'].items():
            for name, got, w in (('first', first.get(topic), want['first_ns']), ('last', last.get(topic), want['last_ns'])):
                if got != (w, w):
                    fail(f'{topic}: {name} (log time, header stamp) {got} != ({w}, {w})')
        for topic, want in expect['odometry'].items():
            m = last_odom[topic]
            p = m.pose.pose.position
            lin = m.twist.twist.linear
            if not (close(p.x, want['last_xy'][0]) and close(p.y, want['last_xy'][1])):
                fail(f'{topic}: last position ({p.x}, {p.y}) != {want["last_xy"]}')
            if not close(math.hypot(lin.x, lin.y, lin.z), want['last_speed']):
                fail(f'{topic}: last speed {lin} != {want["last_speed"]}')
        for topic, want in expect['clouds'].items():
            if points[topic] != want['detections']:
                fail(f'{topic}: {points[topic]} points != {want["detections"]} detections')
        if tf_static is None:
            fail('no /tf_static message')
        got_tf = [(tr.header.frame_id, tr.child_frame_id) for tr in tf_static.transforms]
        want_tf = [(w['parent'], w['child']) for w in expect['tf_static']]
        if got_tf != want_tf:
            fail(f'tf_static frames {got_tf} != {want_tf}')
        for tr, w in zip(tf_static.transforms, expect['tf_static']):
            tt, rr = tr.transform.translation, tr.transform.rotation
            got = [tt.x, tt.y, tt.z, rr.x, rr.y, rr.z, rr.w]
            if not all(close(a, b, 1e-12) for a, b in zip(got, w['translation'] + w['rotation'])):
                fail(f"tf_static {w['child']}: {got} != {w['translation'] + w['rotation']}")
    print(f'rosbags read {bag}: all as expected')
    for name, typ, count in got_topics:
        print(f'  {name} {typ} x{count}')


if __name__ == '__main__':
    main()
