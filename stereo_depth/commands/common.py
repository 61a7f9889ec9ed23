"""Options every processing command shares: --profile, --set name=value, --params FILE."""

from __future__ import annotations

import argparse
from collections.abc import Mapping

from stereo_depth.core.params import PROFILES, StereoParams, make_params, parse_assignments


def add_param_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", default="default", choices=sorted(PROFILES), help="named parameter set")
    parser.add_argument(
        "--set",
        dest="assignments",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override one parameter (repeatable), e.g. --set disparity_range=128",
    )


def params_from_args(args: argparse.Namespace, extra: Mapping[str, object] | None = None) -> StereoParams:
    overrides: dict[str, object] = dict(extra or {})
    overrides.update(parse_assignments(args.assignments))
    return make_params(args.profile, overrides)
