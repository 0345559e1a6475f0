"""A damaged map with ``map.start_empty_on_error`` (run by tests/node.rs).

    test_node_map_fallback.py --node BIN --map FILE

Starts ``BIN --ros-args -p map.file:=FILE -p map.start_empty_on_error:=true`` on loopback with a domain id of
its own, waits for its running line, stops it with SIGTERM, and checks: exit code 0, FILE unchanged, the
new (empty) map written to FILE.new. Prints "fallback: all checks passed" and exits 0, else exits 1.
"""

import argparse
import hashlib
import signal
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dcloc_testlib as tl


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--node", required=True)
    ap.add_argument("--map", required=True, type=Path)
    a = ap.parse_args()
    before = hashlib.sha256(a.map.read_bytes()).hexdigest()
    new = Path(str(a.map) + ".new")
    new.unlink(missing_ok=True)
    with tl.reserve_domain_id() as res:
        env = tl.loopback_env(res.domain_id)
        argv = [a.node, "--ros-args", "-p", f"map.file:={a.map}", "-p", "map.start_empty_on_error:=true"]
        with tl.ManagedProcess(argv, env, name="dc_loc") as node:
            node.wait_for_line(lambda l: "running" in l, 30.0, "the node's running line")
            node.proc.send_signal(signal.SIGTERM)
            code = node.proc.wait(timeout=20)
    ok = True
    for good, what in [(code == 0, f"SIGTERM: exit code {code}"),
                       (hashlib.sha256(a.map.read_bytes()).hexdigest() == before, "damaged map left untouched"),
                       (new.exists() and new.read_bytes()[:8] == b"DCLOCMAP", f"empty map saved to {new}")]:
        print(("ok   " if good else "FAIL ") + what)
        ok &= good
    print("fallback: all checks passed" if ok else "fallback: FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    tl.run_main(main)
