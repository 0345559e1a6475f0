#!/usr/bin/env python3
"""Writes tests/fixtures/rosbags_bag/ (a rosbag2 MCAP bag made by the rosbags library, not by dc_loc)
and tests/fixtures/rosbags_bag_expected.json (what the Rust reader must find in it).

The bag: version 9, MCAP storage with zstd-compressed chunks, the messages of make_cdr_fixtures.py on
five topics, written out of time order (the reader must return them in log-time order), /tf_static
offered transient local.

Run once (and again only to change the bag) with a Python that has rosbags:
    /tmp/bagvenv/bin/python tests/python/make_rosbags_bag.py
"""

from __future__ import annotations

import json
import shutil
from importlib.metadata import version

from make_cdr_fixtures import CASES
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags_dicts import REPO, msg_from_dict, typestore

OUT = REPO / 'tests' / 'fixtures' / 'rosbags_bag'
EXPECTED = REPO / 'tests' / 'fixtures' / 'rosbags_bag_expected.json'

INF = QosTime(9223372036, 854775807)


def qos(durability):
    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, durability, INF, INF,
               QosLiveliness.AUTOMATIC, INF, False)


# (topic, case name, log time ns), in the order written: not time-sorted on purpose.
SCHEDULE = [
    ('/tf_static', 'tfmessage_static', 1_700_000_000_000_000_000),
    ('/radar_front', 'pointcloud2_radar', 1_700_000_000_300_000_000),
    ('/odom', 'odometry', 1_700_000_000_200_000_000),
    ('/clock', 'clock', 1_700_000_000_100_000_000),
    ('/radar_front', 'pointcloud2_empty', 1_700_000_000_400_000_000),
    ('/odom', 'odometry_short_frames', 1_700_000_000_250_000_000),
    ('/radar_front', 'pointcloud2_organized', 1_700_000_000_350_000_000),
    ('/loop_closures', 'loop_closure', 1_700_000_000_500_000_000),
]


def main() -> None:
    store = typestore()
    cases = {name: (typename, d) for name, typename, d in CASES}
    if OUT.exists():
        shutil.rmtree(OUT)
    writer = Writer(OUT, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    expected = []
    with writer:
        conns = {}
        for topic, name, t in SCHEDULE:
            typename, d = cases[name]
            if topic not in conns:
                durability = (QosDurability.TRANSIENT_LOCAL if topic == '/tf_static'
                              else QosDurability.VOLATILE)
                conns[topic] = writer.add_connection(topic, typename, typestore=store,
                                                     offered_qos_profiles=[qos(durability)])
            raw = store.serialize_cdr(msg_from_dict(store, typename, d), typename)
            writer.write(conns[topic], t, raw)
            expected.append({'topic': topic, 'type': typename, 'log_time': t, 'case': name, 'msg': d})
    expected.sort(key=lambda m: m['log_time'])
    counts = {}
    for m in expected:
        counts[(m['topic'], m['type'])] = counts.get((m['topic'], m['type']), 0) + 1
    EXPECTED.write_text(json.dumps({
        'generator': 'tests/python/make_rosbags_bag.py',
        'rosbags_version': version('rosbags'),
        'topics': [{'name': k[0], 'type': k[1], 'count': v} for k, v in sorted(counts.items())],
        'messages': expected,
    }, indent=1, ensure_ascii=False) + '\n')
    size = sum(p.stat().st_size for p in OUT.iterdir())
    print(f'wrote {OUT.relative_to(REPO)} ({size} bytes) and {EXPECTED.relative_to(REPO)}')


if __name__ == '__main__':
    main()
