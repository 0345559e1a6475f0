#!/usr/bin/env python3
"""DC-Loc against three peer registration methods on the radar submap pairs that dc_loc exported.

Each exported pair (a query submap, a target submap within 5 m of it, the true ``T_target_query`` and
DC-Loc's own estimate and single-threaded time) is registered again, source = query onto target = target,
by three peers, each on one thread:

- ``icp``: Open3D point-to-point ICP from the identity (the pairs are keyframes within 5 m of each other,
  so the identity is a fair local start, as ICP is used as a baseline);
- ``fpfh``: Open3D FPFH features + RANSAC (``registration_ransac_based_on_feature_matching``), refined by
  point-to-point ICP; the normals FPFH needs are estimated in the plane (``in_plane_normals``). RANSAC's
  3D fit can return the scene's mirror image (a half turn about an axis in the plane, which maps a
  straight street onto itself); such a result is a failure;
- ``gicp``: small_gicp GICP from the identity.

The script prints a markdown table (DC-Loc's row from the export, one row a peer, the ratios to DC-Loc)
and the project's targets for DC-Loc against its peers with PASS/FAIL. The criteria are informational: the exit code is 0 whatever
they say, and 2 on bad input.

Run it in the test venv (<repo>/.venv, made by tests/python/setup_venv.sh, which pins open3d-cpu and
small_gicp) on an export of dc_loc:

    dc_loc eval --bag B --params P --dcloc-only --export-pairs DIR
    source .venv/bin/activate
    python3 examples/peers.py DIR [--json OUT] [--max-pairs K] [--methods icp,fpfh,gicp]

Figures. Errors are those of dc_loc eval: translation error ``|t_truth - t_estimate|`` (m), rotation error
``|wrap(yaw_truth - yaw_estimate)|`` (rad). The "inlier share" is the share of all pairs whose
translation error is inside the export's outlier threshold (``outlier_threshold`` in meta.json); the
means "inside the threshold" are over those pairs alone, as dc_loc eval reports its tables. A
method's failure on a pair (an exception, no estimate, or a rotation that leaves the plane) counts as a
pair outside the threshold and is left out of the mean, median and maximum; the table says how many
failed. Time is wall time (``time.perf_counter``) of one method on one pair: building its clouds, its
features or covariances and registering; reading the export is not timed, and each peer first registers
the first pair once untimed, so that one-time start-up costs fall on no pair. DC-Loc's time comes from
the export run and likewise covers preparing both submaps and registering on one thread: the time
ratios are fair when both runs had the same, otherwise idle, machine. A last line splits DC-Loc's time
into preparing the submaps and registering them, since the node prepares each keyframe once and
registers it against several.
"""

from __future__ import annotations

import os

# One thread for every peer: Open3D and small_gicp parallelise with OpenMP, which reads this variable
# once, when the library loads.
os.environ["OMP_NUM_THREADS"] = "1"

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

PEERS = ("icp", "fpfh", "gicp")
LABELS = {
    "dcloc": "DC-Loc",
    "icp": "ICP (Open3D)",
    "fpfh": "FPFH+RANSAC+ICP (Open3D)",
    "gicp": "GICP (small_gicp)",
}
# The targets: DC-Loc's mean translation error at most this share of the best peer's, its time
# per pair at most this share of ICP's.
ERROR_RATIO_LIMIT = 0.7
TIME_RATIO_LIMIT = 0.5


class BadInput(Exception):
    """The export is missing, malformed, or inconsistent with itself."""


class MethodFailure(Exception):
    """A method gave no usable estimate on a pair."""


# ---- settings ---------------------------------------------------------------------------------------------


@dataclass
class Settings:
    """The peers' parameters: the best of a sweep on dc_loc's demo export (416 pairs of radar submaps,
    90-990 points over about 100 m, point spacing 0.3-1 m), judged by mean translation error and
    inlier share."""

    # ICP: correspondence distances of a coarse-to-fine schedule, each pass starting from the last one's
    # result. A single pass trades reach against precision (0.5 m: mean 1.31 m, 282/416 inside; 2 m:
    # 0.29 m, 409; 5 m: 0.77 m, 384); 2.5 m then 0.5 m reaches the offsets of pairs up to 5 m apart and
    # then settles on the walls without averaging in the radar noise (0.19 m, 412).
    icp_distances: tuple[float, ...] = (2.5, 0.5)
    icp_iterations: int = 50
    # FPFH: a 1 m voxel, about the point spacing; normals over 2.5 m (a few neighbours along a wall on
    # each side); the histogram over 10 m, which spans a corner or pole and the walls around it. On 104
    # evenly spaced pairs: 0.36 m mean, 96 inside; a 5 m histogram 0.73 m, 96; a 0.5 m voxel 0.50-0.59 m
    # at twice the time; a 2 m voxel 0.9-1.5 m, 82-89 inside.
    fpfh_voxel: float = 1.0
    fpfh_normal_radius: float = 2.5
    fpfh_feature_radius: float = 10.0
    # RANSAC: inliers within 1.5 voxels (Open3D's rule; 1.0 and 2.5 were worse), Open3D's default
    # budget, and no mutual filter (with it, 79 of those 104 pairs inside instead of 96). The refining
    # ICP runs on the full clouds at the ICP schedule's last distance.
    ransac_distance: float = 1.5
    ransac_iterations: int = 100_000
    ransac_confidence: float = 0.999
    ransac_mutual: bool = False
    # GICP: small_gicp's voxel downsampling and a coarse-to-fine schedule of correspondence distances as
    # for ICP (0.25 m voxels: no better and 3 x slower; one pass at 2 m: 0.26 m mean, 409 inside; 2.5 m
    # then 1 m: 0.19 m, 411).
    gicp_downsampling: float = 0.5
    gicp_distances: tuple[float, ...] = (2.5, 1.0)
    gicp_iterations: int = 50


# ---- the export -------------------------------------------------------------------------------------------


@dataclass
class Outcome:
    """One method on one pair: errors (None on failure) and wall time."""

    translation: float | None
    rotation: float | None
    seconds: float
    # DC-Loc only: the share of ``seconds`` spent preparing the two submaps (None when not exported).
    prepare_seconds: float | None = None


@dataclass
class Pair:
    """One exported pair: its two submaps (n x 2, metres), the truth and DC-Loc's outcome."""

    query: np.ndarray
    target: np.ndarray
    truth: np.ndarray
    dcloc: Outcome


@dataclass
class Export:
    meta: dict[str, Any]
    pairs: list[Pair]

    @property
    def threshold(self) -> float:
        return float(self.meta["outlier_threshold"])


def read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise BadInput(f"{path}: no such file") from None
    except (OSError, ValueError) as e:
        raise BadInput(f"{path}: {e}") from None


def read_points(path: Path) -> np.ndarray:
    """The points file as an (n, 2) float64 array."""
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise BadInput(f"{path}: {e.strerror or e}") from None
    if len(raw) % 8:
        raise BadInput(f"{path}: {len(raw)} bytes is not a whole number of (x, y) float32 points")
    return np.frombuffer(raw, dtype="<f4").reshape(-1, 2).astype(np.float64)


def submap(points: np.ndarray, span: Any, where: str) -> np.ndarray:
    try:
        offset, count = int(span["offset"]), int(span["count"])
    except (TypeError, KeyError, ValueError):
        raise BadInput(f"{where}: needs integer 'offset' and 'count'") from None
    if offset < 0 or count < 0 or offset + count > len(points):
        raise BadInput(
            f"{where}: points {offset}..{offset + count} lie beyond the points file ({len(points)} points)"
        )
    return points[offset : offset + count]


def dcloc_outcome(record: Any, where: str) -> Outcome:
    """DC-Loc's errors and time on a pair; no estimate (or no error) is a failure."""
    try:
        seconds = float(record["seconds"])
        prepare = record.get("prepare_seconds")
        prepare = None if prepare is None else float(prepare)
        if record.get("estimate") is None or record.get("translation_error") is None:
            return Outcome(None, None, seconds, prepare)
        return Outcome(
            float(record["translation_error"]), float(record["rotation_error"]), seconds, prepare
        )
    except (AttributeError, TypeError, KeyError, ValueError):
        raise BadInput(f"{where}: 'dcloc' needs 'seconds', and errors with its estimate") from None


def parse_pair(record: Any, points: np.ndarray, where: str) -> Pair:
    try:
        truth = np.array(record["truth"], dtype=np.float64)
        query, target, dcloc = record["query"], record["target"], record["dcloc"]
    except (TypeError, KeyError, ValueError):
        raise BadInput(f"{where}: needs 'query', 'target', 'truth' and 'dcloc'") from None
    if truth.shape != (3,) or not np.all(np.isfinite(truth)):
        raise BadInput(f"{where}: 'truth' must be [x, y, yaw]")
    return Pair(
        submap(points, query, where + " query"),
        submap(points, target, where + " target"),
        truth,
        dcloc_outcome(dcloc, where),
    )


def read_export(directory: Path) -> Export:
    meta = read_json(directory / "meta.json")
    if not isinstance(meta, dict) or "outlier_threshold" not in meta:
        raise BadInput(f"{directory / 'meta.json'}: needs 'outlier_threshold'")
    points = read_points(directory / str(meta.get("points_file", "points.f32")))
    path = directory / "pairs.jsonl"
    try:
        lines = [line for line in path.read_text().splitlines() if line.strip()]
    except OSError as e:
        raise BadInput(f"{path}: {e.strerror or e}") from None
    pairs = []
    for number, line in enumerate(lines, start=1):
        try:
            record = json.loads(line)
        except ValueError as e:
            raise BadInput(f"{path}:{number}: {e}") from None
        pairs.append(parse_pair(record, points, f"{path}:{number}"))
    if "pairs" in meta and meta["pairs"] != len(pairs):
        raise BadInput(f"{path}: {len(pairs)} pairs, meta.json says {meta['pairs']}")
    return Export(meta, pairs)


def evenly_spaced(pairs: list[Pair], k: int | None) -> list[Pair]:
    if k is None or k >= len(pairs):
        return pairs
    picks = np.unique(np.linspace(0, len(pairs) - 1, max(k, 1)).round().astype(int))
    return [pairs[i] for i in picks]


# ---- SE(2) helpers ----------------------------------------------------------------------------------------


def lift(points: np.ndarray) -> np.ndarray:
    """(n, 2) -> (n, 3) with z = 0, as the 3D libraries take them."""
    return np.column_stack([points, np.zeros(len(points))])


def planar(t: np.ndarray) -> np.ndarray:
    """A 4 x 4 rigid transform of the plane z = 0 as [x, y, yaw]. A rotation that turns the plane over
    (its z axis flipped, a mirror image in the plane) is no SE(2) estimate."""
    t = np.asarray(t, dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise MethodFailure("non-finite transform")
    if t[2, 2] < 0.5:
        raise MethodFailure("rotation leaves the plane")
    return np.array([t[0, 3], t[1, 3], math.atan2(t[1, 0], t[0, 0])])


def errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Translation and rotation error as dc_loc eval scores them."""
    dyaw = math.remainder(truth[2] - estimate[2], math.tau)
    return float(math.hypot(*(truth[:2] - estimate[:2]))), abs(dyaw)


# ---- the peers --------------------------------------------------------------------------------------------


def open3d_module() -> Any:
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    o3d.utility.random.seed(0)
    return o3d


def o3d_cloud(o3d: Any, points: np.ndarray) -> Any:
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(lift(points)))


def icp_schedule(o3d: Any, source: Any, target: Any, init: np.ndarray, s: Settings) -> np.ndarray:
    """Point-to-point ICP through the coarse-to-fine correspondence distances."""
    reg = o3d.pipelines.registration
    criteria = reg.ICPConvergenceCriteria(max_iteration=s.icp_iterations)
    for distance in s.icp_distances:
        init = reg.registration_icp(
            source, target, distance, init, reg.TransformationEstimationPointToPoint(), criteria
        ).transformation
    return np.asarray(init)


def run_icp(o3d: Any, query: np.ndarray, target: np.ndarray, s: Settings) -> np.ndarray:
    source, goal = o3d_cloud(o3d, query), o3d_cloud(o3d, target)
    return icp_schedule(o3d, source, goal, np.eye(4), s)


def in_plane_normals(o3d: Any, cloud: Any, radius: float, max_nn: int = 30) -> np.ndarray:
    """Normals in the plane: the points are planar (z = 0), so Open3D's 3D normal estimation would give
    every point the normal z and make FPFH's angles meaningless. Instead the normal is perpendicular,
    in the plane, to the local line: the minor axis of the xy covariance of the neighbourhood (z = 0).
    Each normal faces the submap's anchor (the origin), where the radar looked from."""
    cloud.estimate_covariances(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_nn))
    cov = np.asarray(cloud.covariances)
    major = 0.5 * np.arctan2(2.0 * cov[:, 0, 1], cov[:, 0, 0] - cov[:, 1, 1])
    normals = np.column_stack([-np.sin(major), np.cos(major), np.zeros(len(cov))])
    towards_anchor = -np.einsum("ij,ij->i", normals, np.asarray(cloud.points))
    normals[towards_anchor < 0] *= -1.0
    return normals


def fpfh_features(o3d: Any, points: np.ndarray, s: Settings) -> tuple[Any, Any]:
    """The voxel-downsampled cloud with in-plane normals, and its FPFH features."""
    cloud = o3d_cloud(o3d, points).voxel_down_sample(s.fpfh_voxel)
    cloud.normals = o3d.utility.Vector3dVector(in_plane_normals(o3d, cloud, s.fpfh_normal_radius))
    search = o3d.geometry.KDTreeSearchParamHybrid(radius=s.fpfh_feature_radius, max_nn=100)
    return cloud, o3d.pipelines.registration.compute_fpfh_feature(cloud, search)


def ransac(o3d: Any, source: tuple[Any, Any], target: tuple[Any, Any], s: Settings) -> np.ndarray:
    reg = o3d.pipelines.registration
    checkers = [
        reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
        reg.CorrespondenceCheckerBasedOnDistance(s.ransac_distance),
    ]
    result = reg.registration_ransac_based_on_feature_matching(
        source[0], target[0], source[1], target[1], s.ransac_mutual, s.ransac_distance,
        reg.TransformationEstimationPointToPoint(False), 3, checkers,
        reg.RANSACConvergenceCriteria(s.ransac_iterations, s.ransac_confidence),
    )
    if len(result.correspondence_set) < 3:
        raise MethodFailure("RANSAC found no consensus")
    return np.asarray(result.transformation)


def run_fpfh(o3d: Any, query: np.ndarray, target: np.ndarray, s: Settings) -> np.ndarray:
    coarse = ransac(o3d, fpfh_features(o3d, query, s), fpfh_features(o3d, target, s), s)
    fine = Settings(**{**s.__dict__, "icp_distances": s.icp_distances[-1:]})
    return icp_schedule(o3d, o3d_cloud(o3d, query), o3d_cloud(o3d, target), coarse, fine)


def run_gicp(query: np.ndarray, target: np.ndarray, s: Settings) -> np.ndarray:
    """small_gicp's preprocessing (voxel downsampling, 10-neighbour covariances) and GICP through the
    distance schedule. On planar points its covariances come out flat in the plane (normal z), so
    in the plane GICP weighs every direction alike; extruding the points into vertical walls, to give
    it in-plane normals, did worse (one 2 m pass: 0.32 m mean and 402/416 inside, against 0.26 m and
    409/416)."""
    import small_gicp

    target_cloud, target_tree = small_gicp.preprocess_points(lift(target), s.gicp_downsampling, 10, 1)
    source_cloud, _ = small_gicp.preprocess_points(lift(query), s.gicp_downsampling, 10, 1)
    t = np.eye(4)
    for distance in s.gicp_distances:
        t = small_gicp.align(
            target_cloud, source_cloud, target_tree, t, registration_type="GICP",
            max_correspondence_distance=distance, num_threads=1, max_iterations=s.gicp_iterations,
        ).T_target_source
    return np.asarray(t)


def method_runner(name: str, s: Settings) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A function (query, target) -> 4 x 4 T_target_query for the peer `name`; its library loads here,
    outside the timed calls."""
    if name == "gicp":
        import small_gicp  # noqa: F401

        return lambda q, t: run_gicp(q, t, s)
    o3d = open3d_module()
    run = run_icp if name == "icp" else run_fpfh
    return lambda q, t: run(o3d, q, t, s)


# ---- scoring ----------------------------------------------------------------------------------------------


def register(run: Callable[[np.ndarray, np.ndarray], np.ndarray], pair: Pair) -> Outcome:
    start = time.perf_counter()
    try:
        if min(len(pair.query), len(pair.target)) < 3:
            raise MethodFailure("fewer than 3 points")
        estimate = planar(run(pair.query, pair.target))
    except Exception:  # any library error is the method's failure on this pair
        return Outcome(None, None, time.perf_counter() - start)
    seconds = time.perf_counter() - start
    return Outcome(*errors(estimate, pair.truth), seconds)


@dataclass
class Summary:
    n: int
    failures: int
    inside: int
    mean: float
    median: float
    max: float
    rotation_mean: float
    inside_mean: float
    inside_median: float
    ms_mean: float
    ms_median: float

    @property
    def share(self) -> float:
        return self.inside / self.n if self.n else 0.0


def stat(f: Callable[[np.ndarray], Any], x: np.ndarray) -> float:
    """f(x), or NaN for no values (every pair failed)."""
    return float(f(x)) if len(x) else math.nan


def summarise(outcomes: list[Outcome], threshold: float) -> Summary:
    ok = [o for o in outcomes if o.translation is not None]
    t = np.array([o.translation for o in ok], dtype=np.float64)
    r = np.array([o.rotation for o in ok], dtype=np.float64)
    ms = 1e3 * np.array([o.seconds for o in outcomes], dtype=np.float64)
    inside = t[t <= threshold]
    return Summary(
        n=len(outcomes), failures=len(outcomes) - len(ok), inside=int(np.sum(t <= threshold)),
        mean=stat(np.mean, t), median=stat(np.median, t), max=stat(np.max, t),
        rotation_mean=stat(np.mean, r), inside_mean=stat(np.mean, inside),
        inside_median=stat(np.median, inside), ms_mean=stat(np.mean, ms), ms_median=stat(np.median, ms),
    )


def run_peer(name: str, pairs: list[Pair], s: Settings, threshold: float) -> Summary:
    run = method_runner(name, s)
    register(run, pairs[0])  # untimed warm-up: first-call costs (thread pools, lazy tables) are no pair's
    progress = sys.stderr.isatty()
    outcomes = []
    for i, pair in enumerate(pairs, start=1):
        outcomes.append(register(run, pair))
        if progress:
            print(f"\r{LABELS[name]}: {i}/{len(pairs)}", end="", file=sys.stderr, flush=True)
    if progress:
        print(file=sys.stderr)
    return summarise(outcomes, threshold)


# ---- report -----------------------------------------------------------------------------------------------


def ratio(a: float, b: float) -> float:
    return a / b if b > 0 and math.isfinite(a) and math.isfinite(b) else math.nan


def criteria(results: dict[str, Summary]) -> dict[str, dict[str, Any]]:
    """The three criteria, measured; a criterion without the peer it needs is left out. The mean
    translation error is compared over each method's pairs inside the threshold, as dc_loc eval reports
    it (a global method's rare far-off answer would otherwise outweigh its accuracy), and over all
    pairs it answered."""
    dc, peers = results["dcloc"], {k: v for k, v in results.items() if k != "dcloc"}
    out: dict[str, dict[str, Any]] = {}
    for key, figure in (("translation", "inside_mean"), ("translation_all_pairs", "mean")):
        finite = {k: v for k, v in peers.items() if math.isfinite(getattr(v, figure))}
        if finite:
            best = min(finite, key=lambda k: getattr(finite[k], figure))
            r = ratio(getattr(dc, figure), getattr(finite[best], figure))
            out[key] = {
                "peer": best, "ratio": r, "limit": ERROR_RATIO_LIMIT, "pass": r <= ERROR_RATIO_LIMIT
            }
    if peers:
        best = max(peers, key=lambda k: peers[k].share)
        r = dc.share / peers[best].share if peers[best].share > 0 else math.inf
        out["inliers"] = {"peer": best, "ratio": r, "limit": 1.0, "pass": dc.share >= peers[best].share}
    if "icp" in peers:
        r = ratio(dc.ms_mean, peers["icp"].ms_mean)
        out["time"] = {"peer": "icp", "ratio": r, "limit": TIME_RATIO_LIMIT, "pass": r <= TIME_RATIO_LIMIT}
    return out


def table(results: dict[str, Summary]) -> str:
    dc = results["dcloc"]
    rows = [
        "| method | translation mean / median / max (m) | inside the threshold: mean / median (m) "
        "| rotation mean (rad) | inside threshold | failures | time per pair mean / median (ms) "
        "| mean error inside / DC-Loc | time / DC-Loc |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        rows.append(
            f"| {LABELS[name]} | {r.mean:.3f} / {r.median:.3f} / {r.max:.2f} "
            f"| {r.inside_mean:.3f} / {r.inside_median:.3f} | {r.rotation_mean:.4f} "
            f"| {r.inside}/{r.n} ({100 * r.share:.1f} %) | {r.failures} "
            f"| {r.ms_mean:.2f} / {r.ms_median:.2f} "
            f"| {ratio(r.inside_mean, dc.inside_mean):.2f} | {ratio(r.ms_mean, dc.ms_mean):.2f} |"
        )
    return "\n".join(rows)


def dcloc_stages(pairs: list[Pair]) -> dict[str, float] | None:
    """DC-Loc's mean time per pair split into preparing both submaps and registering them, ms; None
    when the export does not say."""
    prepare = [p.dcloc.prepare_seconds for p in pairs]
    if any(x is None for x in prepare):
        return None
    ms_prepare = 1e3 * float(np.mean(prepare))
    ms_total = 1e3 * float(np.mean([p.dcloc.seconds for p in pairs]))
    return {"prepare_ms_mean": ms_prepare, "register_ms_mean": ms_total - ms_prepare}


def stages_line(stages: dict[str, float], results: dict[str, Summary]) -> str:
    line = (f"DC-Loc's time per pair: {stages['prepare_ms_mean']:.2f} ms preparing both submaps "
            f"(the node prepares each keyframe once), {stages['register_ms_mean']:.2f} ms registering them")
    if "icp" in results:
        r = ratio(stages["register_ms_mean"], results["icp"].ms_mean)
        line += f"; registering alone / {LABELS['icp']} = {r:.2f}"
    return line + "."


def criteria_line(c: dict[str, dict[str, Any]]) -> str:
    texts = {
        "translation": "mean translation error inside the threshold DC-Loc / best peer ({peer}) = "
        "{ratio:.2f} (<= {limit})",
        "translation_all_pairs": "over all pairs answered DC-Loc / best peer ({peer}) = {ratio:.2f} "
        "(<= {limit})",
        "inliers": "inlier share DC-Loc / best peer ({peer}) = {ratio:.3f} (>= {limit:g})",
        "time": "time per pair DC-Loc / {peer} = {ratio:.2f} (<= {limit})",
    }
    parts = [
        texts[k].format(**{**v, "peer": LABELS[v["peer"]]}) + (": PASS" if v["pass"] else ": FAIL")
        for k, v in c.items()
    ]
    return "Criteria: " + ("; ".join(parts) if parts else "none measurable (no peer ran)") + "."


def clean(x: Any) -> Any:
    """JSON has no NaN or infinity: null instead."""
    return None if isinstance(x, float) and not math.isfinite(x) else x


# Every figure of a method that --json writes.
FIGURES = ("mean", "median", "max", "rotation_mean", "inside_mean", "inside_median", "inside", "n",
           "failures", "ms_mean", "ms_median", "share")


def json_report(export: Export, n: int, s: Settings, results: dict[str, Summary], c: dict[str, Any],
                stages: dict[str, float] | None) -> str:
    methods = {k: {f: clean(getattr(v, f)) for f in FIGURES} for k, v in results.items()}
    if stages:
        methods["dcloc"].update(stages)
    body = {
        "pairs": n, "outlier_threshold": export.threshold, "source": export.meta.get("source"),
        "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in s.__dict__.items()},
        "methods": methods,
        "criteria": {k: {f: clean(x) for f, x in v.items()} for k, v in c.items()},
    }
    return json.dumps(body, indent=2) + "\n"


# ---- command line -----------------------------------------------------------------------------------------


def floats(text: str) -> tuple[float, ...]:
    values = tuple(float(x) for x in text.split(",") if x.strip())
    if not values or min(values) <= 0:
        raise argparse.ArgumentTypeError("positive numbers separated by commas")
    return values


def methods_arg(text: str) -> list[str]:
    names = [x.strip() for x in text.split(",") if x.strip()]
    unknown = [x for x in names if x not in PEERS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"choose from {','.join(PEERS)} (got {text!r})")
    return list(dict.fromkeys(names))


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    d = Settings()
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("export", type=Path, help="directory written by dc_loc eval --export-pairs")
    p.add_argument("--json", type=Path, metavar="OUT", help="write every figure to OUT as JSON")
    p.add_argument("--max-pairs", type=int, metavar="K", help="use K evenly spaced pairs")
    p.add_argument("--methods", type=methods_arg, default=list(PEERS), help="peers, e.g. icp,fpfh,gicp")
    p.add_argument("--icp-distances", type=floats, default=d.icp_distances, help="ICP schedule (m)")
    p.add_argument("--fpfh-voxel", type=float, default=d.fpfh_voxel, help="FPFH voxel size (m)")
    p.add_argument("--fpfh-normal-radius", type=float, default=d.fpfh_normal_radius, help="m")
    p.add_argument("--fpfh-feature-radius", type=float, default=d.fpfh_feature_radius, help="m")
    p.add_argument("--ransac-distance", type=float, default=d.ransac_distance, help="m")
    p.add_argument("--gicp-downsampling", type=float, default=d.gicp_downsampling, help="m")
    p.add_argument("--gicp-distances", type=floats, default=d.gicp_distances, help="GICP schedule (m)")
    args = p.parse_args(argv)
    if args.max_pairs is not None and args.max_pairs < 1:
        p.error("--max-pairs must be at least 1")
    return args


def settings_from(args: argparse.Namespace) -> Settings:
    names = Settings.__dataclass_fields__
    return Settings(**{k: v for k, v in vars(args).items() if k in names})


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        export = read_export(args.export)
    except BadInput as e:
        print(f"peers.py: bad input: {e}", file=sys.stderr)
        return 2
    pairs = evenly_spaced(export.pairs, args.max_pairs)
    if not pairs:
        print(f"peers.py: bad input: {args.export} has no pairs", file=sys.stderr)
        return 2
    s = settings_from(args)
    results = {"dcloc": summarise([p.dcloc for p in pairs], export.threshold)}
    for name in (m for m in PEERS if m in args.methods):
        results[name] = run_peer(name, pairs, s, export.threshold)
    c = criteria(results)
    print(f"{len(pairs)} pairs from {export.meta.get('source', args.export)}, "
          f"outlier threshold {export.threshold} m, one thread each\n")
    print(table(results))
    print()
    print(criteria_line(c))
    stages = dcloc_stages(pairs)
    if stages:
        print(stages_line(stages, results))
    if args.json:
        args.json.write_text(json_report(export, len(pairs), s, results, c, stages))
    return 0


if __name__ == "__main__":
    sys.exit(main())
