"""dishbot perception: depth-based mug detection, classification, calibration and lost-mug association."""
