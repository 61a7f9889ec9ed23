"""`stereo-depth eval` as a user runs it: table, JSON, pictures, and one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from conftest import SCENES, read_image

CLI = [sys.executable, "-m", "stereo_depth.cli"]


def test_eval_prints_table_writes_json_and_pictures(tmp_path: Path) -> None:
    out = subprocess.run(
        [
            *CLI,
            "eval",
            str(SCENES / "tsukuba"),
            str(SCENES / "artl"),
            "--json",
            str(tmp_path / "r.json"),
            "--save",
            str(tmp_path / "pics"),
        ],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    assert "mean (2 scenes, default)" in out.stdout
    report = json.loads((tmp_path / "r.json").read_text())
    assert [s["scene"] for s in report["scenes"]] == ["scenes/tsukuba", "scenes/artl"]
    assert set(report["mean"]) == {"bad1", "bad2", "bad4", "bad2_est", "density", "epe", "ms"}
    assert 0.0 < report["mean"]["bad2"] < 0.25
    picture = read_image(tmp_path / "pics" / "scenes_artl.png")
    assert picture.shape == (277, 4 * 347, 3)  # left | ground truth | ours | error map


def test_eval_disparity_range_follows_calib_and_can_be_overridden(tmp_path: Path) -> None:
    runs = {}
    for extra in ([], ["--set", "disparity_range=16"]):
        path = tmp_path / f"{len(extra)}.json"
        subprocess.run(
            [*CLI, "eval", str(SCENES / "artl"), "--json", str(path), *extra],
            check=True,
            capture_output=True,
            timeout=300,
        )
        runs[len(extra)] = json.loads(path.read_text())["mean"]
    # ArtL's disparities reach 55 px: a 16 px search finds almost none of them
    assert runs[2]["bad2"] > runs[0]["bad2"] + 0.5


def test_eval_refuses_bad_input_with_one_line(tmp_path: Path) -> None:
    for args in (["eval", str(tmp_path / "missing")], ["eval", str(SCENES / "artl"), "--set", "P2=1"]):
        out = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=120)
        assert out.returncode == 1
        assert out.stderr.startswith("ERROR: ") and out.stderr.count("\n") == 1, out.stderr
