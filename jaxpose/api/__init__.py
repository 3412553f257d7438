"""Layer 4, the entry points: `solve` (JAX-native, differentiable), `solve_many` (batch-first),
`solve_batch` (chunked and sharded batches from numpy), `minima` (every local minimum
found, beside a `Solution`), and `solve_pnp`/`solve_pnp_batch`/
`solve_pnp_ransac`/`solve_pnp_generic` (OpenCV conventions, numpy in and out).
"""

from ._batch import batch_devices as batch_devices
from ._batch import batch_mesh as batch_mesh
from ._batch import run_batched as run_batched
from ._generic import minima as minima
from ._generic import solve_pnp_generic as solve_pnp_generic
from ._pnp import solve_pnp as solve_pnp
from ._pnp import solve_pnp_batch as solve_pnp_batch
from ._pnp import solve_pnp_ransac as solve_pnp_ransac
from ._programs import cache_dir as cache_dir
from ._solve import METHODS as METHODS
from ._solve import Solution as Solution
from ._solve import solve as solve
from ._solve import solve_batch as solve_batch
from ._solve import solve_many as solve_many
