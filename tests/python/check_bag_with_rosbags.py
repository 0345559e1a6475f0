#!/usr/bin/env python3
"""Reads a rosbag2 bag with the rosbags library and checks it against an expectation (JSON).

Usage: check_bag_with_rosbags.py BAG EXPECT
  BAG     bag directory (or .mcap file)
  EXPECT  JSON text, or @path of a JSON file:
    {"topics": [{"name", "type", "count", "reliability"?, "durability"?}],
     "start_ns": int?, "end_ns": int?,
     "messages": [{"topic", "type", "log_time", "msg": {...}}]}   (all messages, any order)

Checks: topics with types, counts and QoS; every schema (msgdef) parses and matches the ROS 2 Jazzy
typestore; type hashes in metadata.yaml equal rosbags' RIHS01; start and end time; every message
decodes with rosbags' CDR deserialiser and equals the expected dict exactly. Prints a summary, exits
1 with the first mismatch.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from rosbags.rosbag2 import Reader
from rosbags.typesys import get_types_from_msg
from rosbags_dicts import msg_to_dict, typestore


def fail(msg: str) -> None:
    print(f'MISMATCH: {msg}')
    sys.exit(1)


def check_schema(store, conn) -> None:
    """The bag's schema text for a connection parses to the same fields as the typestore's types."""
    text = conn.msgdef.data
    if not text:
        fail(f'{conn.topic}: no message definition stored')
    parsed = get_types_from_msg(text, conn.msgtype)
    if conn.msgtype not in parsed:
        fail(f'{conn.topic}: schema does not define {conn.msgtype}')
    for name, (consts, fields) in parsed.items():
        if name not in store.fielddefs:
            fail(f'{conn.topic}: schema defines unknown type {name}')
        want_consts, want_fields = store.fielddefs[name]
        if [(f, d) for f, d in fields] != [(f, d) for f, d in want_fields]:
            fail(f'{conn.topic}: schema of {name} differs from the typestore: {fields} vs {want_fields}')
        if sorted(consts) != sorted(want_consts):
            fail(f'{conn.topic}: constants of {name} differ: {consts} vs {want_consts}')


def main() -> None:
    bag = Path(sys.argv[1])
    arg = sys.argv[2]
    expect = json.loads(Path(arg[1:]).read_text() if arg.startswith('@') else arg)
    store = typestore()

    with Reader(bag) as reader:
        conns = {c.topic: c for c in reader.connections}
        got_topics = sorted((c.topic, c.msgtype, c.msgcount) for c in reader.connections)
        want_topics = sorted((t['name'], t['type'], t['count']) for t in expect['topics'])
        if got_topics != want_topics:
            fail(f'topics {got_topics} != {want_topics}')
        for t in expect['topics']:
            conn = conns[t['name']]
            check_schema(store, conn)
            if bag.is_dir() and conn.digest != store.hash_rihs01(conn.msgtype):
                fail(f"{t['name']}: type hash {conn.digest!r} != rosbags' {store.hash_rihs01(conn.msgtype)!r}")
            qos = conn.ext.offered_qos_profiles
            for key in ('reliability', 'durability'):
                if key in t:
                    got = [getattr(q, key).name.lower() for q in qos]
                    if got != [t[key]]:
                        fail(f"{t['name']}: {key} {got} != {[t[key]]}")
        if 'start_ns' in expect and reader.start_time != expect['start_ns']:
            fail(f"start time {reader.start_time} != {expect['start_ns']}")
        # rosbags reports the end as one past the last message.
        if 'end_ns' in expect and reader.end_time != expect['end_ns'] + 1:
            fail(f"end time {reader.end_time} != {expect['end_ns']} + 1")

        got = []
        last = -1
        for conn, t, raw in reader.messages():
            if t < last:
                fail(f'{conn.topic} at {t}: messages not in time order')
            last = t
            msg = store.deserialize_cdr(raw, conn.msgtype)
            got.append((t, conn.topic, conn.msgtype, msg_to_dict(store, conn.msgtype, msg)))

    want = [(m['log_time'], m['topic'], m['type'], m['msg']) for m in expect['messages']]
    key = lambda m: (m[0], m[1], json.dumps(m[3], sort_keys=True))  # noqa: E731
    got.sort(key=key)
    want.sort(key=key)
    if len(got) != len(want):
        fail(f'{len(got)} messages read, {len(want)} expected')
    for g, w in zip(got, want):
        if g != w:
            fail(f'message {w[1]} at {w[0]}: read {g} expected {w}')
    print(f'rosbags read {bag}: {len(got_topics)} topics, {len(got)} messages, all as expected')
    for name, typ, count in got_topics:
        print(f'  {name} {typ} x{count}')


if __name__ == '__main__':
    main()
