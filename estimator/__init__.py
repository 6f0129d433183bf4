"""Stereo-vision centerline estimation of a continuum arm (Zou et al., sections 3 and 4).

Pure vision: numpy, OpenCV, SciPy and a numba-compiled SOM. Nothing here knows about MuJoCo,
rendering or devices.

    from estimator import CenterlineEstimator, EstimatorConfig, StereoCalibration
    est = CenterlineEstimator(calib)                      # default mode
    res = est.estimate(left_bgr, right_bgr)               # raw images
    res.points, res.valid, res.reason, res.left_uv, res.right_uv, res.timings_ms
"""

from estimator.calibration import CalibrationFileError, StereoCalibration
from estimator.config import EstimatorConfig
from estimator.pipeline import CenterlineEstimator, EstimateResult, use_second_thread

__all__ = ["CalibrationFileError", "CenterlineEstimator", "EstimateResult", "EstimatorConfig", "StereoCalibration",
           "use_second_thread"]
