"""Layer 4, the entry points: `solve` (JAX-native, differentiable), `solve_many` (batch-first),
`solve_pnp`/`solve_pnp_batch` (OpenCV conventions), chunked and sharded batches.
"""
from ._batch import batch_devices as batch_devices
from ._batch import batch_mesh as batch_mesh
from ._batch import run_batched as run_batched
from ._batch import solve_batch as solve_batch
from ._solve import METHODS as METHODS
from ._solve import Solution as Solution
from ._solve import solve as solve
from ._solve import solve_many as solve_many
from ._solve import solve_pnp as solve_pnp
from ._solve import solve_pnp_batch as solve_pnp_batch
