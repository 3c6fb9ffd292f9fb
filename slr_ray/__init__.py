"""slr_ray: Simulated LiDAR Repositioning.

From one LiDAR scan of a scene, produce the scans an ideal static scanner would
have recorded from other positions, using only points of the original cloud.
"""

import sys as _sys
import warnings as _warnings

#: numba's warning that an old libtbb (open3d's, loaded first) leaves it its OpenMP or workqueue threads:
#: nothing a user can act on, and the loops run the same (numba highlights the text: \x1b[1m before it)
_warnings.filterwarnings("ignore", message=r"(\x1b\[[0-9;]*m)?The TBB threading layer requires TBB")

from .accumulator import ScanAccumulator
from .errors import FormatError, InputTypeError, InputValueError, MissingDependencyError, SlrError, SlrNote, SlrWarning
from .pattern import PRESETS, ScanPattern, as_pattern, preset, pulse_directions, pulse_rays
from .scan import Scan
from .backends import Backend, Scanner, available_backends, prepare, simulate_scan
from .distances import DistanceHistogram, distance_histogram, height_sweep, pulse_sized_bins
from .meshscan import MeshScan, scan_mesh
from .positions import (AzimuthProfile, candidate_cells, label_ground, minimum_profile, select_positions,
                        suggest_resolution)
from .metrics import Agreement, agreement, similarity
from .sensors import SENSORS, BeamPattern, sensor
from .spherical import pulse_bins, spherical_coordinates
from .io import e57, las, outputs, pcd
from .metrics import cellgrid, coverage as _coverage

#: modules that moved into :mod:`slr_ray.io`, importable under their old paths too
#: (``from slr_ray.outputs import OutputPlan``): the same module objects, not copies
for _module in (outputs, las, pcd, e57):
    _sys.modules[f"{__name__}.{_module.__name__.rsplit('.', 1)[1]}"] = _module
del _module
#: and modules that moved into :mod:`slr_ray.metrics` (``from slr_ray.similarity import nearest``)
_sys.modules[f"{__name__}.similarity"] = _coverage
_sys.modules[f"{__name__}.cellgrid"] = cellgrid  # and slr_ray.cellgrid, as before

__version__ = "0.1.0"

__all__ = [
    "ScanPattern", "PRESETS", "preset", "as_pattern", "Scan", "simulate_scan", "prepare", "Scanner",
    "Backend", "available_backends", "ScanAccumulator", "pulse_rays",
    "scan_mesh", "MeshScan", "similarity", "agreement", "Agreement", "BeamPattern", "sensor", "SENSORS",
    "candidate_cells", "select_positions", "minimum_profile", "AzimuthProfile", "suggest_resolution",
    "label_ground", "pulse_sized_bins", "distance_histogram", "DistanceHistogram", "height_sweep",
    "pulse_bins", "pulse_directions", "spherical_coordinates",
    "SlrError", "InputValueError", "InputTypeError", "FormatError", "MissingDependencyError",
    "SlrWarning", "SlrNote",
]
