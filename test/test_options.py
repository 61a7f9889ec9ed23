"""One home for options: the command line is derived from the option tables (the documents: test_docs.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from stereo_depth.cli import build_parser, main
from stereo_depth.commands import process as process_command
from stereo_depth.core.matching import MATCHERS
from stereo_depth.core.params import MATCHER_NAMES

MIDDLEBURY_BAG = Path(__file__).resolve().parents[1] / "bags" / "middlebury"


def test_every_matcher_name_the_parameters_accept_has_a_core() -> None:
    assert sorted(MATCHERS) == sorted(MATCHER_NAMES)


def process_args(*extra: str) -> argparse.Namespace:
    return build_parser().parse_args(["process", str(MIDDLEBURY_BAG), "out", *extra])


def test_sync_flags_come_from_the_node_options_and_keep_their_old_spelling() -> None:
    _, settings = process_command.settings_from(
        process_args("--approximate-sync", "--approximate-sync-tolerance", "0.005")
    )
    assert settings.options.approximate_sync and settings.options.approximate_sync_tolerance_seconds == 0.005
    _, settings = process_command.settings_from(process_args("--queue-size", "7", "--no-approximate-sync"))
    assert settings.options.queue_size == 7 and not settings.options.approximate_sync


@pytest.mark.parametrize(
    ("in_file", "flags", "reason"),
    [
        ("queue_size: 7", ["--queue-size", "0"], "queue_size 0 is outside [1, 100]"),
        ("matching_threads: 9", [], "matching_threads 9 is outside [1, 4]"),
        ("input_reliability: sometimes", [], "input_reliability 'sometimes' is unknown"),
        ("queue_size: 7", ["--set", "depth_encoding=16UC2"], "depth_encoding '16UC2' is unknown"),
    ],
)
def test_process_refuses_options_out_of_range_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], in_file: str, flags: list[str], reason: str
) -> None:
    params = tmp_path / "params.yaml"
    params.write_text(f"/**:\n  ros__parameters:\n    {in_file}\n")
    out = tmp_path / "out"
    assert main(["process", str(MIDDLEBURY_BAG), str(out), "--params", str(params), *flags]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and reason in err
    assert not out.exists()


def test_process_reads_its_parameter_file_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    params = tmp_path / "params.yaml"
    params.write_text("/**:\n  ros__parameters:\n    disparity_range: 32\n    queue_size: 7\n    use_color: false\n")
    reads: list[Path] = []

    def counting(path: Path) -> dict[str, object]:
        reads.append(path)
        return read(path)

    read = process_command.read_params_file
    monkeypatch.setattr(process_command, "read_params_file", counting)
    _, settings = process_command.settings_from(process_args("--params", str(params)))
    assert reads == [params]
    assert settings.stereo is not None and settings.stereo.disparity_range == 32
    assert settings.options.queue_size == 7 and settings.output.use_color is False
