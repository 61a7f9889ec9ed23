"""Output messages of one processed frame, built one way for the live nodes and `stereo-depth process`.

Both must agree to the byte (the replay tests compare them), so the DisparityImage's valid window,
range and resolution are assembled here, for either message flavour, and nowhere else.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.matching import valid_window
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pipeline import output_params
from stereo_depth.messages import MessageTypes, disparity_to_msg


def disparity_message(
    types: MessageTypes, header: Any, disparity: np.ndarray, camera: StereoCamera, params: StereoParams
) -> Any:
    """DisparityImage with the matcher's real valid window and resolution (1/16 px per downsample step)."""
    params = output_params(params)  # the disparity's own size and range (downsample_output)
    height, width = disparity.shape
    return disparity_to_msg(
        types,
        header,
        disparity,
        camera,
        params.min_disparity,
        params.disparity_range,
        valid_window(width, height, params),
        delta_d=params.downsample / 16.0,
    )
