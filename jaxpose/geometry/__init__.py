"""Layer 1, geometry: rotations in four parameterisations, the 3x4 camera and its projection,
visual-ray planes and back-projection, the pose type and the observations of one problem,
the paper's error measures, input validation.
"""

from ._camera import backproject as backproject
from ._camera import camera_centre as camera_centre
from ._camera import camera_matrix as camera_matrix
from ._camera import decompose_camera as decompose_camera
from ._camera import normalize_camera as normalize_camera
from ._camera import project as project
from ._camera import project_with_depth as project_with_depth
from ._camera import ray_planes as ray_planes
from ._camera import undistort_pixels as undistort_pixels
from ._distortion import distort as distort
from ._distortion import project_points as project_points
from ._distortion import refine_in_image as refine_in_image
from ._errors import pose_error as pose_error
from ._errors import pose_error_per_point as pose_error_per_point
from ._errors import reprojection_residuals as reprojection_residuals
from ._errors import reprojection_rms as reprojection_rms
from ._euler import matrix_to_rpy as matrix_to_rpy
from ._euler import rpy_to_matrix as rpy_to_matrix
from ._pose import Observations as Observations
from ._pose import Pose as Pose
from ._pose import observations as observations
from ._pose import transform as transform
from ._rotation import compose as compose
from ._rotation import hat as hat
from ._rotation import matrix_to_quaternion as matrix_to_quaternion
from ._rotation import matrix_to_rotvec as matrix_to_rotvec
from ._rotation import project_to_rotation as project_to_rotation
from ._rotation import quaternion_multiply as quaternion_multiply
from ._rotation import quaternion_to_matrix as quaternion_to_matrix
from ._rotation import quaternion_to_rotvec as quaternion_to_rotvec
from ._rotation import quaternion_vector_to_matrix as quaternion_vector_to_matrix
from ._rotation import rotation_angle as rotation_angle
from ._rotation import rotation_distance as rotation_distance
from ._rotation import rotvec_to_matrix as rotvec_to_matrix
from ._rotation import rotvec_to_quaternion as rotvec_to_quaternion
