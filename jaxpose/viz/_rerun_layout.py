"""The layouts (rerun blueprints) a recording opens on, and the 3D eye that frames the
object in them."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    import rerun.blueprint as rrb

__all__ = ["pointing_blueprint", "rerun_blueprint"]


def rerun_blueprint(
    *,
    pose_error: bool = True,
    eye: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> rrb.Blueprint:
    """The layout a recording opens on: the 3D scene and the camera image side by side,
    the per-triplet error series (px, and the pose error when `pose_error`) and the
    triplet log below, the time panel on the `triplet` timeline.

    `eye`: optionally the 3D view's initial `(position, look_target, up)` in the world
    (`log_solution` and `log_experiment` set one that frames the object)."""
    import rerun.blueprint as rrb

    series = [rrb.TimeSeriesView(origin="metrics/error_px", name="Eq. 8 error per triplet (px)")]
    if pose_error:
        series.append(
            rrb.TimeSeriesView(origin="metrics/pose_error_mm", name="pose error per triplet")
        )
    return rrb.Blueprint(
        rrb.Vertical(
            _scene_and_image(eye),
            rrb.Horizontal(
                *series,
                rrb.Tabs(
                    rrb.TextLogView(origin="triplets", name="triplets"),
                    rrb.TextDocumentView(origin="summary", name="summary"),
                ),
            ),
            row_shares=[3, 2],
        ),
        rrb.TimePanel(timeline="triplet"),
        collapse_panels=True,
    )


def _scene_and_image(eye):
    """The 3D scene (its eye from `_eye_controls`) beside the camera image."""
    import rerun.blueprint as rrb

    return rrb.Horizontal(
        rrb.Spatial3DView(origin="world", name="scene", eye_controls=_eye_controls(eye)),
        rrb.Spatial2DView(origin="world/camera/image", name="image"),
    )


def _eye_controls(eye):
    """rerun's 3D eye from `(position, look_target, up)`, or `None`."""
    import rerun.blueprint as rrb

    if eye is None:
        return None
    position, target, up = (np.asarray(v, dtype=np.float64) for v in eye)
    return rrb.EyeControls3D(position=position, look_target=target, eye_up=up)


def pointing_blueprint(
    *, eye: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
) -> rrb.Blueprint:
    """The layout of a pointing recording (`log_pointing`): the 3D scene (object, ray,
    point, robot) and the camera image side by side, the summary below."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            _scene_and_image(eye),
            rrb.TextDocumentView(origin="summary", name="summary"),
            row_shares=[4, 1],
        ),
        collapse_panels=True,
    )


def _frame_object(
    rec, centre, world_points, up, *, pose_error: bool = False, make_blueprint=None
) -> None:
    """Send the default layout (`make_blueprint(eye=...)`, default `rerun_blueprint`)
    with the 3D eye looking at the object from the side of the line of sight, above it,
    so that the object, the rays and the camera all show."""
    target = np.mean(world_points, axis=0)
    towards_camera = centre - target
    distance = float(np.linalg.norm(towards_camera))
    if not np.isfinite(distance) or distance == 0:
        return
    back = towards_camera / distance
    side = np.cross(up, back)
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.zeros(3)
    direction = 0.75 * back + 0.5 * side + 0.45 * up
    # About 2.5 object sizes away (the object fills a good part of the view), at most
    # 0.8 of the camera's distance.
    size = float(np.max(np.linalg.norm(world_points - target, axis=1)))
    reach = min(2.5 * 2 * size, 0.8 * distance) if size > 0 else 0.5 * distance
    position = target + reach * direction / np.linalg.norm(direction)
    eye = (position, target, up)
    if make_blueprint is None:
        blueprint = rerun_blueprint(pose_error=pose_error, eye=eye)
    else:
        blueprint = make_blueprint(eye=eye)
    rec.send_blueprint(blueprint, make_active=True, make_default=True)
