"""Stereo frames out of a recording (ROS 1 bag, or rosbag2 MCAP / sqlite3), paired with the live node's
sync rules.

The stereo pair is found by the names cameras use in the wild: `left`/`right`, `cam0`/`cam1`,
`infra1`/`infra2` (RealSense IR), `zed_node/left|right`, with images named `image_raw`, `image_rect`,
`image_rect_color` and the like, as sensor_msgs/Image or image_transport's `/compressed`
sensor_msgs/CompressedImage, each with its `camera_info` beside it. So a bag recorded under any
namespace works without naming topics; `--left/--right` name them when the conventions do not fit, and
a calibration file replaces camera_info topics that are missing or wrong.
Messages go through `sync.Synchronizer` in the order they were recorded, as they would arrive live.

A colour camera beside the pair (registered depth) is read from `<ns>/rgb/` (image_raw, image_color,
image_rect_color or their /compressed, with camera_info beside it) or the topics `--rgb`/`--rgb-info`
name; its image and camera_info pair by stamp, and each pair waits in `colour_sets` for the caller.

The robot's odometry (the temporal filter's, `left_in_base` set) is read from `<ns>/odom` or the topic
`--odom` names: every message of it, in header stamp order (`odometry`).
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

from stereo_depth.bag.recording import open_reader
from stereo_depth.bag.types import deserialize, rosbags_types
from stereo_depth.core.camera import CameraInfo
from stereo_depth.core.odometry import OdometrySample
from stereo_depth.errors import BagError
from stereo_depth.frames import InputNames
from stereo_depth.messages import ODOMETRY_TYPE, camera_info_to_msg, odometry_from_msg, same_calibration, stamp_to_ns
from stereo_depth.options import NodeOptions
from stereo_depth.sync import STEREO_CALIBRATIONS, StereoSet, SyncCounters, Synchronizer

ROLES = ("left_image", "left_info", "right_image", "right_info")
IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE_TYPE, COMPRESSED_TYPE)
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
# (left, right) name pieces, in the order they are tried
SIDES = (("left", "right"), ("cam0", "cam1"), ("infra1", "infra2"))
RAW_IMAGES = ("image_raw", "image_color", "image_mono", "image_rect_raw", "image")
RECTIFIED_IMAGES = ("image_rect", "image_rect_color")
COMPRESSED = "/compressed"
# a shard reads the odometry recorded this much beyond what it reads of the images (header stamps and recording
# times differ)
ODOMETRY_MARGIN_NS = 10_000_000_000


@dataclass(frozen=True)
class StereoTopics:
    namespace: str  # "" or "/ns", without a trailing slash
    names: tuple[str, str | None, str, str | None]  # in ROLES order; no camera_info topics with a calibration file
    rectified: bool
    rgb: tuple[str, str | None] | None = None  # the colour image and its camera_info (None: a file's)
    odom: str | None = None  # the odometry (nav_msgs/Odometry), when read

    def output(self, name: str) -> str:
        """An output topic under the same namespace as the input (e.g. /stereo/disparity)."""
        return f"{self.namespace}/{name}"

    @property
    def images(self) -> tuple[str, str]:
        return self.names[0], self.names[2]

    @property
    def input_names(self) -> InputNames:
        """What errors call each of the four inputs: its topic, or the calibration file that replaces it."""
        left_image, left_info, right_image, right_info = self.names
        return InputNames(
            left_image, left_info or "left --camera-info", right_image, right_info or "right --camera-info"
        )

    def describe(self) -> str:
        return " + ".join(n for n in self.names if n is not None)


@dataclass(frozen=True)
class TopicChoice:
    """What the user chose: a namespace, explicit topics, a calibration that replaces camera_info."""

    namespace: str | None = None
    left: str | None = None
    right: str | None = None
    left_info: str | None = None
    right_info: str | None = None
    calibration: tuple[CameraInfo, CameraInfo] | None = None
    need_info: bool = True  # False: only the images are read (calibrate)
    with_rgb: bool = False  # read the colour camera too (registered outputs)
    rgb: str | None = None
    rgb_info: str | None = None
    rgb_calibration: CameraInfo | None = None  # replaces the colour camera_info topic (a camchain's cam2)
    with_odom: bool = False  # read the odometry too (left_in_base set)
    odom: str | None = None  # its topic (None: <namespace>/odom)

    @property
    def reads_info(self) -> bool:
        """Whether the bag's camera_info topics are read (not replaced by a file, and needed at all)."""
        return self.calibration is None and self.need_info


LEAD_IN_PERIOD_NS = 100_000_000  # a shard's lead-in frames are read back at 10 Hz: slower bags are refused


@dataclass(frozen=True)
class TimeWindow:
    """The sets one shard of a long bag owns: set stamps in [start_ns, stop_ns) (None: unbounded).

    Reading starts `lead_ns` of recording time before `start_ns` so the synchronizer holds what one
    pass over the whole bag would hold at the border, and goes on past `stop_ns` (at most `lead_ns`)
    until the first set of the next window is paired: its stamp (`ReadStats.handoff_ns`) must be the
    next shard's first (`ReadStats.first_ns`), which is how a border is checked to pair as one pass does.
    """

    start_ns: int | None = None
    stop_ns: int | None = None
    lead_ns: int = 2_000_000_000

    def owns(self, stamp_ns: int) -> bool:
        return (self.start_ns is None or stamp_ns >= self.start_ns) and (
            self.stop_ns is None or stamp_ns < self.stop_ns
        )


def _normalise(namespace: str) -> str:
    return "/" + namespace.strip("/") if namespace.strip("/") else ""


def _image_name(topic: str) -> str:
    """The image's own name: the last segment, before image_transport's /compressed."""
    return topic.removesuffix(COMPRESSED).rsplit("/", 1)[-1]


def info_topic(image_topic: str) -> str:
    """The camera_info beside an image topic, as image_transport pairs them."""
    return image_topic.removesuffix(COMPRESSED).rsplit("/", 1)[0] + "/camera_info"


def _partner(topic: str, left: str, right: str) -> tuple[str, str] | None:
    """(namespace, right topic) when `topic` names a left camera by `left`, else None."""
    segments = topic.split("/")
    for index in range(len(segments) - 2, 0, -1):  # the camera's folder, nearest the image first
        if left in segments[index]:
            namespace = "/".join(segments[:index])
            swapped = segments[index][::-1].replace(left[::-1], right[::-1], 1)[::-1]
            return namespace, "/".join([*segments[:index], swapped, *segments[index + 1 :]])
    return None


def _kind(topic: str) -> tuple[bool, bool]:
    """(rectified, compressed); preference: raw before rectified, Image before CompressedImage."""
    return _image_name(topic) in RECTIFIED_IMAGES, topic.endswith(COMPRESSED)


def stereo_sets(topics: dict[str, str], with_info: bool = True) -> list[StereoTopics]:
    """Every left/right image pair the conventions find, with camera_info beside each when `with_info`."""
    found = []
    for topic, msgtype in sorted(topics.items()):
        if msgtype not in IMAGE_TYPES or _image_name(topic) not in RAW_IMAGES + RECTIFIED_IMAGES:
            continue
        for left, right in SIDES:
            pair = _partner(topic, left, right)
            if pair is None or topics.get(pair[1]) not in IMAGE_TYPES:
                continue
            infos = (info_topic(topic), info_topic(pair[1]))
            if with_info and not all(topics.get(i) == INFO_TYPE for i in infos):
                continue
            names = (topic, infos[0] if with_info else None, pair[1], infos[1] if with_info else None)
            found.append(StereoTopics(_normalise(pair[0]), names, _kind(topic)[0]))
            break
    return found


def _wrong_types(topics: dict[str, str]) -> str:
    """'; but X is T, not Image' for image- or camera_info-named topics of another type."""
    wrong = [
        f"{name} is {kind}, not {' or '.join(IMAGE_TYPES)}"
        for name, kind in sorted(topics.items())
        if _image_name(name) in RAW_IMAGES + RECTIFIED_IMAGES and kind not in IMAGE_TYPES
    ]
    wrong += [
        f"{name} is {kind}, not {INFO_TYPE}"
        for name, kind in sorted(topics.items())
        if name.endswith("/camera_info") and kind != INFO_TYPE
    ]
    return f"; but {'; '.join(wrong)}" if wrong else ""


def find_stereo_topics(topics: dict[str, str], namespace: str | None = None, with_info: bool = True) -> StereoTopics:
    """The stereo set in a bag's {topic: msgtype}. In one namespace raw images win over rectified ones
    and Image over CompressedImage (lossless first); several namespaces need a choice."""
    candidates = stereo_sets(topics, with_info)
    if namespace is not None:
        candidates = [c for c in candidates if c.namespace == _normalise(namespace)]
    if not candidates and with_info and (images_only := find_images_without_info(topics, namespace)):
        msg = (
            f"the bag has the stereo images {images_only.describe()} but no camera_info beside them "
            f"({info_topic(images_only.names[0])}, {info_topic(images_only.names[2])}); pass the calibration with "
            "--camera-info FILE_OR_DIR (Kalibr camchain.yaml, left.yaml + right.yaml, or a EuRoC folder), or name "
            f"the camera_info topics with --left-info and --right-info{_wrong_types(topics)}"
        )
        raise BagError(msg)
    if not candidates:
        where = f" under namespace '{_normalise(namespace) or '/'}'" if namespace is not None else ""
        needs = "" if not with_info else " with camera_info beside each (or pass --camera-info FILE_OR_DIR)"
        msg = (
            f"the bag has no complete stereo topic set{where}: left and right images (left/right, cam0/cam1, "
            f"infra1/infra2; image_raw, image_rect, image_rect_color or their /compressed){needs}; "
            f"it has: {', '.join(sorted(topics)) or 'no topics'}{_wrong_types(topics)}; "
            "name them with --left and --right"
        )
        raise BagError(msg)
    namespaces = sorted({c.namespace for c in candidates})
    if len(namespaces) > 1:
        sets = "; ".join(
            f"{ns or '/'}: {min((c for c in candidates if c.namespace == ns), key=_rank).describe()}"
            for ns in namespaces
        )
        msg = (
            f"the bag holds stereo topics under several namespaces ({', '.join(ns or '/' for ns in namespaces)}); "
            f"choose one with --namespace, or name the images with --left and --right. Sets found: {sets}"
        )
        raise BagError(msg)
    return min(candidates, key=_rank)


def find_images_without_info(topics: dict[str, str], namespace: str | None) -> StereoTopics | None:
    """The image pair the bag would give if it had camera_info (for the error that asks for a file)."""
    try:
        return find_stereo_topics(topics, namespace, with_info=False)
    except BagError:
        return None


def _rank(candidate: StereoTopics) -> tuple[bool, bool]:
    return _kind(candidate.names[0])


def chosen_topics(topics: dict[str, str], choice: TopicChoice) -> StereoTopics:
    """The set the user named (--left/--right), else the one the conventions find; with its colour camera
    when `choice.with_rgb`, its odometry when `choice.with_odom`."""
    stereo = _stereo_topics(topics, choice)
    if choice.with_rgb:
        stereo = dataclasses.replace(stereo, rgb=colour_topics(topics, choice, stereo.namespace))
    if choice.with_odom:
        stereo = dataclasses.replace(stereo, odom=odometry_topic(topics, choice, stereo.namespace))
    return stereo


def odometry_topic(topics: dict[str, str], choice: TopicChoice, namespace: str) -> str:
    """The odometry topic: the one named (--odom), else `<namespace>/odom`."""
    name = choice.odom or f"{namespace}/odom"
    if topics.get(name) != ODOMETRY_TYPE:
        found_as = f"is {topics[name]}" if name in topics else "is not in the bag"
        odometry = sorted(topic for topic, kind in topics.items() if kind == ODOMETRY_TYPE)
        have = f"; its {ODOMETRY_TYPE} topics: {', '.join(odometry)}" if odometry else f"; it has no {ODOMETRY_TYPE}"
        msg = (
            f"left_in_base is set, so the temporal filter needs the odometry, but {name} {found_as}{have}; "
            "name the topic with --odom TOPIC, or unset left_in_base"
        )
        raise BagError(msg)
    return name


def colour_topics(topics: dict[str, str], choice: TopicChoice, namespace: str) -> tuple[str, str | None]:
    """(image, camera_info) of the colour camera: the ones named, else `<namespace>/rgb/...` (raw before
    rectified, Image before CompressedImage); camera_info None when a calibration file replaces it."""
    image = choice.rgb
    if image is None:
        names = [
            f"{namespace}/rgb/{name}{kind}" for kind in ("", COMPRESSED) for name in (*RAW_IMAGES, *RECTIFIED_IMAGES)
        ]
        found = sorted((n for n in names if topics.get(n) in IMAGE_TYPES), key=_kind)
        if not found:
            msg = (
                f"the registered outputs need a colour camera, but the bag has no image under {namespace}/rgb/ "
                f"(image_raw, image_color, image_rect_color or their /compressed); name it with --rgb TOPIC and "
                f"--rgb-info TOPIC; the bag has: {', '.join(sorted(topics))}"
            )
            raise BagError(msg)
        image = found[0]
    info = None if choice.rgb_calibration is not None else (choice.rgb_info or info_topic(image))
    for name, types in ((image, IMAGE_TYPES), (info, (INFO_TYPE,))):
        if name is not None and topics.get(name) not in types:
            found_as = f"is {topics[name]}" if name in topics else "is not in the bag"
            msg = f"colour camera: {name} {found_as}; expected {' or '.join(types)}; name it with --rgb / --rgb-info"
            raise BagError(msg)
    return image, info


def _stereo_topics(topics: dict[str, str], choice: TopicChoice) -> StereoTopics:
    with_info = choice.reads_info
    if choice.left is None and choice.right is None:
        return find_stereo_topics(topics, choice.namespace, with_info)
    if choice.left is None or choice.right is None:
        msg = "--left and --right go together: name both image topics"
        raise BagError(msg)
    left_info = (choice.left_info or info_topic(choice.left)) if with_info else None
    right_info = (choice.right_info or info_topic(choice.right)) if with_info else None
    wanted: dict[str, tuple[str, ...]] = {choice.left: IMAGE_TYPES, choice.right: IMAGE_TYPES}
    for info in (left_info, right_info):
        if info is not None:
            wanted[info] = (INFO_TYPE,)
    for name, types in wanted.items():
        if topics.get(name) not in types:
            found = f"is {topics[name]}" if name in topics else "is not in the bag"
            hint = " (or pass --camera-info FILE_OR_DIR)" if types == (INFO_TYPE,) else ""
            msg = f"{name} {found}; expected {' or '.join(types)}{hint}; the bag has: {', '.join(sorted(topics))}"
            raise BagError(msg)
    common = []
    for a, b in zip(choice.left.split("/")[:-1], choice.right.split("/")[:-1], strict=False):
        if a != b:
            break
        common.append(a)
    return StereoTopics(
        _normalise("/".join(common)),
        (choice.left, left_info, choice.right, right_info),
        _kind(choice.left)[0],
    )


@dataclass
class ReadStats:
    """What happened to the input: enough to tell a user why frames are missing."""

    left_images: int = 0
    right_images: int = 0
    matched: int = 0
    sync: SyncCounters | None = None
    unmatched_at_end: int = 0
    first_ns: int | None = None  # stamp of the first set yielded (a window's first)
    handoff_ns: int | None = None  # with a window: stamp of the first set after it (None: the bag ended)


class StereoBagReader:
    """Open a bag, find its stereo topics and yield matched sets; use as a context manager."""

    def __init__(
        self,
        path: Path | str,
        *,
        namespace: str | None = None,
        sync: NodeOptions | None = None,
        choice: TopicChoice | None = None,
        window: TimeWindow | None = None,
        lead_in_frames: int = 0,
    ) -> None:
        """`lead_in_frames`: with a window, yield (as `lead_in`) up to this many sets paired before its
        start, just before its first own set; the window's lead-in time grows to hold them at 10 Hz."""
        self.path = Path(path)
        self.lead_in_frames = lead_in_frames
        self.policy = sync or NodeOptions()  # the live node's sync options and defaults
        self.choice = choice or TopicChoice(namespace=namespace)
        self.window = window or TimeWindow()
        if lead_in_frames:
            lead_ns = max(self.window.lead_ns, lead_in_frames * LEAD_IN_PERIOD_NS)
            self.window = dataclasses.replace(self.window, lead_ns=lead_ns)
        self._reader = open_reader(self.path)
        try:
            self.topics = chosen_topics(self.topic_types(), self.choice)
        except BagError:
            self._reader.close()
            raise
        self.stats = ReadStats()
        self.colour_sets: deque[tuple[Any, Any]] = deque()  # (image, camera_info) paired, for the caller to take

    def topic_types(self) -> dict[str, str]:
        return {c.topic: c.msgtype for c in self._reader.connections}

    def count(self, topic: str) -> int:
        return sum(c.msgcount for c in self._reader.connections if c.topic == topic)

    def __enter__(self) -> StereoBagReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> Literal[False]:
        self._reader.close()
        return False

    def frames(self) -> Iterator[StereoSet]:
        """Matched sets in recording order; counts in `stats` what could not be paired. With a
        calibration file only the two images are paired, and each gets that calibration as its
        camera_info (stamped like the image), so what follows cannot tell the two apart; without
        camera_info at all (need_info False) the infos are None."""
        inputs = [name for name in self.topics.names if name is not None]
        colour = [name for name in self.topics.rgb or () if name is not None]
        colour_sync = Synchronizer(2, self.policy.queue_size, calibrations={1: 0}, same_calibration=same_calibration)
        sync = Synchronizer(
            len(inputs),
            self.policy.queue_size,
            self.policy.approximate_sync,
            self.policy.tolerance_ns,
            calibrations=STEREO_CALIBRATIONS if self.choice.reads_info else None,
            same_calibration=same_calibration,
        )
        self.stats.sync = sync.counters
        role_of = {name: i for i, name in enumerate(inputs)}
        window = self.window
        lead_in: deque[StereoSet] = deque(maxlen=self.lead_in_frames or 1)
        for topic, message in self._messages([*inputs, *colour]):
            stamp_ns = stamp_to_ns(message.header.stamp)
            if topic in colour:
                self._add_colour(colour_sync, colour.index(topic), stamp_ns, message)
                continue
            role = role_of[topic]
            if window.owns(stamp_ns):
                self._count_input(topic)
            yield from self._owned(sync.add(role, stamp_ns, message), lead_in)
            if self.stats.handoff_ns is not None:
                break
        else:  # the end of what this window reads: sets that wait only for a camera_info go out
            self.colour_sets.extend((image, info) for _, (image, info) in colour_sync.flush())
            yield from self._owned(sync.flush(), lead_in)
        self.stats.unmatched_at_end = sync.pending()

    def _add_colour(self, sync: Synchronizer, role: int, stamp_ns: int, message: Any) -> None:
        """A colour image or camera_info; a calibration file's camera_info stands in for the topic."""
        calibration = self.choice.rgb_calibration
        if calibration is not None:
            info = camera_info_to_msg(rosbags_types(), message.header, calibration)
            self.colour_sets.append((message, info))
            return
        self.colour_sets.extend((image, info) for _, (image, info) in sync.add(role, stamp_ns, message))

    def _owned(self, sets: list[tuple[int, tuple[Any, ...]]], lead_in: deque[StereoSet]) -> Iterator[StereoSet]:
        """The sets the window owns. The first set past its end is the hand-off (set stamps only grow: the
        window is complete); sets before its start were paired only to reach one pass's state there, and
        the last `lead_in_frames` of them go out (as `lead_in`) just before the window's first set."""
        for stamp, msgs in sets:
            if self.window.stop_ns is not None and stamp >= self.window.stop_ns:
                self.stats.handoff_ns = stamp
                return
            if not self.window.owns(stamp):
                if self.lead_in_frames:
                    lead_in.append(dataclasses.replace(self._stereo_set(stamp, msgs), lead_in=True))
                continue
            self.stats.matched += 1
            if self.stats.first_ns is None:
                self.stats.first_ns = stamp
                self._check_lead_in(len(lead_in))
                yield from lead_in
            yield self._stereo_set(stamp, msgs)

    def _check_lead_in(self, found: int) -> None:
        """A window that needs lead-in frames and finds fewer in its lead-in time, with more of the bag
        before it, would start from another state than one pass: refused, not silently different."""
        start = self.window.start_ns
        if found >= self.lead_in_frames or start is None:
            return
        if start - self.window.lead_ns > self._reader.time_span[0]:
            msg = (
                f"{self.path}: the window from stamp {start} needs {self.lead_in_frames} frames before it "
                f"(temporal_filter) but its {self.window.lead_ns / 1e9:g} s lead-in holds {found}; process this "
                "bag without --shard-seconds"
            )
            raise BagError(msg)

    def _stereo_set(self, stamp_ns: int, messages: tuple[Any, ...]) -> StereoSet:
        calibration = self.choice.calibration
        if self.choice.reads_info:
            return StereoSet.paired(stamp_ns, messages)
        left_image, right_image = messages
        if calibration is None:
            return StereoSet(stamp_ns, left_image, None, right_image, None)
        types = rosbags_types()
        left_info = camera_info_to_msg(types, left_image.header, calibration[0])
        right_info = camera_info_to_msg(types, right_image.header, calibration[1])
        return StereoSet(stamp_ns, left_image, left_info, right_image, right_info)

    def _messages(self, topics: list[str], window: TimeWindow | None = None) -> Iterator[tuple[str, Any]]:
        """(topic, message) in recording order, of what `window` (the reader's own unless given) reads.
        Damage found while reading (a cut-off file, a corrupt compressed chunk or database page,
        undecodable CDR) becomes one BagError naming the file, whichever library noticed it: rosbags,
        zstd, apsw and the CDR decoder each raise their own."""
        connections = [c for c in self._reader.connections if c.topic in topics]
        window = window or self.window
        start, stop = window.start_ns, window.stop_ns
        messages = self._reader.messages(
            connections,
            start=None if start is None else start - window.lead_ns,
            stop=None if stop is None else stop + window.lead_ns,
        )
        while True:
            try:
                item = next(messages, None)
                if item is None:
                    return
                connection, _, raw = item
                message = deserialize(raw, connection.msgtype)
            except Exception as exc:
                msg = (
                    f"{self.path}: cannot read messages ({type(exc).__name__}: {exc}); the bag is truncated or "
                    "damaged: record it again, or repair a copy (mcap recover, ros2 bag reindex, rosbag reindex)"
                )
                raise BagError(msg) from exc
            yield connection.topic, message

    def odometry(self) -> list[OdometrySample]:
        """Every message of the odometry topic (none unless chosen), in header stamp order; with a window,
        those recorded within ODOMETRY_MARGIN_NS of what the window reads."""
        if self.topics.odom is None:
            return []
        start, stop = self.window.start_ns, self.window.stop_ns
        window = TimeWindow(
            None if start is None else start - ODOMETRY_MARGIN_NS,
            None if stop is None else stop + ODOMETRY_MARGIN_NS,
            self.window.lead_ns,
        )
        samples = [odometry_from_msg(message) for _, message in self._messages([self.topics.odom], window)]
        return sorted(samples, key=lambda sample: sample.stamp_ns)

    def _count_input(self, topic: str) -> None:
        if topic == self.topics.names[0]:
            self.stats.left_images += 1
        elif topic == self.topics.names[2]:
            self.stats.right_images += 1


def read_messages(path: Path | str, topics: list[str]) -> dict[str, list[Any]]:
    """Every message on `topics`, deserialized, in recording order (for checks and small bags)."""
    reader = open_reader(Path(path))
    try:
        missing = sorted(set(topics) - {c.topic for c in reader.connections})
        if missing:
            have = ", ".join(sorted({c.topic for c in reader.connections}))
            msg = f"{path} has no topic {', '.join(missing)}; it has: {have}"
            raise BagError(msg)
        out: dict[str, list[Any]] = {t: [] for t in topics}
        connections = [c for c in reader.connections if c.topic in out]
        for connection, _, raw in reader.messages(connections):
            out[connection.topic].append(deserialize(raw, connection.msgtype))
        return out
    finally:
        reader.close()
