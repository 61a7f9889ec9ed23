"""The end-to-end tables of docs/performance.md, from `bench/e2e_dds.py --json` runs (called as a command).

Each table has its baseline from the same run: bare rclpy for the publish orders, the default
`max_waiting_frames` for the queue lengths, the ROS 1 C++ stereo_image_proc anchor run in turn with the
node (`--anchor DIR`), `default` for the quality profile's rate.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from e2e_dds import PAIRING, median_figures, median_row

from lib.table import ratio, table_header, table_row, times

E2E = Path(__file__).resolve().parents[1] / "e2e_dds.py"
PAIRING_LABELS = {
    "bare_vga_30": "bare rclpy, disparity- and cloud-sized messages (the baseline)",
    "bm_vga_30_info_first": "camera_info first (left info, right info, left image, right image)",
    "bm_vga_30": "each camera_info after its image",
    "bm_vga_30_bgr8_info_first": "camera_info first, bgr8 colour (921 KB images)",
    "bm_vga_30_right_2_late": "camera_info first, right camera 2 frames late",
    "bm_vga_30_bursts_of_3": "camera_info first, bursts of 3 frames",
}
OUTPUTS = ("disparity", "points2")
LATENCIES = ("lat_median", "lat_p95", "send_lat_median", "send_lat_p95")
NAN = float("nan")
BARE_NONE, BARE_ALL = ("bare_vga_30", "none"), ("bare_vga_30", "all")
QUEUE_CASE = "bm_vga_30_bgr8_info_first"  # the case whose DDS bursts a short queue turns into losses
DEFAULT_WAITING = 3  # max_waiting_frames' default, measured in the pairing run
# (case, the anchor's case name or None, [(our case, label)]): the Performance table's groups
ANCHOR_GROUPS: list[tuple[str, str | None, list[tuple[str, str]]]] = [
    (
        "BM 640x480",
        "bm vga 1x",
        [("bm_vga_30_16b", "stereo_node, 16 B points"), ("bm_vga_30", "stereo_node, 32 B points (default)")],
    ),
    ("BM 640x480, disparity only", "bm vga 1x disparity-only", [("bm_vga_30_disparity_only", "stereo_node")]),
    (
        "SGBM 640x480",
        "sgbm vga 1x",
        [("sgbm_vga_30_16b", "stereo_node, 16 B points"), ("sgbm_vga_30", "stereo_node, 32 B points")],
    ),
    (
        "BM 1280x720",
        "bm hd720 1x",
        [("bm_720p_30_16b", "stereo_node, 16 B points"), ("bm_720p_30", "stereo_node, 32 B points")],
    ),
    ("`profile:=fast` 640x480 @ 15 Hz", None, [("fast_vga_15", "stereo_node")]),
    ("`fast` @ 30 Hz", None, [("fast_vga_30", "stereo_node")]),
    ("`fast` @ 60 Hz (newest set kept)", None, [("fast_vga_60", "stereo_node")]),
]
QUALITY_CASES = ("default_vga_30_128", "quality_vga_30_128")  # default first: the baseline


def frames(quick: bool) -> int:
    """Frames per e2e run: 5 s at 30 Hz after the warm-up, enough for a median and a p95 (--quick: 1 s)."""
    return 30 if quick else 150


Rows = dict[tuple[str, str], dict[str, Any]]


@dataclass(frozen=True)
class E2eRun:
    """One e2e_dds.py run's figures: (case, profile) -> median row; anchor case -> its median figures."""

    rows: Rows
    anchor: dict[str, dict[str, Any]]


def e2e_run(work: Path, quick: bool, *options: str) -> E2eRun | None:
    """One e2e_dds.py run (its own table goes to stderr as progress); None (and a note) if it failed."""
    report = work / f"e2e_{time.monotonic_ns()}.json"
    command = [sys.executable, str(E2E), *options, "--frames", str(frames(quick)), "--json", str(report)]
    print(f"$ {' '.join(command)}", file=sys.stderr, flush=True)
    if subprocess.run(command, stdout=sys.stderr, check=False).returncode != 0:
        print(f"(failed: {' '.join(options)}; see the output above on stderr)")
        return None
    written = json.loads(report.read_text())  # e2e_dds --json: {"runs": [...], "anchor": {case: [...]}}
    runs: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in written["runs"]:
        for output in (row[name] for name in OUTPUTS if row[name]):  # no output seen: no latency, NaN
            output.update({key: output.get(key, NAN) for key in LATENCIES})
        runs.setdefault((row["case"], row["profile"]), []).append(row)
    rows = {key: median_row(rows) if len(rows) > 1 else rows[0] for key, rows in runs.items()}
    return E2eRun(rows, {name: median_figures(figures) for name, figures in written["anchor"].items()})


def e2e_rows(work: Path, quick: bool, *options: str) -> Rows | None:
    run = e2e_run(work, quick, *options)
    return None if run is None else run.rows


def span(values: list[float], digits: int = 0) -> str:
    values = [v for v in values if v == v] or [NAN]
    low, high = f"{min(values):.{digits}f}", f"{max(values):.{digits}f}"
    return low if low == high else f"{low}-{high}"


def latency_pair(row: dict[str, Any], key: str) -> tuple[float, float]:
    return row["disparity"][key], row["points2"][key]


def pairing(work: Path, quick: bool) -> bool:
    """Publish orders with and without the profile exported, against bare rclpy; then the queue lengths."""
    rows = e2e_rows(work, quick, "--pairing")
    if rows is None:
        return False
    n = frames(quick)
    print(f"VGA, `profile:=stereo_image_proc`, 30 Hz, {n} frames, driver / stereo_node / viewer in three processes:\n")
    columns = ["publish order per frame (driver)", "profile exported", "disparity Hz", "points2 Hz", f"lost /{n}"]
    columns += ["latency ms, median from the driver's send (disparity / points2)", "latency vs bare rclpy"]
    print(table_header(columns))
    for case in PAIRING:
        print(table_row((PAIRING_LABELS[case], "none", *pairing_cells([rows[(case, "none")]], rows[BARE_NONE]))))
    everything = [rows[(case, "all")] for case in PAIRING if case != "bare_vga_30"]
    print(table_row(("any of the above", "all three processes", *pairing_cells(everything, rows[BARE_ALL]))))
    return queue_lengths(work, quick, rows[(QUEUE_CASE, "none")])


def pairing_cells(rows: list[dict[str, Any]], bare: dict[str, Any]) -> list[str]:
    """Rate, losses, latency from the driver's send and its ratio to bare rclpy; ranges over several rows."""
    hz = [span([r[output]["hz"] for r in rows], 1) for output in OUTPUTS]
    lost = " / ".join(span([r[output]["dropped"] for r in rows]) for output in OUTPUTS)
    latency = [[r[output]["send_lat_median"] for r in rows] for output in OUTPUTS]
    bare_latency = [bare[output]["send_lat_median"] for output in OUTPUTS]
    ratios = [span([v / base for v in values], 2) + "x" for values, base in zip(latency, bare_latency, strict=True)]
    return [*hz, lost, " / ".join(span(values) for values in latency), " / ".join(ratios)]


def queue_lengths(work: Path, quick: bool, default_row: dict[str, Any]) -> bool:
    """The bgr8 case with 1 and 2 waiting places against the default 3, no profile exported."""
    by_waiting = {DEFAULT_WAITING: default_row}
    for waiting in (1, 2):
        options = ("--cases", QUEUE_CASE, "--profiles", "none", "--param", f"max_waiting_frames:={waiting}")
        rows = e2e_rows(work, quick, *options)
        if rows is None:
            return False
        by_waiting[waiting] = rows[(QUEUE_CASE, "none")]
    print(f"\n{PAIRING_LABELS[QUEUE_CASE]}, no profile exported, by `max_waiting_frames`:\n")
    columns = ["`max_waiting_frames`", "disparity Hz", f"lost /{frames(quick)}", "latency ms (disparity / points2)"]
    print(table_header([*columns, f"latency vs {DEFAULT_WAITING} (the default)"]))
    base = latency_pair(default_row, "send_lat_median")
    for waiting in sorted(by_waiting):
        row = by_waiting[waiting]
        latency = latency_pair(row, "send_lat_median")
        cells = (waiting, f"{row['disparity']['hz']:.1f}", f"{row['disparity']['dropped']:.0f}")
        versus = f"{times(latency[0] / base[0])} / {times(latency[1] / base[1])}"
        print(table_row((*cells, f"{latency[0]:.0f} / {latency[1]:.0f}", versus)))
    return True


def anchor(work: Path, quick: bool, folder: Path) -> bool:
    """The node beside the ROS 1 C++ anchor (folder/run.sh), run in turn case by case, profile exported
    everywhere, latency as the anchor measures it (from the monitor's receipt of left/image_raw)."""
    cases = [case for _, _, ours in ANCHOR_GROUPS for case, _ in ours]
    run = e2e_run(work, quick, "--cases", *cases, "--profiles", "all", "--anchor", str(folder))
    if run is None:
        return False
    n = frames(quick)
    print(f"{n} frames per case, the C++ chain run after each of our runs of a case it has:")
    columns = ["case", "", "disparity Hz", "points2 Hz", f"dropped /{n} (disparity / points2)"]
    columns += ["disparity latency ms", "points2 latency ms (p95)", "latency vs C++ (disparity / points2)", "node CPU"]
    print(table_header(columns))
    missing = []
    for case, anchor_name, ours in ANCHOR_GROUPS:
        theirs = run.anchor.get(anchor_name or "")
        first = case
        if theirs:
            points = theirs.get("points2_hz")
            dropped = f"{theirs['disparity_dropped']:.0f}" + (f" / {theirs['points2_dropped']:.0f}" if points else "")
            label = "C++ ROS 1 stereo_image_proc" + (" (16 B points)" if points else "")
            cells = [case, label, f"{theirs['disparity_hz']:.1f}"]
            cells += [f"{points:.1f}" if points else "-", dropped, f"{theirs['disparity_lat_ms_median']:.1f}"]
            points_latency = theirs.get("points2_lat_ms_median")
            cells += [f"{points_latency:.1f}" if points_latency else "-", "1.00x (baseline)"]
            print(table_row((*cells, f"{theirs['node_cpu_pct']:.0f}%")))
            first = ""
        elif anchor_name:
            missing.append(anchor_name)
        for name, label in ours:
            print(table_row((first, label, *node_cells(run.rows[(name, "all")], theirs))))
            first = ""
    if missing:
        print(f"\nThe C++ chain gave no figures for: {', '.join(missing)} (run.sh failed; its log is on stderr).")
        return False
    return True


def node_cells(row: dict[str, Any], theirs: dict[str, Any] | None) -> tuple[str, ...]:
    d, p = row["disparity"], row["points2"]
    latency = f"{p['lat_median']:.1f} ({p['lat_p95']:.1f})" if p else "-"
    versus = "-"
    if theirs:
        versus = times(d["lat_median"] / theirs["disparity_lat_ms_median"])
        if p and theirs.get("points2_lat_ms_median"):
            versus += f" / {times(p['lat_median'] / theirs['points2_lat_ms_median'])}"
    dropped = f"{d['dropped']:.0f}" + (f" / {p['dropped']:.0f}" if p else "")
    cells = (f"{d['hz']:.1f}", f"{p['hz']:.1f}" if p else "-", dropped, f"{d['lat_median']:.1f}", latency, versus)
    return (*cells, f"{row['node_cpu_pct']:.0f}%")


def quality(work: Path, quick: bool) -> bool:
    """The node's rate with the census core against `default`, 128 disparities, VGA at 30 Hz."""
    rows = e2e_rows(work, quick, "--cases", *QUALITY_CASES, "--profiles", "all")
    if rows is None:
        return False
    print("stereo_node end to end, 640x480 at 30 Hz, 128 disparities (`bench/e2e_dds.py`):\n")
    print(table_header(("profile", "disparity Hz", "vs `default`", "node CPU")))
    base = rows[(QUALITY_CASES[0], "all")]["disparity"]["hz"]
    for case in QUALITY_CASES:
        row = rows[(case, "all")]
        hz = row["disparity"]["hz"]
        print(
            table_row((f"`{case.split('_')[0]}`", f"{hz:.1f}", times(ratio(hz, base)), f"{row['node_cpu_pct']:.0f}%"))
        )
    return True
