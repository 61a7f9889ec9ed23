"""A fleet run: plan every bag (skip the finished ones, cut long ones), run the tasks, join the shards.

Every output appears complete or not at all: a bag is written by BagWriter (temporary folder, one
rename), a sharded bag's parts live in a hidden folder beside it until they are merged, and on Ctrl-C
or any failure the hidden folders of unfinished bags are swept away.
"""

from __future__ import annotations

import dataclasses
import glob
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from stereo_depth.bag.process import ProcessOptions
from stereo_depth.core.params import StereoParams
from stereo_depth.errors import BagError, StereoDepthError
from stereo_depth.fleet.backends import Backend, InProcess, LocalPool, RayBackend
from stereo_depth.fleet.inputs import BagInput, plan_inputs
from stereo_depth.fleet.report import BagReport, ProgressLine, write_report
from stereo_depth.fleet.shards import check_borders, merge, windows
from stereo_depth.fleet.tasks import RECORD_KEY, Task, TaskResult, record


@dataclass(frozen=True)
class FleetSettings:
    jobs: int = field(default_factory=lambda: os.cpu_count() or 1)
    ray_address: str | None = None  # None: no Ray; "": a new local instance; "auto" / "ray://host:port": join
    shard_seconds: float | None = None
    report: Path | None = None


def backend_for(settings: FleetSettings, out_dir: Path) -> Backend:
    if settings.ray_address is not None:
        return RayBackend(settings.ray_address, out_dir)
    return InProcess() if settings.jobs == 1 else LocalPool(settings.jobs)


def recorded(output: Path) -> str | None:
    """What an existing output was made with (its metadata.yaml custom_data), if this tool made it."""
    try:
        metadata = yaml.safe_load((output / "metadata.yaml").read_text())
        return str(metadata["rosbag2_bagfile_information"]["custom_data"][RECORD_KEY])
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return None


@dataclass
class BagPlan:
    """One input's tasks and, while it runs, their results."""

    bag: BagInput
    report: BagReport
    tasks: list[Task] = field(default_factory=list)
    results: list[TaskResult] = field(default_factory=list)
    parts_dir: Path | None = None  # sharded: where the windows' bags wait to be merged

    @property
    def finished(self) -> bool:
        return len(self.results) == len(self.tasks)


class FleetRun:
    def __init__(self, out_dir: Path, params: StereoParams, options: ProcessOptions, settings: FleetSettings) -> None:
        self.out_dir = out_dir
        self.params = params
        self.options = dataclasses.replace(options, custom_data={RECORD_KEY: record(params, options)})
        self.settings = settings
        self.plans: dict[str, BagPlan] = {}

    def plan(self, inputs: list[Path]) -> None:
        for bag in plan_inputs(inputs, self.out_dir):
            plan = BagPlan(bag, BagReport(str(bag.source), str(bag.output)))
            self.plans[bag.name] = plan
            try:
                self._plan_bag(plan)
            except StereoDepthError as exc:
                self._fail(plan, str(exc))

    def _plan_bag(self, plan: BagPlan) -> None:
        output, made_with = plan.bag.output, self.options.custom_data[RECORD_KEY]
        if output.exists() and not self.options.overwrite:
            if recorded(output) == made_with:
                plan.report.status = "skipped"
                return
            msg = f"{output} exists, made with other parameters or by another tool; pass --overwrite to redo it"
            raise BagError(msg)
        spans = windows(plan.bag.source, self.settings.shard_seconds) if self.settings.shard_seconds else []
        if len(spans) <= 1:
            plan.tasks.append(Task(plan.bag.name, plan.bag.source, output, self.params, self.options))
            return
        plan.parts_dir = self.out_dir / f".{plan.bag.name}.shards"
        shutil.rmtree(plan.parts_dir, ignore_errors=True)
        plan.parts_dir.mkdir()
        part_options = dataclasses.replace(self.options, storage="mcap", compress=False, overwrite=False)
        plan.report.shards = len(spans)
        plan.tasks.extend(
            Task(plan.bag.name, plan.bag.source, plan.parts_dir / f"{k:05d}", self.params, part_options, k, span)
            for k, span in enumerate(spans)
        )

    def run(self) -> list[BagReport]:
        tasks = [task for plan in self.plans.values() for task in plan.tasks]
        progress = ProgressLine(len(self.plans))
        start = time.perf_counter()
        results = backend_for(self.settings, self.out_dir).run(tasks)
        try:
            progress.update(self.reports)
            for result in results:
                plan = self.plans[result.bag]
                plan.results.append(result)
                plan.report.frames_in += result.frames_in
                plan.report.frames_out += result.frames_out
                plan.report.seconds += result.seconds
                plan.report.threads = result.threads
                if plan.finished:
                    self._finish(plan)
                progress.update(self.reports)
        finally:
            results.close()  # on Ctrl-C or an error: cancels the tasks left and waits for running ones
            progress.close()
            for plan in self.plans.values():
                if plan.report.status == "cancelled":
                    self._sweep(plan)
            if self.settings.report is not None:
                write_report(self.settings.report, self.reports, time.perf_counter() - start)
        return self.reports

    @property
    def reports(self) -> list[BagReport]:
        return [plan.report for plan in self.plans.values()]

    def _finish(self, plan: BagPlan) -> None:
        errors = [r.error for r in sorted(plan.results, key=lambda r: r.shard) if r.error]
        try:
            if errors:
                raise BagError(errors[0])
            if plan.report.frames_out == 0:  # all windows of a sharded bag empty (process_bag refuses a whole one)
                msg = f"{plan.bag.source}: no frame was processed (no matched stereo set)"
                raise BagError(msg)
            if plan.parts_dir is not None:
                start = time.perf_counter()
                self._merge(plan)
                plan.report.seconds += time.perf_counter() - start
        except StereoDepthError as exc:
            self._fail(plan, str(exc))
            return
        finally:
            if plan.parts_dir is not None:
                shutil.rmtree(plan.parts_dir, ignore_errors=True)
        plan.report.status = "done"
        plan.report.frames_per_second = plan.report.frames_out / max(plan.report.seconds, 1e-9)

    def _merge(self, plan: BagPlan) -> None:
        parts = sorted(plan.results, key=lambda r: r.shard)
        check_borders(plan.bag.name, parts)
        merge(
            [task.output for task in sorted(plan.tasks, key=lambda t: t.shard)],
            plan.bag.output,
            storage=self.options.storage,
            compress=self.options.compress,
            overwrite=self.options.overwrite,
            custom_data=self.options.custom_data,
        )

    def _fail(self, plan: BagPlan, error: str) -> None:
        plan.report.status, plan.report.error = "failed", error
        self._sweep(plan)

    def _sweep(self, plan: BagPlan) -> None:
        """Hidden folders this bag's tasks left beside its output (killed workers cannot clean up)."""
        for leftover in self.out_dir.glob(f".{glob.escape(plan.bag.name)}.*"):
            shutil.rmtree(leftover, ignore_errors=True)


def process_many(
    inputs: list[Path], out_dir: Path, params: StereoParams, options: ProcessOptions, settings: FleetSettings
) -> list[BagReport]:
    """Process every bag under `inputs` into `out_dir/<bag name>`; one report per bag, failures included."""
    out_dir = out_dir.absolute()  # workers (Ray's especially) may run in another working directory
    out_dir.mkdir(parents=True, exist_ok=True)
    fleet = FleetRun(out_dir, params, options, settings)
    fleet.plan([path.absolute() for path in inputs])
    return fleet.run()
