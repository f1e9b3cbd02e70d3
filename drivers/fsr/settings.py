"""The FSR reader's settings (``[hardware.fsr]`` in the config is this type); light: checking a config
file imports this module, not the reader."""

from __future__ import annotations

from dataclasses import KW_ONLY, dataclass
from typing import Annotated

from validation import NON_EMPTY, Invalid, within


@dataclass(frozen=True, slots=True)
class FsrSettings:
    """The FSR Arduino's port and the reader's calibration and grasp detection (``dishbot fsr calibrate``
    prints gain, threshold_n and release_n); ``release_n`` None is 60 % of ``threshold_n``."""

    port: Annotated[str, NON_EMPTY]
    _: KW_ONLY
    gain: Annotated[float, within(0.001, 1000.0)] = 1.0
    threshold_n: Annotated[float, within(0.05, 50.0)]
    release_n: Annotated[float, within(0.0, 50.0)] | None = None
    debounce_s: Annotated[float, within(0.0, 1.0)] = 0.03
    stale_after_s: Annotated[float, within(0.02, 5.0)] = 0.2

    def __post_init__(self) -> None:
        if self.release_n is not None and self.release_n >= self.threshold_n:
            raise Invalid(
                f"release_n: {self.release_n:g} must be below threshold_n {self.threshold_n:g} "
                "(the hysteresis of the grasp detection)"
            )
