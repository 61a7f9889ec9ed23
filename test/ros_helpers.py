"""Node tests over real DDS: nodes in their own processes, a test node spinning in a thread.

Every wait has a generous deadline (waiting.py) and nothing asserts a duration.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ClassVar

import rclpy
from parent_death import die_with_parent
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
from waiting import TIMEOUT_S as TIMEOUT_S  # re-exported: the node tests import them from here
from waiting import wait_until as wait_until

from stereo_depth.messages import stamp_to_ns

STOP_TIMEOUT_S = 60.0  # a node's DDS teardown on a loaded 2-core machine can take seconds


class NodeProcess:
    """One node as its console script (`<venv>/bin/<module> --ros-args ...`, what `ros2 run` starts), or with
    `as_module` as `python -m stereo_depth.nodes.<module>`; output kept in a file. A failing test's report
    shows the output of those running during it (`started`, `stopped_at`; conftest.py)."""

    started: ClassVar[list[NodeProcess]] = []

    def __init__(
        self,
        module: str,
        namespace: str,
        env: dict[str, str],
        log_dir: Path,
        args: Iterable[str] = (),
        *,
        as_module: bool = False,
    ) -> None:
        self.name = module
        self.namespace = namespace
        self.log = log_dir / f"{namespace.strip('/').replace('/', '_')}_{module}.log"
        command = (
            [sys.executable, "-m", f"stereo_depth.nodes.{module}"]
            if as_module
            else [Path(sys.executable).with_name(module)]
        )
        parent = os.getpid()
        with self.log.open("wb") as out:
            self.process = subprocess.Popen(
                [*command, "--ros-args", "-r", f"__ns:={namespace}", *args],
                env=env,
                stdout=out,
                stderr=subprocess.STDOUT,
                preexec_fn=lambda: die_with_parent(parent),  # no node outlives a killed test run
            )
        self.stopped_at: float | None = None  # time.time() when stopped
        NodeProcess.started.append(self)

    @property
    def fqn(self) -> str:
        return f"{self.namespace.rstrip('/')}/{self.name}"

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def stop(self, sig: signal.Signals = signal.SIGINT) -> tuple[int, str]:
        """Send `sig`, wait for the exit; returns (exit code, everything it printed)."""
        self.stopped_at = self.stopped_at or time.time()
        if self.process.poll() is None:
            self.process.send_signal(sig)
            try:
                self.process.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.process.send_signal(signal.SIGUSR1)  # the node's stack dump (ros/signals.py): where it hangs
                time.sleep(1.0)
                self.process.kill()
                self.process.wait()
                note = f"[test: no exit {STOP_TIMEOUT_S:.0f} s after {sig.name}]"
                return self.process.returncode, f"{self.output()}\n{note}"
        return self.process.returncode, self.output()


class Collector:
    """Keeps every message of one topic; `wait_stamp` finds the one for a given input stamp."""

    def __init__(self, harness: RosHarness, msg_type: Any, topic: str) -> None:
        self.messages: list[Any] = []
        self._lock = threading.Lock()
        self.subscription = harness.node.create_subscription(msg_type, topic, self._store, reliable_qos(5))

    def _store(self, msg: Any) -> None:
        with self._lock:
            self.messages.append(msg)

    def stamps(self) -> list[int]:
        with self._lock:
            return [stamp_to_ns(m.header.stamp) for m in self.messages]

    def find(self, stamp_ns: int) -> Any:
        """The message received with this stamp, or None."""
        with self._lock:
            return next((m for m in self.messages if stamp_to_ns(m.header.stamp) == stamp_ns), None)

    def wait_stamp(self, stamp_ns: int, timeout: float = TIMEOUT_S) -> Any:
        return wait_until(lambda: self.find(stamp_ns), f"{self.subscription.topic_name} with stamp {stamp_ns}", timeout)

    def wait_any(self, timeout: float = TIMEOUT_S) -> Any:
        start = len(self.messages)
        return wait_until(lambda: self.messages[start:] and self.messages[-1], self.subscription.topic_name, timeout)


def reliable_qos(depth: int) -> QoSProfile:
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)


class RosHarness:
    """rclpy in the test process: one node, spun by a background thread."""

    def __init__(self) -> None:
        rclpy.init()
        self.node = rclpy.create_node("stereo_depth_test")
        self._executor = SingleThreadedExecutor()
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._executor.spin, daemon=True)
        self._thread.start()
        self._clients: dict[str, AsyncParameterClient] = {}

    def collector(self, msg_type: Any, topic: str) -> Collector:
        return Collector(self, msg_type, topic)

    def publisher(self, msg_type: Any, topic: str, reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE) -> Any:
        return self.node.create_publisher(msg_type, topic, QoSProfile(depth=5, reliability=reliability))

    @contextmanager
    def running(self, processes: Iterable[NodeProcess], timeout: float = TIMEOUT_S) -> Iterator[None]:
        """Module fixtures' shape: the nodes are up for the block, then stopped, each exiting cleanly. Nodes
        that did not all come up are stopped too: an orphan would answer a later run on this domain id."""
        processes = list(processes)
        try:
            self.wait_for_nodes(processes, timeout)
        except BaseException:
            stop_all(processes, expect_clean=False)
            raise
        try:
            yield
        finally:
            stop_all(processes)

    def wait_for_nodes(self, processes: Iterable[NodeProcess], timeout: float = TIMEOUT_S) -> None:
        for process in processes:
            wait_until(
                lambda p=process: (
                    (p.name, p.namespace) in self.node.get_node_names_and_namespaces() or p.process.poll() is not None
                ),
                f"node {process.fqn}",
                timeout,
            )
            assert process.process.poll() is None, f"{process.fqn} exited:\n{process.output()}"

    def set_parameters(self, node_fqn: str, **values: Any) -> list[Any]:
        """`ros2 param set`, one parameter per call as the CLI does; returns the SetParametersResults."""
        client = self._parameter_client(node_fqn)
        results = []
        for name, value in values.items():
            future = client.set_parameters([Parameter(name, value=value)])
            wait_until(future.done, f"set {name}")
            results.extend(future.result().results)
        return results

    def get_parameters(self, node_fqn: str, *names: str) -> dict[str, Any]:
        future = self._parameter_client(node_fqn).get_parameters(list(names))
        wait_until(future.done, "get parameters")
        values = future.result().values
        pairs = zip(names, values, strict=True)
        return {n: Parameter.from_parameter_msg(ParameterMsg(name=n, value=v)).value for n, v in pairs}

    def _parameter_client(self, node_fqn: str) -> AsyncParameterClient:
        if node_fqn not in self._clients:
            client = AsyncParameterClient(self.node, node_fqn)
            assert client.wait_for_services(timeout_sec=TIMEOUT_S), f"{node_fqn} offers no parameter services"
            self._clients[node_fqn] = client
        return self._clients[node_fqn]

    def close(self) -> None:
        self._executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()


def stop_all(
    processes: Iterable[NodeProcess], sig: signal.Signals = signal.SIGINT, *, expect_clean: bool = True
) -> dict[str, tuple[int, str]]:
    """Signal all first, then wait: the nodes shut down in parallel. With `expect_clean`, every node must
    have ended with exit code 0 and no traceback, whatever the test before did to it."""
    processes = list(processes)
    for process in processes:
        if process.process.poll() is None:
            process.process.send_signal(sig)
    results = {p.fqn: p.stop(sig) for p in processes}
    if expect_clean:
        for fqn, (code, output) in results.items():
            assert code == 0, f"{fqn}: exit code {code}\n{output}"
            assert "Traceback" not in output and "terminate called" not in output, f"{fqn}:\n{output}"
    return results
