"""Real depth cameras. The simulated camera lives with the simulated world."""

from drivers.camera.realsense import CameraUnavailable, RealSenseCamera, depth_in_metres, load_pyrealsense

__all__ = ["CameraUnavailable", "RealSenseCamera", "depth_in_metres", "load_pyrealsense"]
