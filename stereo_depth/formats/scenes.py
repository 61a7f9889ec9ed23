"""Scene folders in the layout of shared/data (Middlebury / KITTI style), read without ROS.

A scene is a rectified pair, optional ground-truth disparity (PNG with a scale or PFM), an optional
non-occlusion mask and a Middlebury `calib.txt` of `key=value` lines.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.camera import CameraInfo
from stereo_depth.errors import StereoDepthError


class SceneError(StereoDepthError):
    """A scene folder is missing a file or has an unreadable one."""


@dataclass
class Scene:
    name: str
    left: np.ndarray
    right: np.ndarray
    calib: dict[str, str]
    gt: np.ndarray | None  # float32 disparity in pixels, NaN = unknown
    mask: np.ndarray | None  # bool, True where the evaluation counts (non-occluded)

    def disparity_range(self) -> int:
        """`ndisp` from calib.txt, else the GT maximum plus 15 %, rounded up to a multiple of 16."""
        if "ndisp" in self.calib:
            wanted = calib_number(self.calib, "ndisp", self.name)
        elif "gt_max" in self.calib:
            wanted = calib_number(self.calib, "gt_max", self.name) * 1.15
        elif self.gt is not None and np.isfinite(self.gt).any():
            wanted = float(np.nanmax(self.gt)) * 1.15
        else:
            wanted = 64
        return max(16, int(np.ceil(wanted / 16.0)) * 16)

    def camera_infos(self, frame_id: str = "camera_left_optical_frame") -> tuple[CameraInfo, CameraInfo]:
        """Rectified-stream CameraInfos from cam0/cam1 and baseline (mm): identity R, zero D."""
        try:
            k0, k1 = parse_matrix(self.calib["cam0"]), parse_matrix(self.calib["cam1"])
            baseline_m = float(self.calib["baseline"]) / 1000.0
        except KeyError as exc:
            msg = f"{self.name}: calib.txt has no {exc.args[0]}; the scene has no calibration"
            raise SceneError(msg) from exc
        except ValueError as exc:
            msg = (
                f"{self.name}: calib.txt has a malformed cam0, cam1 or baseline ({exc}); expected e.g. "
                "cam0=[1038.0 0 322.0; 0 1038.0 243.5; 0 0 1] and baseline=176.252 (mm)"
            )
            raise SceneError(msg) from exc
        h, w = self.left.shape[:2]
        p0 = np.hstack([k0, np.zeros((3, 1))])
        p1 = np.hstack([k1, np.array([[-k1[0, 0] * baseline_m], [0.0], [0.0]])])
        eye = np.eye(3)
        left = CameraInfo.from_values(w, h, k0, np.zeros(5), eye, p0, "plumb_bob", frame_id)
        right = CameraInfo.from_values(w, h, k1, np.zeros(5), eye, p1, "plumb_bob", frame_id)
        return left, right


def calib_number(calib: dict[str, str], key: str, source: str) -> float:
    """calib.txt's `key` as a number; a SceneError naming the scene when it is not one."""
    try:
        return float(calib[key])
    except ValueError as exc:
        msg = f"{source}: calib.txt has {key}={calib[key]!r}, not a number"
        raise SceneError(msg) from exc


def parse_matrix(text: str) -> np.ndarray:
    """A 3x3 matrix written as Middlebury does: `[fx 0 cx; 0 fy cy; 0 0 1]`; ValueError otherwise."""
    rows = [r.split() for r in text.strip().strip("[]").split(";")]
    matrix = np.array(rows, dtype=np.float64)
    if matrix.shape != (3, 3):
        msg = f"'{text}' is not a 3x3 matrix"
        raise ValueError(msg)
    return matrix


def read_calib(path: Path) -> dict[str, str]:
    calib: dict[str, str] = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        key, sep, value = line.partition("=")
        if sep:
            calib[key.strip()] = value.strip()
    return calib


def read_pfm(path: Path) -> np.ndarray:
    """PFM (single channel `Pf`), rows stored bottom-to-top; the scale's sign gives the byte order."""
    with path.open("rb") as f:
        header = f.readline().strip()
        if header != b"Pf":
            msg = f"{path}: not a single-channel PFM (header {header!r})"
            raise SceneError(msg)
        width, height = (int(v) for v in f.readline().split())
        scale = float(f.readline().strip())
        dtype = "<f4" if scale < 0 else ">f4"
        data = np.frombuffer(f.read(width * height * 4), dtype=dtype)
    if data.size != width * height:
        msg = f"{path}: truncated PFM ({data.size} of {width * height} values)"
        raise SceneError(msg)
    return np.flipud(data.reshape(height, width)).astype(np.float32)


def _read_image(path: Path, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        msg = f"cannot read image {path}"
        raise SceneError(msg)
    return image


def _find(folder: Path, stem: str) -> Path:
    for suffix in (".png", ".jpg", ".ppm", ".pgm"):
        if (folder / f"{stem}{suffix}").exists():
            return folder / f"{stem}{suffix}"
    msg = f"{folder}: no {stem}.png/.jpg; a scene folder needs left and right images"
    raise SceneError(msg)


def read_ground_truth(folder: Path, calib: dict[str, str]) -> np.ndarray | None:
    name = calib.get("gt_file")
    path = (
        folder / name
        if name
        else next((folder / n for n in ("disp_gt.pfm", "disp_gt.png") if (folder / n).exists()), None)
    )
    if path is None or not path.exists():
        return None
    if path.suffix == ".pfm":
        gt = read_pfm(path)
        gt[~np.isfinite(gt)] = np.nan
        return gt
    raw = _read_image(path)
    if raw.ndim == 3:
        raw = raw[:, :, 0]
    gt = raw.astype(np.float32) / (calib_number(calib, "gt_scale", str(folder)) if "gt_scale" in calib else 1.0)
    gt[raw == 0] = np.nan
    return gt


def load_scene(folder: Path | str) -> Scene:
    folder = Path(folder)
    if not folder.is_dir():
        msg = f"{folder}: not a folder"
        raise SceneError(msg)
    calib_path = folder / "calib.txt"
    calib = read_calib(calib_path) if calib_path.exists() else {}
    left = _read_image(_find(folder, "left"), cv2.IMREAD_COLOR)
    right = _read_image(_find(folder, "right"), cv2.IMREAD_COLOR)
    gt = read_ground_truth(folder, calib)
    mask = None
    if (folder / "mask_nonocc.png").exists():
        mask = _read_image(folder / "mask_nonocc.png", cv2.IMREAD_GRAYSCALE) == 255
    return Scene(
        folder.name if folder.parent.name in ("", ".") else f"{folder.parent.name}/{folder.name}",
        left,
        right,
        calib,
        gt,
        mask,
    )
