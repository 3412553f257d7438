"""The paper's four-degree-of-freedom robot (Section 6, Fig. 9) as a kinematic model.

A carriage with two translation axes carries a turret with two rotary joints; the turret
holds a straight shank with an LED at its tip. In the robot's base frame (z up, the
carriage moving parallel to the base plane `z = 0`):

- joint 1, `x`: prismatic, carriage along the base x axis (mm);
- joint 2, `y`: prismatic, carriage along the base y axis (mm);
- joint 3, `pan` (psi): revolute about the vertical axis through the wrist (rad);
- joint 4, `tilt` (theta): revolute about the turret's horizontal axis (rad), the shank's
  angle from the downward vertical, positive towards the turret's +x.

The pan and tilt axes meet at the wrist, `w = (x, y, h)`, a fixed height `h` above the
base plane; the shank of fixed length `L` points along

$$ s(\\psi, \\theta) = (\\sin\\theta \\cos\\psi,\\ \\sin\\theta \\sin\\psi,\\ -\\cos\\theta), $$

so the tip (the LED) is at

$$ \\text{tip} = (x + L \\sin\\theta \\cos\\psi,\\ y + L \\sin\\theta \\sin\\psi,\\
   h - L \\cos\\theta) $$

in the base frame, and at `R_base tip + t_base` in the world.

**Inverse kinematics, closed form.** Four joints, three coordinates: one degree of
freedom is left. The tip height fixes the tilt, `cos(theta) = (h - z) / L` (two
solutions, `+theta` and `-theta` with the pan turned by pi: the same shank direction); the
pan, i.e. the horizontal direction `phi` the shank leans to, is free, and the carriage
follows, `(x, y) = (p_x, p_y) - L sin(theta) (cos phi, sin phi)`. We choose `phi` as the
azimuth of a requested approach direction (e.g. into the clicked face, against its
outward normal): this gives the shank direction closest to it. Without one, the shank
leans away from the base's vertical axis (`phi = atan2(p_y, p_x)`), which keeps the
carriage nearest the middle of its travel. When that candidate breaks a joint limit, the
nearest azimuth (in 5 degree steps, both tilt signs) within every limit is taken instead;
if none is, the status says so.

**The default robot** (`default_robot`): base frame = world frame (the bench's world is
the robot's table frame, z up, origin at the table's centre), wrist height `h = 300` mm,
shank `L = 320` mm (tip heights from -20 mm, straight down, to 244 mm at 80 degrees of
tilt), carriage travel +-400 mm on both axes, pan +-180 degrees, tilt +-80 degrees. The
bench object (z from -14 to 33 mm, within 130 mm of the table origin) is reachable, its top
face with about 30 degrees of tilt.

Everything is pure JAX for one robot and one joint vector / target (no batch axis;
`jax.vmap` over many), fixed shapes, NaN-free; `joint_command` is the validating numpy
boundary that raises `ValueError`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt
from jaxtyping import Array, ArrayLike, Float, Int, Real

from ..geometry._numerics import float_dtype, safe_sqrt
from ..geometry._validate import no_type_check
from ..solvers._status import StatusCode

__all__ = [
    "JOINT_NAMES",
    "JointCommand",
    "Robot",
    "RobotState",
    "RobotStatus",
    "default_robot",
    "forward_kinematics",
    "inverse_kinematics",
    "joint_command",
]

#: Names of the four joints, in the order of a joint vector.
JOINT_NAMES = ("x", "y", "pan", "tilt")


class RobotStatus(StatusCode):
    """Whether the LED tip can be brought to a target (`JointCommand.status`). `OK` and
    `NOT_FINITE` have the values of the solvers' `Status`."""

    OK = 0, "the tip reaches the target within the joint limits"
    NOT_FINITE = 11, "non-finite values in the input"
    UNREACHABLE = (
        14,
        "the target is outside the robot's workspace: no joint values put the shank tip there",
    )
    JOINT_LIMITS = 15, "the shank tip reaches the target only with joints outside their limits"


class Robot(NamedTuple):
    """The robot's geometry and limits (a pytree: pass it into `jit`/`vmap` freely).

    **Fields:**
    - `base_R`, `base_t`: `(3, 3)`, `(3,)` the base frame in the world, `p_world =
      base_R p_base + base_t`.
    - `height`: `()` wrist height `h` above the base plane `z = 0` (mm).
    - `shank`: `()` shank length `L`, wrist to LED tip (mm).
    - `lower`, `upper`: `(4,)` joint limits `(x, y, pan, tilt)` (mm, mm, rad, rad).

    Numpy arrays from `default_robot`; JAX arrays inside `jit`/`vmap`.
    """

    base_R: Float[Array | np.ndarray, "3 3"]
    base_t: Float[Array | np.ndarray, " 3"]
    height: Float[Array | np.ndarray, ""]
    shank: Float[Array | np.ndarray, ""]
    lower: Float[Array | np.ndarray, " 4"]
    upper: Float[Array | np.ndarray, " 4"]


class RobotState(NamedTuple):
    """Forward kinematics of one joint vector, world frame.

    **Fields:**
    - `tip`: `(3,)` the LED at the shank's tip.
    - `wrist`: `(3,)` where the pan and tilt axes meet (the shank's root).
    - `shank`: `(3,)` unit direction from wrist to tip.
    - `frames`: `(4, 4, 4)` homogeneous transforms (frame -> world) for drawing: the base,
      the carriage (after `x`, `y`; at the wrist, base orientation), the turret (after
      `pan`) and the tool (after `tilt`, at the tip, its z axis along the shank).
    """

    tip: Float[Array, " 3"]
    wrist: Float[Array, " 3"]
    shank: Float[Array, " 3"]
    frames: Float[Array, "4 4 4"]


class JointCommand(NamedTuple):
    """The joint command that brings the LED tip to a target.

    **Fields:**
    - `joints`: `(4,)` `(x, y, pan, tilt)` in mm, mm, rad, rad. Placeholder when the
      status is not `OK`: the joints clipped to their limits (finite, not a solution).
    - `approach_angle`: `()` angle (rad) between the shank and the requested approach
      direction (0 when none was requested).
    - `error`: `()` distance from the commanded tip to the target (mm): rounding only
      when `OK`.
    - `status`: `()` int32 `RobotStatus`: `OK`, `UNREACHABLE` (no joint values put the tip
      there: `|h - z| > L`), `JOINT_LIMITS` (only outside the limits) or `NOT_FINITE`.
    """

    joints: Float[Array, " 4"]
    approach_angle: Float[Array, ""]
    error: Float[Array, ""]
    status: Int[Array, ""]


def default_robot(dtype=np.float64) -> Robot:
    """The default robot, dimensioned for the default bench (see the module docstring).

    **Arguments:**
    - `dtype`: floating dtype of its arrays (numpy; default float64).

    **Returns:** a `Robot` of numpy arrays.
    """
    deg = math.pi / 180
    return Robot(
        base_R=np.eye(3, dtype=dtype),
        base_t=np.zeros(3, dtype=dtype),
        height=np.asarray(300.0, dtype),
        shank=np.asarray(320.0, dtype),
        lower=np.asarray([-400.0, -400.0, -180 * deg, -80 * deg], dtype),
        upper=np.asarray([400.0, 400.0, 180 * deg, 80 * deg], dtype),
    )


def _as_robot(robot: Robot, dtype) -> Robot:
    r = Robot(*(jnp.asarray(a, dtype) for a in robot))
    shapes = {"base_R": (3, 3), "base_t": (3,), "height": (), "shank": (), "lower": (4,)}
    shapes["upper"] = (4,)
    for name, shape in shapes.items():
        if tuple(getattr(r, name).shape) != shape:
            raise ValueError(
                f"robot.{name} must have shape {shape}, got {tuple(getattr(r, name).shape)}"
            )
    return r


def _rz(a):
    c, s = jnp.cos(a), jnp.sin(a)
    z, o = jnp.zeros_like(a), jnp.ones_like(a)
    return jnp.stack([jnp.stack([c, -s, z]), jnp.stack([s, c, z]), jnp.stack([z, z, o])])


def _ry(a):
    c, s = jnp.cos(a), jnp.sin(a)
    z, o = jnp.zeros_like(a), jnp.ones_like(a)
    return jnp.stack([jnp.stack([c, z, s]), jnp.stack([z, o, z]), jnp.stack([-s, z, c])])


def _frame(R, t):
    bottom = jnp.asarray([[0, 0, 0, 1]], R.dtype)
    return jnp.concatenate([jnp.concatenate([R, t[:, None]], axis=1), bottom], axis=0)


# `forward_kinematics`, `inverse_kinematics` and `joint_command` check their arguments
# themselves (a `ValueError` naming the argument): no run-time type check comes before
# theirs.
@no_type_check
def forward_kinematics(robot: Robot, joints: Real[ArrayLike, " 4"]) -> RobotState:
    """Where the LED tip is for a joint vector (see the module docstring).

    $$ \\text{tip} = R_b \\left( (x, y, h) + L \\, s(\\psi, \\theta) \\right) + t_b $$

    **Arguments:**
    - `robot`: the `Robot`.
    - `joints`: `(4,)` `(x, y, pan, tilt)` (mm, mm, rad, rad); limits are not checked.

    **Returns:** a `RobotState` (tip, wrist, shank direction, frames), world frame.
    """
    dtype = float_dtype(joints, robot.height)
    robot = _as_robot(robot, dtype)
    q = jnp.asarray(joints, dtype)
    if q.shape != (4,):
        raise ValueError(f"joints must have shape (4,), got {q.shape}")
    x, y, pan, tilt = q[0], q[1], q[2], q[3]
    # Tool frame: z along the shank, s = Rz(pan) Ry(pi - tilt) e_z.
    turret = _rz(pan)
    tool = turret @ _ry(jnp.pi - tilt)
    wrist_b = jnp.stack([x, y, robot.height])
    shank_b = tool[:, 2]
    tip_b = wrist_b + robot.shank * shank_b
    Rb, tb = jnp.asarray(robot.base_R), jnp.asarray(robot.base_t)
    frames = jnp.stack(
        [
            _frame(Rb, tb),
            _frame(Rb, Rb @ wrist_b + tb),
            _frame(Rb @ turret, Rb @ wrist_b + tb),
            _frame(Rb @ tool, Rb @ tip_b + tb),
        ]
    )
    return RobotState(
        tip=Rb @ tip_b + tb, wrist=Rb @ wrist_b + tb, shank=Rb @ shank_b, frames=frames
    )


def _wrap(a):
    """Angle to `(-pi, pi]`."""
    return jnp.pi - jnp.mod(jnp.pi - a, 2 * jnp.pi)


@no_type_check
def inverse_kinematics(
    robot: Robot,
    target: Real[ArrayLike, " 3"],
    approach: Real[ArrayLike, " 3"] | None = None,
    *,
    steps: int = 72,
) -> JointCommand:
    """The joint command that brings the LED tip to `target` (closed form).

    `cos(theta) = (h - z) / L` from the target's height in the base frame, then a
    choice of the pan (the azimuth `phi` the shank leans to) and the carriage
    `(x, y) = (p_x, p_y) - L sin(theta) (cos phi, sin phi)`; see the module docstring.
    Candidates are the preferred azimuth `phi0` and its neighbours in steps of
    `2 pi / steps`, each with both tilt signs (`(phi, theta)` and `(phi + pi, -theta)`,
    the same shank); the one nearest `phi0` (then `theta >= 0`) within all joint limits
    is returned.

    **Arguments:**
    - `robot`: the `Robot`.
    - `target`: `(3,)` world point for the tip (mm).
    - `approach`: optional `(3,)` world direction the shank should point along, towards
      the target (e.g. minus the outward normal of the face to touch). `phi0` is its
      azimuth in the base frame; when it is `None`, zero or vertical,
      `phi0 = atan2(p_y, p_x)` (the shank leans outwards).
    - `steps`: number of candidate azimuths around the circle (static).

    **Returns:** a `JointCommand` (joints, approach angle, tip error, status).
    """
    dtype = float_dtype(target, robot.height)
    robot = _as_robot(robot, dtype)
    target = jnp.asarray(target, dtype)
    if target.shape != (3,):
        raise ValueError(f"target must have shape (3,), got {target.shape}")
    a = jnp.zeros(3, dtype) if approach is None else jnp.asarray(approach, dtype)
    if a.shape != (3,):
        raise ValueError(f"approach must have shape (3,), got {a.shape}")
    finite = jnp.all(jnp.isfinite(target)) & jnp.all(jnp.isfinite(a))
    target = jnp.where(finite, target, 0)
    a = jnp.where(finite, a, 0)
    p = robot.base_R.T @ (target - robot.base_t)
    a_b = robot.base_R.T @ a
    L, h = robot.shank, robot.height

    cos_t = (h - p[2]) / L
    reachable = jnp.abs(cos_t) <= 1
    cos_t = jnp.clip(cos_t, -1, 1)
    sin_t = safe_sqrt(1 - cos_t * cos_t)
    theta = jnp.arctan2(sin_t, cos_t)
    radius = L * sin_t

    a_norm = jnp.sqrt(jnp.sum(a_b * a_b))
    a_h = jnp.sqrt(a_b[0] ** 2 + a_b[1] ** 2)
    eps = jnp.finfo(dtype).eps
    use_approach = a_h > 1e3 * eps * jnp.maximum(a_norm, jnp.finfo(dtype).tiny)
    safe_ax = jnp.where(use_approach, a_b[0], 1)
    phi_out = jnp.arctan2(p[1], p[0])
    phi0 = jnp.where(use_approach, jnp.arctan2(a_b[1], safe_ax), phi_out)

    # Candidate azimuths ordered by distance from phi0: 0, +d, -d, +2d, ...
    k = np.arange(steps)
    offsets = np.where(k % 2 == 1, (k + 1) // 2, -(k // 2)) * (2 * np.pi / steps)
    phis = phi0 + jnp.asarray(offsets, dtype)  # (steps,)
    carriage = p[None, :2] - radius * jnp.stack([jnp.cos(phis), jnp.sin(phis)], axis=1)
    # Both tilt signs: (pan = phi, +theta) and (pan = phi + pi, -theta).
    pans = jnp.concatenate([_wrap(phis), _wrap(phis + jnp.pi)])
    tilts = jnp.concatenate([jnp.full(steps, theta), jnp.full(steps, -theta)])
    xy = jnp.concatenate([carriage, carriage])
    q = jnp.concatenate([xy, pans[:, None], tilts[:, None]], axis=1)  # (2 steps, 4)
    lo, hi = robot.lower, robot.upper
    # Pan limits may be any window: use whichever of pan, pan + 2 pi, pan - 2 pi is in it.
    shifted = pans[None, :] + jnp.asarray([[0.0], [2 * np.pi], [-2 * np.pi]], dtype)
    in_window = (lo[2] <= shifted) & (shifted <= hi[2])
    pans = jnp.take_along_axis(shifted, jnp.argmax(in_window, axis=0)[None, :], axis=0)[0]
    q = q.at[:, 2].set(pans)
    others = jnp.asarray([0, 1, 3])
    within = jnp.all(
        (lo[others][None, :] <= q[:, others]) & (q[:, others] <= hi[others][None, :]), axis=1
    )
    within = within & jnp.any(in_window, axis=0)
    # Rank: azimuth nearest phi0 first, then the positive tilt.
    order = jnp.concatenate([2 * jnp.arange(steps), 2 * jnp.arange(steps) + 1])
    score = jnp.where(within, order, 2 * steps)
    best = jnp.argmin(score)
    feasible = jnp.any(within) & reachable & finite
    joints = jnp.where(feasible, q[best], jnp.clip(q[0], lo, hi))

    state = forward_kinematics(robot, joints)
    error = jnp.sqrt(jnp.sum((state.tip - target) ** 2))
    safe_a = jnp.where(a_norm > 0, a_norm, 1)
    cos_app = jnp.clip(jnp.dot(state.shank, a) / safe_a, -1, 1)
    angle = jnp.where(a_norm > 0, jnp.arccos(cos_app), 0)
    status = jnp.select(
        [~finite, ~reachable, ~jnp.any(within)],
        [RobotStatus.NOT_FINITE, RobotStatus.UNREACHABLE, RobotStatus.JOINT_LIMITS],
        RobotStatus.OK,
    ).astype(jnp.int32)
    return JointCommand(joints, jax.lax.stop_gradient(angle), error, status)


@no_type_check
def joint_command(
    robot: Robot,
    target: npt.ArrayLike,
    approach: npt.ArrayLike | None = None,
) -> np.ndarray:
    """Numpy boundary of `inverse_kinematics`: the joints `(4,)`, or a `ValueError`.

    **Arguments:** as `inverse_kinematics` (the target and approach in the world frame).

    **Returns:** numpy `(4,)` `(x, y, pan, tilt)` in mm, mm, rad, rad (float64).

    **Raises:** `ValueError` naming `target` when it is not a finite 3-vector, is out of
    the robot's reach (`RobotStatus.UNREACHABLE`), or is reachable only outside the joint
    limits (`RobotStatus.JOINT_LIMITS`; the message says whether the tilt or the carriage and
    pan are the limit); naming `approach` for a bad approach vector.
    """
    t = np.asarray(target, dtype=np.float64)
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"target must be a finite 3-vector, got {target!r}")
    a = None
    if approach is not None:
        a = np.asarray(approach, dtype=np.float64)
        if a.shape != (3,) or not np.all(np.isfinite(a)):
            raise ValueError(f"approach must be a finite 3-vector, got {approach!r}")
    r = Robot(*(np.asarray(x, np.float64) for x in robot))
    with jax.enable_x64(True):
        out = _ik_jit(r, t, a)
        status = RobotStatus(int(out.status))
        joints = np.asarray(out.joints, np.float64)
    if status == RobotStatus.UNREACHABLE:
        local = r.base_R.T @ (t - r.base_t)
        lo_z, hi_z = float(r.height - r.shank), float(r.height + r.shank)
        raise ValueError(
            f"target {np.round(t, 3).tolist()} is out of the robot's reach: the tip height "
            f"{local[2]:.1f} mm (base frame) is outside [{lo_z:.1f}, {hi_z:.1f}] mm"
        )
    if status == RobotStatus.JOINT_LIMITS:
        local = r.base_R.T @ (t - r.base_t)
        tilt = math.degrees(math.acos(float(np.clip((r.height - local[2]) / r.shank, -1, 1))))
        lo, hi = np.degrees(r.lower[3]), np.degrees(r.upper[3])
        if not (lo <= tilt <= hi or lo <= -tilt <= hi):
            raise ValueError(
                f"target {np.round(t, 3).tolist()} needs a tilt of +-{tilt:.1f} deg, outside "
                f"the tilt limits [{lo:.1f}, {hi:.1f}] deg"
            )
        raise ValueError(
            f"target {np.round(t, 3).tolist()} is reachable only with the carriage or pan "
            f"outside their limits (x in [{r.lower[0]:g}, {r.upper[0]:g}] mm, y in "
            f"[{r.lower[1]:g}, {r.upper[1]:g}] mm, pan in [{np.degrees(r.lower[2]):.1f}, "
            f"{np.degrees(r.upper[2]):.1f}] deg)"
        )
    return joints


_ik_jit = jax.jit(inverse_kinematics)
