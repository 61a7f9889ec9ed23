"""sensor_msgs/PointCloud2 of a depth image, and back to arrays: the point-cloud layouts."""

from __future__ import annotations

import sys
from typing import Any

import cv2
import numpy as np

from stereo_depth.core.geometry import Rays, point_planes, voxel_thinned
from stereo_depth.errors import ImageError
from stereo_depth.messages.common import MessageBuffer, MessageTypes, _bytes, _with_data, in_serialized_bytes

FLOAT32 = 7  # sensor_msgs/PointField FLOAT32


def cloud_layout(with_color: bool, avoid_padding: bool) -> tuple[list[tuple[str, int]], int]:
    """Field offsets and point_step as stereo_image_proc lays them out (PCL-style rgb)."""
    if with_color:
        return ([("x", 0), ("y", 4), ("z", 8), ("rgb", 12 if avoid_padding else 16)], 16 if avoid_padding else 32)
    return ([("x", 0), ("y", 4), ("z", 8)], 12 if avoid_padding else 16)


def pack_rgb(bgr: np.ndarray) -> np.ndarray:
    """PCL's rgb: 0x00RRGGBB as uint32, read as float32 by consumers."""
    b, g, r = (bgr[:, :, i].astype(np.uint32) for i in range(3))
    return (r << 16) | (g << 8) | b


def depth_to_cloud(
    types: MessageTypes,
    header: Any,
    depth: np.ndarray,
    rays: Rays,
    color: np.ndarray | None = None,
    avoid_padding: bool = False,
    buffer: MessageBuffer | None = None,
    *,
    organized: bool = True,
    voxel_size: float = 0.0,
) -> Any:
    """PointCloud2 of a depth image: the one cloud builder.

    `organized`: height x width points, NaN for invalid ones, is_dense false (stereo_image_proc's
    layout), x, y, z computed straight into the message's buffer. Otherwise the valid points only
    (REP 117's dense cloud: height 1, is_dense true), thinned to one point per `voxel_size` voxel when
    that is > 0 (the members' centroid, the colour of one of them).
    `color` is BGR or grey (uint8); `buffer` lends the bytes of the previous organized cloud (see
    MessageBuffer).
    """
    fields, point_step = cloud_layout(color is not None, avoid_padding)
    height, width = depth.shape
    buffer = buffer or MessageBuffer()

    def cloud(data: Any, height: int, width: int) -> Any:
        return _with_data(
            types,
            types.PointCloud2,
            data,
            header=header,
            height=height,
            width=width,
            fields=[types.PointField(name=n, offset=o, datatype=FLOAT32, count=1) for n, o in fields],
            is_bigendian=sys.byteorder == "big",
            point_step=point_step,
            row_step=point_step * width,
            is_dense=not organized,
        )

    size = height * width * point_step
    serialized = (
        in_serialized_bytes(types, lambda data: cloud(data, height, width), size, buffer) if organized else None
    )
    if serialized is not None:  # the points written into the serialized message (rclpy)
        _fill_records(serialized[1].reshape(height, width, point_step), fields, depth, rays, color)
        return serialized[0]
    data = buffer.get(types, (height, width, tuple(fields), point_step), size)
    records = np.frombuffer(data, dtype=np.uint8).reshape(height, width, point_step)
    _fill_records(records, fields, depth, rays, color)
    if not organized:  # the valid points, copied out of the organized records (faster than gathering)
        kept = np.compress(np.isfinite(depth).ravel(), records.reshape(-1, point_step), axis=0)
        if voxel_size > 0:
            kept = _voxel_records(kept, fields, voxel_size)
        height, width = 1, len(kept)
        data = _bytes(types, kept)
    return cloud(data, height, width)


def _fill_records(
    records: np.ndarray, fields: list[tuple[str, int]], depth: np.ndarray, rays: Rays, color: np.ndarray | None
) -> None:
    """Every point's x, y, z and rgb, padding zero, written into the (H, W, point_step) records in one
    pass over them (cv2.merge): 1.5x sooner than a strided write per field."""
    height, width, point_step = records.shape
    words = dict(enumerate(point_planes(depth, rays)))  # float32 word of a record -> its plane
    if color is not None:
        words[fields[3][1] // 4] = _packed(color).view(np.float32)
    count = point_step // 4
    if len(words) < count:  # padding words: zero
        zero = np.zeros((height, width), np.float32)
        words.update((i, zero) for i in range(count) if i not in words)
    cv2.merge([words[i] for i in range(count)], dst=records.view(np.float32).reshape(height, width, count))


def _packed(color: np.ndarray) -> np.ndarray:
    """(H, W) PCL rgb of a BGR or grey (r = g = b) image."""
    if color.ndim == 2:
        grey: np.ndarray = np.multiply(color, np.uint32(0x010101), dtype=np.uint32)
        return grey
    return pack_rgb(color)


def _rgb_view(records: np.ndarray, fields: list[tuple[str, int]]) -> np.ndarray:
    """The rgb field of (..., point_step) uint8 records as uint32, (...)."""
    offset = fields[3][1]
    view: np.ndarray = records[..., offset : offset + 4].view(np.uint32)[..., 0]
    return view


def _voxel_records(records: np.ndarray, fields: list[tuple[str, int]], size: float) -> np.ndarray:
    """(N, point_step) records thinned to one per voxel (`voxel_thinned`), padding zero."""
    rgb = _rgb_view(records, fields) if len(fields) > 3 else None
    xyz, rgb = voxel_thinned(records.view(np.float32)[:, 0:3], rgb, size)
    out = np.zeros((len(xyz), records.shape[1]), np.uint8)
    out.view(np.float32)[:, 0:3] = xyz
    if rgb is not None:
        _rgb_view(out, fields)[...] = rgb
    return out


def cloud_to_arrays(msg: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W, 3) xyz float32 and (H, W) uint32 rgb (or None), read by field name from any layout."""
    offsets = {f.name: int(f.offset) for f in msg.fields}
    for name in ("x", "y", "z"):
        if name not in offsets:
            msg_text = f"point cloud has no '{name}' field (fields: {sorted(offsets)})"
            raise ImageError(msg_text)
    endian = ">" if msg.is_bigendian else "<"
    names = ["x", "y", "z"] + (["rgb"] if "rgb" in offsets else [])
    dtype = np.dtype(
        {
            "names": names,
            "formats": [endian + ("u4" if n == "rgb" else "f4") for n in names],
            "offsets": [offsets[n] for n in names],
            "itemsize": int(msg.point_step),
        }
    )
    records = np.frombuffer(msg.data, dtype=dtype).reshape(int(msg.height), int(msg.width))
    xyz = np.stack([records["x"], records["y"], records["z"]], axis=-1).astype(np.float32)
    rgb = records["rgb"].astype(np.uint32) if "rgb" in offsets else None
    return xyz, rgb
