"""dishbot perception: depth-based mug detection, classification, calibration and lost-mug association.

The daemon uses ``CameraObserver`` (a ``MugObserver`` on a depth camera) and ``associate``; the detector can
be used on its own on any ``RGBDFrame``.
"""

from perception.association import Association, associate
from perception.detector import DepthMugDetector, DetectorParams
from perception.observer import CameraObserver

__all__ = ["Association", "CameraObserver", "DepthMugDetector", "DetectorParams", "associate"]
