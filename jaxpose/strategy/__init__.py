"""Layer 3, strategies over all triplets at once: triplet selection, the mixed algorithm
(three-point, linear, Levenberg-Marquardt, retries) in `jax.lax` control flow, robust
scoring by consensus, pose covariance.
"""
from ._covariance import PoseCovariance as PoseCovariance
from ._covariance import pose_covariance as pose_covariance
from ._mixed import Initial as Initial
from ._mixed import MixedResult as MixedResult
from ._mixed import best_triplet as best_triplet
from ._mixed import initial_poses as initial_poses
from ._mixed import mixed as mixed
from ._mixed import mixed_from_initial as mixed_from_initial
from ._mixed import mixed_from_initial_batch as mixed_from_initial_batch
from ._mixed import spread_triplets as spread_triplets
from ._mixed import triplet_indices as triplet_indices
from ._robust import RobustResult as RobustResult
from ._robust import robust as robust
from ._robust import solve_pnp_ransac as solve_pnp_ransac
