"""One scene, every profile: a picture (left | ground truth | each profile) and a table of bad-2 and time.

.venv/bin/python bench/compare_profiles.py test/data/scenes/cones --out docs/images/profiles_cones.png [--markdown]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.metrics import accuracy, colorize_disparity, label
from stereo_depth.core.params import PROFILES, make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.scenes import load_scene

sys.path.insert(0, str(Path(__file__).parent))
from markdown_table import parse_bench_arguments, table_header, table_row, times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--profiles", nargs="+", default=["stereo_image_proc", "fast", "default", "quality"])
    parser.add_argument("--repeat", type=int, default=5)
    args = parse_bench_arguments(parser, "the README's table (ms against the first profile)")
    scene = load_scene(args.scene)
    assert scene.gt is not None, "the scene needs ground truth"
    top = float(np.nanmax(scene.gt))
    panels = [label(scene.left, scene.name), label(colorize_disparity(scene.gt, top), "ground truth")]
    if args.markdown:
        print(table_header(("profile", "bad-2", "bad-2 of estimated", "density", "ms", f"vs {args.profiles[0]}")))
    else:
        print(f"{'profile':20s}{'bad2':>8s}{'bad2_est':>10s}{'density':>9s}{'ms':>8s}")
    first_ms = 0.0
    for profile in args.profiles:
        if profile not in PROFILES:
            parser.error(f"unknown profile {profile}")
        pipeline = StereoPipeline(make_params(profile, {"disparity_range": scene.disparity_range()}))
        pipeline.process(scene.left, scene.right, None, rectified=True, want_points=False)  # warm-up
        runs = []
        for _ in range(args.repeat):
            start = time.perf_counter()
            result = pipeline.process(scene.left, scene.right, None, rectified=True, want_points=False)
            runs.append((time.perf_counter() - start) * 1000.0)
        acc = accuracy(result.disparity, scene.gt, scene.mask)
        ms = float(np.median(runs))
        first_ms = first_ms or ms
        if args.markdown:
            cells = (f"`{profile}`", f"{acc.bad2:.3f}", f"{acc.bad2_est:.3f}", f"{acc.density:.3f}", f"{ms:.1f}")
            print(table_row((*cells, times(ms / first_ms))))
        else:
            print(f"{profile:20s}{acc.bad2:8.3f}{acc.bad2_est:10.3f}{acc.density:9.3f}{ms:8.1f}")
        text = f"{profile}: bad-2 {acc.bad2:.3f}, {ms:.0f} ms"
        panels.append(label(colorize_disparity(result.disparity, top), text))
    half = (len(panels) + 1) // 2  # two rows, padded with black
    panels += [np.zeros_like(panels[0])] * (2 * half - len(panels))
    picture = np.vstack([np.hstack(panels[:half]), np.hstack(panels[half:])])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), picture)
    print(f"\npicture: {args.out}")


if __name__ == "__main__":
    main()
