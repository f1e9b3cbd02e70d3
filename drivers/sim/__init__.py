"""Device simulators on pseudo-terminals: a Dynamixel chain and the FSR Arduino, byte for byte.

The real drivers open these like hardware, so the simulated cell runs the hardware code path. The world
behind the servos plugs in through :class:`ServoPlant`.
"""

from drivers.sim.fsr import FsrSimulator
from drivers.sim.plant import FirstOrderPlant, ServoPlant
from drivers.sim.servo_chain import ServoChainSimulator, SimServo, default_chain

__all__ = [
    "FirstOrderPlant",
    "FsrSimulator",
    "ServoChainSimulator",
    "ServoPlant",
    "SimServo",
    "default_chain",
]
