"""A bag with a colour camera beside the stereo pair, made from the bundled EuRoC bag: its right camera given
again as `rgb/image_raw` (raw and distorted, as a colour camera's driver publishes it) with a camera_info of
its own (cam1's intrinsics, R = I, P = [K | 0]), stamped a little after the stereo pair, as an unsynchronised
colour camera is. The pose that goes with it: cam1 in cam0 (from the bundled camchain)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from stereo_depth.bag.reader import read_messages
from stereo_depth.bag.types import rosbags_types
from stereo_depth.bag.writer import BagWriter
from stereo_depth.core.camera import CameraInfo
from stereo_depth.formats.kalibr import pose_of
from stereo_depth.messages import camera_info_to_msg, make_header

ROOT = Path(__file__).resolve().parents[1]
EUROC_BAG = ROOT / "bags" / "euroc_raw"
CAMCHAIN = ROOT / "test" / "data" / "euroc" / "camchain.yaml"
NS = "/stereo"
STEREO_TOPICS = tuple(f"{NS}/{side}/{kind}" for side in ("left", "right") for kind in ("image_raw", "camera_info"))
COLOUR_TOPICS = (f"{NS}/rgb/image_raw", f"{NS}/rgb/camera_info")
START_NS = 1_700_000_000_000_000_000
PERIOD_NS = 50_000_000  # 20 Hz, the EuRoC camera's rate
COLOUR_DELAY_NS = 3_000_000  # the colour camera exposes 3 ms after the stereo pair


def camchain() -> dict[str, Any]:
    document: dict[str, Any] = yaml.safe_load(CAMCHAIN.read_text())
    return document


def colour_info(frame_id: str = "rgb_optical") -> CameraInfo:
    """cam1 as a single camera: its raw intrinsics and distortion, R = I, P = [K | 0]."""
    cam1 = camchain()["cam1"]
    fu, fv, cu, cv = cam1["intrinsics"]
    k = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    d = [*cam1["distortion_coeffs"], 0.0]
    return CameraInfo.from_values(752, 480, k, d, np.eye(3), np.hstack([k, np.zeros((3, 1))]), "plumb_bob", frame_id)


def cam1_in_cam0() -> list[float]:
    """rgb_in_left for the colour camera that is cam1: the inverse of cam1's T_cn_cnm1."""
    return pose_of(np.linalg.inv(np.asarray(camchain()["cam1"]["T_cn_cnm1"]))).as_list()


def restamped(message: Any, stamp_ns: int, frame_id: str | None = None) -> Any:
    types = rosbags_types()
    header = make_header(types, stamp_ns, str(message.header.frame_id) if frame_id is None else frame_id)
    return dataclasses.replace(message, header=header)


def write_colour_bag(out: Path, frames: int = 20, *, colour: CameraInfo | None = None) -> dict[int, int]:
    """The bag; returns {stereo stamp: colour stamp}. The EuRoC frames repeat in order."""
    source = read_messages(EUROC_BAG, list(STEREO_TOPICS))
    types = rosbags_types()
    info = colour or colour_info()
    stamps = {}
    with BagWriter(out, compress=False) as writer:
        for index in range(frames):
            stamp = START_NS + index * PERIOD_NS
            for topic in STEREO_TOPICS:
                writer.write(topic, restamped(source[topic][index % len(source[topic])], stamp), stamp)
            colour_stamp = stamp + COLOUR_DELAY_NS
            image = restamped(source[f"{NS}/right/image_raw"][index % 6], colour_stamp, info.frame_id)
            writer.write(COLOUR_TOPICS[0], image, colour_stamp)
            writer.write(COLOUR_TOPICS[1], camera_info_to_msg(types, image.header, info), colour_stamp)
            stamps[stamp] = colour_stamp
    return stamps
