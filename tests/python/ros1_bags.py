#!/usr/bin/env python3
"""ROS 1 bags (format 2.0) written by the rosbags library, for tests/rosbag1.rs.

    ros1_bags.py convert SRC DST [--compression none|bz2|lz4] [--chunk-threshold BYTES]
        A rosbag2 bag (directory or .mcap) as a ROS 1 bag: every message of a type ROS 1 has
        (sensor_msgs, nav_msgs, geometry_msgs, tf2_msgs, radar_msgs, ...) in the order the rosbag2
        reader gives them, each with its log time; other types (dc_loc/msg/*) are left out and named.
    ros1_bags.py fixtures DIR
        DIR/{none,bz2,lz4}.bag: the same messages (the cases of make_cdr_fixtures.py that ROS 1 can
        carry, plus PoseStamped, Imu and RadarScan) in small chunks of each compression, and
        DIR/expected.json: per message its topic, ROS 1 type, time and its ROS 2 CDR bytes (hex), so
        that the Rust side compares its ROS 1 decoding with its CDR decoding of the same message.

The messages' bytes are rosbags' `cdr_to_ros1` of their CDR (a Header gets `seq` 0); each
connection's definition and md5sum are the ROS 1 ones (rosbags' ROS1_NOETIC store, with
tf2_msgs/TFMessage and radar_msgs registered from their .msg texts), as `rosbag record` writes them.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags_dicts import REPO, msg_from_dict, typestore

from make_cdr_fixtures import CASES, header, pose

RADAR_MSGS = REPO / 'tests' / 'python' / 'interfaces' / 'radar_msgs' / 'msg'


def ros1_store():
    """ROS 1 Noetic types, with tf2_msgs/TFMessage and radar_msgs registered."""
    store = get_typestore(Stores.ROS1_NOETIC)
    types = get_types_from_msg('geometry_msgs/TransformStamped[] transforms', 'tf2_msgs/msg/TFMessage')
    for name in ('RadarReturn', 'RadarScan'):
        types.update(get_types_from_msg((RADAR_MSGS / f'{name}.msg').read_text(),
                                        f'radar_msgs/msg/{name}'))
    store.register(types)
    return store


def ros2_store():
    """The ROS 2 Jazzy store of the other scripts, with radar_msgs registered."""
    store = typestore()
    types = {}
    for name in ('RadarReturn', 'RadarScan'):
        types.update(get_types_from_msg((RADAR_MSGS / f'{name}.msg').read_text(),
                                        f'radar_msgs/msg/{name}'))
    store.register(types)
    return store


def writer(dst: Path, compression: str, chunk_threshold: int | None) -> Writer:
    w = Writer(dst)
    if compression == 'bz2':
        w.set_compression(Writer.CompressionFormat.BZ2)
    elif compression == 'lz4':
        w.set_compression(Writer.CompressionFormat.LZ4)
    elif compression != 'none':
        sys.exit(f'unknown compression {compression}')
    if chunk_threshold is not None:
        w.chunk_threshold = chunk_threshold
    return w


def add_connection(w: Writer, ros1, topic: str, msgtype: str):
    msgdef, md5sum = ros1.generate_msgdef(msgtype, ros_version=1)
    return w.add_connection(topic, msgtype, msgdef=msgdef, md5sum=md5sum)


def convert(src: Path, dst: Path, compression: str, chunk_threshold: int | None) -> None:
    ros1 = ros1_store()
    with AnyReader([src], default_typestore=ros2_store()) as reader:
        left_out = sorted({c.topic for c in reader.connections if c.msgtype not in ros1.fielddefs})
        conns = [c for c in reader.connections if c.msgtype in ros1.fielddefs]
        w = writer(dst, compression, chunk_threshold)
        count = 0
        with w:
            out = {}
            for conn, t, raw in reader.messages(connections=conns):
                if conn.id not in out:
                    out[conn.id] = add_connection(w, ros1, conn.topic, conn.msgtype)
                w.write(out[conn.id], t, reader.typestore.cdr_to_ros1(raw, conn.msgtype))
                count += 1
    print(f'{count} messages -> {dst} ({compression}); left out: {", ".join(left_out) or "none"}')


def extra_cases():
    """Types the CDR fixtures do not have: ground truth as PoseStamped, an IMU, a RadarScan."""
    cov9 = [0.0625 * (i + 1) for i in range(9)]
    vec = lambda x, y, z: {'x': x, 'y': y, 'z': z}  # noqa: E731
    ret = lambda r, a, e, v: {'range': r, 'azimuth': a, 'elevation': e,  # noqa: E731
                              'doppler_velocity': v, 'amplitude': 31.5}
    return [
        ('pose_stamped', 'geometry_msgs/msg/PoseStamped', {
            'header': header(1700000000, 250000000, 'map'),
            'pose': pose(10.5, -2.25, 0.0, 0.0, 0.0, 0.5, 0.5),
        }),
        ('imu', 'sensor_msgs/msg/Imu', {
            'header': header(1700000000, 300000000, 'imu_link'),
            'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
            'orientation_covariance': [-1.0] + [0.0] * 8,
            'angular_velocity': vec(0.125, -0.25, 0.5),
            'angular_velocity_covariance': cov9,
            'linear_acceleration': vec(0.0, 0.5, 9.8125),
            'linear_acceleration_covariance': cov9[::-1],
        }),
        ('radar_scan', 'radar_msgs/msg/RadarScan', {
            'header': header(1700000000, 350000000, 'radar_front'),
            'returns': [ret(10.0, 0.25, 0.0, -3.5), ret(25.5, -0.5, 0.125, 1.25)],
        }),
        ('radar_scan_empty', 'radar_msgs/msg/RadarScan', {
            'header': header(1700000000, 450000000, 'radar_front'),
            'returns': [],
        }),
    ]


TOPICS = {
    'sensor_msgs/msg/PointCloud2': '/radar_front',
    'nav_msgs/msg/Odometry': '/odom',
    'tf2_msgs/msg/TFMessage': '/tf_static',
    'geometry_msgs/msg/PoseStamped': '/ground_truth',
    'sensor_msgs/msg/Imu': '/imu',
    'radar_msgs/msg/RadarScan': '/radar_scan',
}


def fixtures(out: Path) -> None:
    ros2 = ros2_store()
    ros1 = ros1_store()
    out.mkdir(parents=True, exist_ok=True)
    cases = [c for c in CASES if c[1] in TOPICS] + extra_cases()
    messages = []
    t0 = 1_700_000_000_000_000_000
    for i, (name, typename, d) in enumerate(cases):
        cdr = ros2.serialize_cdr(msg_from_dict(ros2, typename, d), typename)
        messages.append({'case': name, 'topic': TOPICS[typename], 'type': typename,
                         'time': t0 + i * 10_000_000, 'cdr': bytes(cdr).hex(),
                         'ros1': ros2.cdr_to_ros1(cdr, typename)})
    for compression in ('none', 'bz2', 'lz4'):
        # Chunks of about 600 bytes: several per bag, so that damage can fall between them.
        w = writer(out / f'{compression}.bag', compression, 600)
        with w:
            conns = {}
            for m in messages:
                if m['topic'] not in conns:
                    conns[m['topic']] = add_connection(w, ros1, m['topic'], m['type'])
                w.write(conns[m['topic']], m['time'], m['ros1'])
    for m in messages:
        del m['ros1']
    (out / 'expected.json').write_text(json.dumps(messages, indent=1))
    print(f'{len(messages)} messages -> {out}/{{none,bz2,lz4}}.bag')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', required=True)
    c = sub.add_parser('convert')
    c.add_argument('src', type=Path)
    c.add_argument('dst', type=Path)
    c.add_argument('--compression', default='none', choices=['none', 'bz2', 'lz4'])
    c.add_argument('--chunk-threshold', type=int)
    f = sub.add_parser('fixtures')
    f.add_argument('dir', type=Path)
    args = parser.parse_args()
    if args.command == 'convert':
        convert(args.src, args.dst, args.compression, args.chunk_threshold)
    else:
        fixtures(args.dir)


if __name__ == '__main__':
    main()
