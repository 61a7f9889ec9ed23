"""What disp12_max_diff does per matcher: the share of valid pixels and bad-2 of the estimates at
-1 (check off), 0 (stereo_image_proc's value), 1 and 3 px.

.venv/bin/python bench/left_right_check.py SCENE_DIR... [--markdown]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from stereo_depth.core.metrics import accuracy
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.scenes import load_scene

sys.path.insert(0, str(Path(__file__).parent))
from markdown_table import parse_bench_arguments, table_header, table_row

SETTINGS = (-1, 0, 1, 3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+", type=Path)
    args = parse_bench_arguments(parser, "(always a markdown table)")
    print("valid pixels / bad-2 of the estimates, profile default, by disp12_max_diff:")
    print(table_header(("scene", "matcher", *(f"{d}: valid / bad-2" for d in SETTINGS))))
    for folder in args.scenes:
        scene = load_scene(folder)
        for matcher in ("bm", "sgbm", "census_sgm"):
            cells = []
            for disp12 in SETTINGS:
                params = make_params("default", {"matcher": matcher, "disp12_max_diff": disp12})
                disparity = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True).disparity
                valid = float(np.isfinite(disparity).mean()) * 100
                bad2 = accuracy(disparity, scene.gt, scene.mask).bad2_est * 100 if scene.gt is not None else np.nan
                cells.append(f"{valid:.1f} % / {bad2:.1f} %")
            print(table_row((folder.name, matcher, *cells)))


if __name__ == "__main__":
    main()
