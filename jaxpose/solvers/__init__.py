"""Layer 2, solvers of ONE problem, one method per module: the three-point analytic solver, the
small-movement linear solver (rotation vector, Gauss-Newton), the Levenberg-Marquardt solver
(quaternion, optimistix), the residuals they minimise, the status codes they report.
"""

from ._linear import LinearResult as LinearResult
from ._linear import linear as linear
from ._nonlinear import NonlinearResult as NonlinearResult
from ._nonlinear import nonlinear as nonlinear
from ._p3p import ThreePointResult as ThreePointResult
from ._p3p import p3p as p3p
from ._p3p import three_point as three_point
from ._residuals import quaternion_residual as quaternion_residual
from ._residuals import ray_residual as ray_residual
from ._residuals import rotvec_residual as rotvec_residual
from ._status import Status as Status
from ._status import describe as describe
