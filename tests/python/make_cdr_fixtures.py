#!/usr/bin/env python3
"""Writes tests/fixtures/cdr_fixtures.json: CDR bytes made by the rosbags library (independent truth
for crates/core/src/cdr.rs) and rosbags' RIHS01 type hashes (for crates/io/src/bag/schema.rs).

Each case holds a message as a dict (the serde_json form of the Rust structs in crates/core/src/msgs.rs), its CDR
little endian (`cdr_hex`, as ROS 2 writes it) and big endian (`cdr_be_hex`), both from
`Typestore.serialize_cdr`. Floats are dyadic rationals so that JSON round-trips them exactly.

Run once (and again only to change the cases) with a Python that has rosbags:
    python3 -m venv /tmp/bagvenv && /tmp/bagvenv/bin/pip install rosbags
    /tmp/bagvenv/bin/python tests/python/make_cdr_fixtures.py
"""

from __future__ import annotations

import json
import struct
from importlib.metadata import version
from pathlib import Path

from rosbags_dicts import LOOP_CLOSURE_TYPE, REPO, msg_from_dict, typestore

OUT = REPO / 'tests' / 'fixtures' / 'cdr_fixtures.json'

TYPES = [
    'builtin_interfaces/msg/Time',
    'std_msgs/msg/Header',
    'sensor_msgs/msg/PointField',
    'sensor_msgs/msg/PointCloud2',
    'geometry_msgs/msg/Point',
    'geometry_msgs/msg/Quaternion',
    'geometry_msgs/msg/Pose',
    'geometry_msgs/msg/PoseWithCovariance',
    'geometry_msgs/msg/Vector3',
    'geometry_msgs/msg/Twist',
    'geometry_msgs/msg/TwistWithCovariance',
    'geometry_msgs/msg/Transform',
    'geometry_msgs/msg/TransformStamped',
    'nav_msgs/msg/Odometry',
    'sensor_msgs/msg/Imu',
    'tf2_msgs/msg/TFMessage',
    'rosgraph_msgs/msg/Clock',
    LOOP_CLOSURE_TYPE,
]


def time(sec, nanosec):
    return {'sec': sec, 'nanosec': nanosec}


def header(sec, nanosec, frame_id):
    return {'stamp': time(sec, nanosec), 'frame_id': frame_id}


def field(name, offset, datatype, count=1):
    return {'name': name, 'offset': offset, 'datatype': datatype, 'count': count}


def pose(x, y, z, qx, qy, qz, qw):
    return {
        'position': {'x': x, 'y': y, 'z': z},
        'orientation': {'x': qx, 'y': qy, 'z': qz, 'w': qw},
    }


def transform(x, y, z, qx, qy, qz, qw):
    return {
        'translation': {'x': x, 'y': y, 'z': z},
        'rotation': {'x': qx, 'y': qy, 'z': qz, 'w': qw},
    }


def covariance(scale):
    return [scale * (i - 17) for i in range(36)]


def radar_points():
    # nuScenes-like record: x y z float32, rcs int8 at 12, vx int16 at 13 (odd offset): 15 bytes.
    out = b''
    for i in range(3):
        out += struct.pack('<fffbh', 1.5 * i, -2.25 * i, 0.5, -5 + i, 300 * i - 2)
    return list(out)


CASES = [
    # A radar cloud with a packed 15-byte record: data length 45, not a multiple of 4.
    ('pointcloud2_radar', 'sensor_msgs/msg/PointCloud2', {
        'header': header(1532402927, 647951000, 'radar_front'),
        'height': 1,
        'width': 3,
        'fields': [field('x', 0, 7), field('y', 4, 7), field('z', 8, 7), field('rcs', 12, 1),
                   field('vx', 13, 3)],
        'is_bigendian': False,
        'point_step': 15,
        'row_step': 45,
        'data': radar_points(),
        'is_dense': True,
    }),
    # Everything empty: empty frame_id, no fields, no data.
    ('pointcloud2_empty', 'sensor_msgs/msg/PointCloud2', {
        'header': header(0, 0, ''),
        'height': 0,
        'width': 0,
        'fields': [],
        'is_bigendian': False,
        'point_step': 0,
        'row_step': 0,
        'data': [],
        'is_dense': False,
    }),
    # Organized 2x2 cloud, float64 field with count 2, big-endian flag, non-ASCII frame id, negative time.
    ('pointcloud2_organized', 'sensor_msgs/msg/PointCloud2', {
        'header': header(-3, 999999999, 'rädar_ß'),
        'height': 2,
        'width': 2,
        'fields': [field('intensity', 0, 8, 2)],
        'is_bigendian': True,
        'point_step': 16,
        'row_step': 32,
        'data': [(7 * i + 3) % 256 for i in range(64)],
        'is_dense': True,
    }),
    ('odometry', 'nav_msgs/msg/Odometry', {
        'header': header(1700000000, 500000000, 'odom'),
        'child_frame_id': 'base_link',
        'pose': {'pose': pose(12.5, -3.25, 0.125, 0.0, 0.0, 0.5, 0.5), 'covariance': covariance(0.0625)},
        'twist': {
            'twist': {'linear': {'x': 8.5, 'y': -0.25, 'z': 0.0},
                      'angular': {'x': 0.0, 'y': 0.0, 'z': 0.03125}},
            'covariance': covariance(-0.5),
        },
    }),
    # Short strings shift the float64 fields so that padding before them differs.
    ('odometry_short_frames', 'nav_msgs/msg/Odometry', {
        'header': header(1, 2, 'o'),
        'child_frame_id': 'ab',
        'pose': {'pose': pose(-1.0, 2.0, -4.0, 0.5, -0.5, 0.5, 0.5), 'covariance': covariance(1.0)},
        'twist': {
            'twist': {'linear': {'x': 0.0, 'y': 0.0, 'z': 0.0},
                      'angular': {'x': 0.0, 'y': 0.0, 'z': 0.0}},
            'covariance': [0.0] * 36,
        },
    }),
    # No orientation (-1 first, as a gyro-only driver publishes), a yaw rate and an acceleration.
    ('imu', 'sensor_msgs/msg/Imu', {
        'header': header(1700000000, 10000000, 'imu_link'),
        'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
        'orientation_covariance': [-1.0] + [0.0] * 8,
        'angular_velocity': {'x': 0.001953125, 'y': -0.00390625, 'z': 0.15625},
        'angular_velocity_covariance': [0.0009765625 * (i % 4 == 0) for i in range(9)],
        'linear_acceleration': {'x': 0.5, 'y': -0.25, 'z': 9.8125},
        'linear_acceleration_covariance': [0.0] * 9,
    }),
    ('tfmessage_empty', 'tf2_msgs/msg/TFMessage', {'transforms': []}),
    ('tfmessage_static', 'tf2_msgs/msg/TFMessage', {'transforms': [
        {'header': header(0, 0, 'base_link'), 'child_frame_id': 'radar_front',
         'transform': transform(3.375, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0)},
        {'header': header(1532402927, 1000, 'base_link'), 'child_frame_id': 'radar_back_left',
         'transform': transform(-0.5625, 0.625, 0.53125, 0.0, 0.0, 1.0, 0.0)},
    ]}),
    ('clock', 'rosgraph_msgs/msg/Clock', {'clock': time(1700000000, 123456789)}),
    ('header_trigger', 'std_msgs/msg/Header', header(1631895354, 18503000, 'PB4')),
    ('loop_closure', LOOP_CLOSURE_TYPE, {
        'header': header(1700000100, 250000000, 'base_link'),
        'query_id': 1234,
        'match_id': 2**40 + 7,
        'query_robot': 2,
        'match_robot': -7,
        'query_stamp': time(1700000100, 250000000),
        'match_stamp': time(1699999000, 750000000),
        'query_odom_pose': pose(100.5, 20.25, 0.0, 0.0, 0.0, 0.5, 0.5),
        'match_odom_pose': pose(99.75, 21.0, 0.0, 0.0, 0.0, -0.5, 0.5),
        'relative_pose': {'pose': pose(0.75, -0.75, 0.0, 0.0, 0.0, 0.0, 1.0),
                          'covariance': covariance(0.0078125)},
        'inliers': 57,
        'score': 0.875,
    }),
]


def main() -> None:
    store = typestore()
    cases = []
    for name, typename, d in CASES:
        msg = msg_from_dict(store, typename, d)
        le = bytes(store.serialize_cdr(msg, typename, little_endian=True))
        be = bytes(store.serialize_cdr(msg, typename, little_endian=False))
        cases.append({'name': name, 'type': typename, 'msg': d, 'cdr_hex': le.hex(), 'cdr_be_hex': be.hex()})
    out = {
        'generator': 'tests/python/make_cdr_fixtures.py',
        'rosbags_version': version('rosbags'),
        'typestore': 'ROS2_JAZZY',
        'type_hashes': {t: store.hash_rihs01(t) for t in TYPES},
        'cases': cases,
    }
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(out, indent=1, ensure_ascii=False) + '\n')
    print(f'wrote {len(cases)} cases to {OUT.relative_to(REPO)}')


if __name__ == '__main__':
    main()
