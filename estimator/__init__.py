"""Stereo-vision centerline estimation of a continuum arm (Zou et al., sections 3 and 4).

Pure vision: numpy, OpenCV, SciPy and a numba-compiled SOM. Nothing here knows about MuJoCo,
rendering or devices.
"""

from estimator.calibration import CalibrationFileError, StereoCalibration

__all__ = ["CalibrationFileError", "StereoCalibration"]
