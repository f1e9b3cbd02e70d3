"""Array types shared by every layer."""

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
