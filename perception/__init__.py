"""dishbot perception: depth-based mug detection, classification, calibration and lost-mug association.

The daemon uses ``CameraObserver`` (a ``MugObserver`` on a depth camera) and ``associate``; the detector can
be used on its own on any ``RGBDFrame``. They load OpenCV and NumPy, so they are imported on first use:
``perception.frames`` (what a frame must meet, what checking a config needs) comes without them.
"""

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from perception.association import Association, associate
    from perception.detector import DepthMugDetector, DetectorParams
    from perception.observer import CameraObserver

_ON_FIRST_USE = {
    "Association": "perception.association",
    "associate": "perception.association",
    "DepthMugDetector": "perception.detector",
    "DetectorParams": "perception.detector",
    "CameraObserver": "perception.observer",
}


def __getattr__(name: str) -> object:
    module = _ON_FIRST_USE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


__all__ = ["Association", "CameraObserver", "DepthMugDetector", "DetectorParams", "associate"]
