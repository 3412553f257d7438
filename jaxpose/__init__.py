"""jaxpose: batched, differentiable pose recovery of a known 3D object from one calibrated
image, after Shaheen, Mallem & Chavand (2001).

The public API is re-exported here; the implementation lives in private modules.
"""

from ._api import METHODS as METHODS
from ._api import Solution as Solution
from ._api import solve as solve
from ._api import solve_pnp as solve_pnp
from ._api import solve_pnp_batch as solve_pnp_batch
from ._bench import Bench as Bench
from ._bench import Polyhedron as Polyhedron
from ._bench import Scene as Scene
from ._bench import cross_prism as cross_prism
from ._bench import default_bench as default_bench
from ._bench import random_scene as random_scene
from ._camera import backproject as backproject
from ._camera import camera_centre as camera_centre
from ._camera import camera_matrix as camera_matrix
from ._camera import decompose_camera as decompose_camera
from ._camera import normalize_camera as normalize_camera
from ._camera import project as project
from ._camera import project_with_depth as project_with_depth
from ._camera import ray_planes as ray_planes
from ._camera import undistort_pixels as undistort_pixels
from ._errors import pose_error as pose_error
from ._errors import pose_error_per_point as pose_error_per_point
from ._errors import reprojection_residuals as reprojection_residuals
from ._errors import reprojection_rms as reprojection_rms
from ._mixed import Initial as Initial
from ._mixed import MixedResult as MixedResult
from ._mixed import best_triplet as best_triplet
from ._mixed import initial_poses as initial_poses
from ._mixed import mixed as mixed
from ._mixed import mixed_from_initial as mixed_from_initial
from ._mixed import triplet_indices as triplet_indices
from ._pose import Observations as Observations
from ._pose import Pose as Pose
from ._pose import observations as observations
from ._pose import transform as transform
from ._residuals import quaternion_residual as quaternion_residual
from ._residuals import ray_residual as ray_residual
from ._residuals import rotvec_residual as rotvec_residual
from ._rotation import compose as compose
from ._rotation import hat as hat
from ._rotation import matrix_to_quaternion as matrix_to_quaternion
from ._rotation import matrix_to_rotvec as matrix_to_rotvec
from ._rotation import matrix_to_rpy as matrix_to_rpy
from ._rotation import project_to_rotation as project_to_rotation
from ._rotation import quaternion_multiply as quaternion_multiply
from ._rotation import quaternion_to_matrix as quaternion_to_matrix
from ._rotation import quaternion_to_rotvec as quaternion_to_rotvec
from ._rotation import quaternion_vector_to_matrix as quaternion_vector_to_matrix
from ._rotation import rotation_angle as rotation_angle
from ._rotation import rotation_distance as rotation_distance
from ._rotation import rotvec_to_matrix as rotvec_to_matrix
from ._rotation import rotvec_to_quaternion as rotvec_to_quaternion
from ._rotation import rpy_to_matrix as rpy_to_matrix
from ._solver.linear import LinearResult as LinearResult
from ._solver.linear import linear as linear
from ._solver.nonlinear import NonlinearResult as NonlinearResult
from ._solver.nonlinear import nonlinear as nonlinear
from ._solver.p3p import ThreePointResult as ThreePointResult
from ._solver.p3p import p3p as p3p
from ._solver.p3p import three_point as three_point
from ._status import Status as Status
from ._status import describe as describe

__version__ = "0.1.0"
