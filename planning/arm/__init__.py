"""The arm: its URDF (generated from the thesis's Table 3.1), servo models, kinematics and grasp geometry."""

from description.arm import BUNDLED_URDF, GRASP_FRAME, GripperGeometry
from description.servos import SERVO_MODELS, ServoModel
from planning.arm.errors import ArmModelError, CalibrationError, InvalidTarget
from planning.arm.model import ArmModel
from planning.arm.targets import GraspKind, GraspTarget, IkResult

__all__ = [
    "BUNDLED_URDF",
    "GRASP_FRAME",
    "SERVO_MODELS",
    "ArmModel",
    "ArmModelError",
    "CalibrationError",
    "GraspKind",
    "GraspTarget",
    "GripperGeometry",
    "IkResult",
    "InvalidTarget",
    "ServoModel",
]
