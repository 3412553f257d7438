"""Layer 3, strategies over all triplets at once: the options, triplet selection, the mixed
algorithm (three-point, linear, Levenberg-Marquardt, retries) in `jax.lax` control flow,
robust scoring by consensus, pose covariance, the implicit derivative of the answer.
"""

from ._accept import accepts as accepts
from ._accept import threshold as threshold
from ._best import Answer as Answer
from ._best import answer as answer
from ._best import answer_batch as answer_batch
from ._best import escalation as escalation
from ._best import rung_applies as rung_applies
from ._best import spread_matches as spread_matches
from ._best_roots import Best as Best
from ._best_roots import best_of_roots as best_of_roots
from ._best_roots import best_of_roots_batch as best_of_roots_batch
from ._covariance import PoseCovariance as PoseCovariance
from ._covariance import pose_covariance as pose_covariance
from ._methods import SINGLE_METHODS as SINGLE_METHODS
from ._methods import per_triplet as per_triplet
from ._methods import run_method as run_method
from ._minima import MINIMA_ROOTS as MINIMA_ROOTS
from ._minima import SAME_MINIMUM as SAME_MINIMUM
from ._minima import Minima as Minima
from ._minima import local_minima as local_minima
from ._minima import rank_minima as rank_minima
from ._mixed import MixedResult as MixedResult
from ._mixed import mixed as mixed
from ._mixed import mixed_from_initial as mixed_from_initial
from ._mixed import mixed_from_initial_batch as mixed_from_initial_batch
from ._options import METHODS as METHODS
from ._options import TRACED as TRACED
from ._options import Acceptance as Acceptance
from ._options import Execution as Execution
from ._options import Options as Options
from ._options import RobustOptions as RobustOptions
from ._options import Search as Search
from ._options import Selection as Selection
from ._options import resolve as resolve
from ._options import split_values as split_values
from ._options import with_values as with_values
from ._pipeline import Solution as Solution
from ._pipeline import solve_problems as solve_problems
from ._planar import planar_partner as planar_partner
from ._planar import planar_poses as planar_poses
from ._robust import RobustResult as RobustResult
from ._robust import robust as robust
from ._triplets import Initial as Initial
from ._triplets import area_threshold as area_threshold
from ._triplets import best_triplet as best_triplet
from ._triplets import initial_poses as initial_poses
from ._triplets import spread_triplets as spread_triplets
from ._triplets import triplet_indices as triplet_indices
