"""appdgen: self-labelled data for learning camera miscalibration detection."""
from appdgen.calib.calibration import PARAMS, Calibration
from appdgen.errors import AppdgenError

__version__ = "0.2.0"
__all__ = ["AppdgenError", "Calibration", "PARAMS", "__version__"]
