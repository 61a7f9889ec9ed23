"""Which bags a fleet run processes, and where each one's output goes."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from stereo_depth.errors import BagError

BAG_MARKER = "metadata.yaml"  # a rosbag2 folder (MCAP or sqlite3)
ROS1_SUFFIX = ".bag"  # a ROS 1 bag: one file


@dataclass(frozen=True)
class BagInput:
    source: Path
    output: Path

    @property
    def name(self) -> str:
        return self.output.name


def is_bag(path: Path) -> bool:
    return (path.is_dir() and (path / BAG_MARKER).is_file()) or (path.is_file() and path.suffix == ROS1_SUFFIX)


def find_bags(path: Path) -> list[Path]:
    """`path` itself when it is a bag, else every bag below it (a bag's own folder is not searched)."""
    if is_bag(path):
        return [path]
    if not path.is_dir():
        msg = (
            f"{path} is neither a bag nor a folder; pass rosbag2 folders (with {BAG_MARKER}), "
            f"ROS 1 {ROS1_SUFFIX} files, or folders holding them"
        )
        raise BagError(msg)
    folders = sorted(p.parent for p in path.rglob(BAG_MARKER))
    files = sorted(p for p in path.rglob(f"*{ROS1_SUFFIX}") if p.is_file())
    return [bag for bag in sorted(folders + files) if not any(folder in bag.parents for folder in folders)]


def plan_inputs(paths: list[Path], out_dir: Path) -> list[BagInput]:
    """Every bag under `paths`, each into `out_dir/<bag folder name>`; names must not collide.
    Bags inside `out_dir` are outputs of an earlier run, not inputs."""
    bags = [bag for path in paths for bag in find_bags(path) if out_dir.resolve() not in bag.resolve().parents]
    if not bags:
        msg = f"no bag (a folder with {BAG_MARKER}) found in {', '.join(map(str, paths))}"
        raise BagError(msg)
    by_name: dict[str, Path] = {}
    for bag in bags:
        other = by_name.setdefault(output_name(bag), bag)
        if other != bag:
            msg = f"two inputs would both write {out_dir / output_name(bag)}: {other} and {bag}; rename one"
            raise BagError(msg)
    clash = next((bag for name, bag in by_name.items() if (out_dir / name).resolve() == bag.resolve()), None)
    if clash is not None:
        msg = f"--out-dir {out_dir} would overwrite the input {clash}; choose another folder"
        raise BagError(msg)
    return [BagInput(bag, out_dir / output_name(bag)) for bag in dict.fromkeys(bags)]


def output_name(bag: Path) -> str:
    """A rosbag2 keeps its folder name (`run.bag/` too); a ROS 1 file `run.bag` becomes the rosbag2 folder `run`."""
    return bag.stem if bag.is_file() else bag.name
