"""Does the confidence mean something? bad-2 among confident pixels against bad-2 over all estimates.

.venv/bin/python bench/confidence.py SCENE_DIR... [--profile quality] [--threshold 0.5] [--markdown]
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
from markdown_table import parse_bench_arguments


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+", type=Path)
    parser.add_argument("--profile", default="quality")
    parser.add_argument("--threshold", type=float, default=0.5)
    args = parse_bench_arguments(parser, "the README's sentence only (no table per scene)")
    if not args.markdown:
        print(f"{'scene':36s}{'bad2_est':>10s}{'confident':>11s}{'share':>8s}")
    overall, confident, shares = [], [], []
    for folder in args.scenes:
        scene = load_scene(folder)
        if scene.gt is None:
            continue
        params = make_params(args.profile, {"disparity_range": scene.disparity_range()})
        result = StereoPipeline(params).process(scene.left, scene.right, None, rectified=True, want_points=False)
        if result.confidence is None:
            parser.error(f"profile {args.profile} gives no confidence")
        sure = np.where(result.confidence >= args.threshold, result.disparity, np.nan)
        everything, kept = accuracy(result.disparity, scene.gt, scene.mask), accuracy(sure, scene.gt, scene.mask)
        share = kept.density / everything.density
        overall.append(everything.bad2_est)
        confident.append(kept.bad2_est)
        shares.append(share)
        if not args.markdown:
            print(f"{scene.name:36s}{everything.bad2_est:10.4f}{kept.bad2_est:11.4f}{share:8.2f}", flush=True)
    mean_all, mean_sure = float(np.mean(overall)), float(np.mean(confident))
    if not args.markdown:
        print(f"{'mean':36s}{mean_all:10.4f}{mean_sure:11.4f}{np.mean(shares):8.2f}")
    ratio = mean_sure / mean_all
    print(f"confidence >= {args.threshold}: bad-2 {mean_sure:.4f} = {ratio:.2f} x the overall {mean_all:.4f}")


if __name__ == "__main__":
    main()
