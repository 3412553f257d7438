"""jaxpose: batched, differentiable pose recovery of a known 3D object from one calibrated
image, after Shaheen, Mallem & Chavand (2001).

The entry points a user needs are here; everything else is reachable through the
subpackages, one per layer, imports pointing down: `geometry` (rotations, camera, pose,
errors), `solvers` (one method for one problem per module), `strategy` (all triplets at
once: the mixed algorithm, robust mode, covariance, options), `api` (the entry points and
batching), `features` (the image front end: segments, vertices, keypoints, model and camera
files), `apps` (the paper's experiment, models, recognition, pointing, robot,
calibration), `viz` (rerun, overlays, figures); `jaxpose.cli` is the command line.
`apps`, `features` and `viz` (and the names from them) are imported on first use: a
program that only solves does not pay for OpenCV's front end, the models and rerun.
"""

import importlib
from typing import TYPE_CHECKING

from . import api as api
from . import geometry as geometry
from . import solvers as solvers
from . import strategy as strategy
from .api import Solution as Solution
from .api import minima as minima
from .api import solve as solve
from .api import solve_batch as solve_batch
from .api import solve_many as solve_many
from .api import solve_pnp as solve_pnp
from .api import solve_pnp_batch as solve_pnp_batch
from .api import solve_pnp_generic as solve_pnp_generic
from .api import solve_pnp_ransac as solve_pnp_ransac
from .geometry import Observations as Observations
from .geometry import Pose as Pose
from .geometry import camera_matrix as camera_matrix
from .geometry import matrix_to_rotvec as matrix_to_rotvec
from .geometry import observations as observations
from .geometry import project as project
from .geometry import rotvec_to_matrix as rotvec_to_matrix
from .solvers import Status as Status
from .strategy import Acceptance as Acceptance
from .strategy import Execution as Execution
from .strategy import MixedResult as MixedResult
from .strategy import Options as Options
from .strategy import PoseCovariance as PoseCovariance
from .strategy import RobustOptions as RobustOptions
from .strategy import RobustResult as RobustResult
from .strategy import Search as Search
from .strategy import Selection as Selection
from .strategy import mixed as mixed
from .strategy import pose_covariance as pose_covariance
from .strategy import robust as robust

if TYPE_CHECKING:
    from . import apps as apps
    from . import features as features
    from . import viz as viz
    from .apps import Polyhedron as Polyhedron
    from .apps import default_bench as default_bench

__version__ = "0.1.0"

# name -> the subpackage that holds it (itself, for a subpackage)
_LAZY = {
    "apps": None,
    "features": None,
    "viz": None,
    "Polyhedron": "apps",
    "default_bench": "apps",
}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'jaxpose' has no attribute {name!r}")
    home = _LAZY[name]
    if home is None:
        return importlib.import_module(f".{name}", __name__)
    return getattr(importlib.import_module(f".{home}", __name__), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
