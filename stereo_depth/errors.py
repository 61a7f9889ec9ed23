"""The package's own error types.

Every error a user can cause (bad calibration, bad image, bad parameter, bad bag) is raised as one of
these, with a message that says what was expected, what was found and how to fix it. Nodes log them and
skip the frame; commands print them as one line and exit non-zero. Anything else escaping is a bug.
"""

import inspect


class StereoDepthError(Exception):
    """Base of every error stereo_depth raises on purpose. `made_at` (file:line where it was created)
    tells kinds of problems apart where one `raise` passes on errors built by a helper."""

    def __init__(self, *args: object) -> None:
        super().__init__(*args)
        caller = inspect.currentframe()
        caller = caller.f_back if caller is not None else None
        self.made_at = f"{caller.f_code.co_filename}:{caller.f_lineno}" if caller is not None else ""


class CalibrationError(StereoDepthError):
    """A CameraInfo pair cannot be used for stereo (zero K, size mismatch, bad baseline, ...)."""


class ImageError(StereoDepthError):
    """An image cannot be decoded (unknown encoding, wrong buffer size, mismatched pair, ...)."""


class ParameterError(StereoDepthError):
    """A parameter value is out of range or inconsistent with another one."""


class BagError(StereoDepthError):
    """A rosbag2 file cannot be read or written as asked."""


class MessageError(StereoDepthError):
    """An input's bytes are not a message of its topic's type (cut short, or another layout)."""
