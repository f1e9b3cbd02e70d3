"""What a camera frame must meet before the observer uses it (``FrameLimits``); light: checking a config
file imports this module, not the observer."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from validation import within

# The ranges of the config's ``[camera]`` keys ``frame_timeout_s``, ``max_frame_age_s`` and ``frame_retries``.
FrameTimeout = Annotated[float, within(0.05, 60.0)]
FrameAge = Annotated[float, within(0.01, 60.0)]
FrameRetries = Annotated[int, within(0, 10)]


@dataclass(frozen=True, slots=True)
class FrameLimits:
    """What a frame must meet (``[camera]`` in the config): ``timeout_s`` to arrive, at most ``max_age_s``
    old when it does (by the frame's ``t`` on the observer's clock), and ``retries`` further attempts after
    a frame that failed either or could not be used."""

    timeout_s: FrameTimeout = 2.0
    max_age_s: FrameAge = 1.0
    retries: FrameRetries = 2

    def __post_init__(self) -> None:
        if not self.timeout_s > 0.0:
            raise ValueError(f"frame timeout_s {self.timeout_s}: must be positive")
        if not self.max_age_s > 0.0:
            raise ValueError(f"frame max_age_s {self.max_age_s}: must be positive")
        if self.retries < 0:
            raise ValueError(f"frame retries {self.retries}: must be 0 or more")
