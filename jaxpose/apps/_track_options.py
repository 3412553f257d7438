"""The tracker's settings (`TrackOptions`, issue #32), each field checked when the options
are made (one table: field, kind, bound), with a `ValueError` naming it."""

from __future__ import annotations

import dataclasses

__all__ = ["TrackOptions"]


@dataclasses.dataclass(frozen=True)
class TrackOptions:
    """The tracker's settings (defaults for a 640 x 480 video).

    **Fields:**
    - `spacing`: pixels between edge samples; `search`: the first search range (+-px);
      `refine_search`: the range of the later rounds; `threshold`: the least derivative
      of an edge (grey levels per pixel); `rounds`: edge measurements per frame at most,
      `settle`: the later rounds stop once one moves the measured points by at most this
      many pixels (the edges measured again from a pose that hardly moved: the same);
      `init_rounds`: the rounds at most on a (re)initialisation frame, from the given
      or recognised pose (recognition's pose can be a degree or two off, and in clutter
      each round moves it only part of the way: on the photo-textured box in clutter,
      1.5 degrees off, three rounds left it 1.3 degrees off, twenty 0.2);
      `init_max_scale`: those fits end with a few rounds whose robust scale is at most
      this (px; None: no such rounds), where clutter beside the edges weighs nothing.
    - `max_corners`: KLT points kept at most; `min_corners`: top the set up below this;
      `erode`: pixels kept away from the faces' borders when detecting;
      `fb_threshold`: forward-backward check (px); `min_correlation`: the least
      normalised cross-correlation of a point's 7 x 7 patch in the last frame and where
      it went (`track_points`; -1: no check): on a plain face the only corners are the
      image noise, drawn afresh on every frame, which the flow cannot follow (such
      points stay put while the object moves, and one detected where an occluder
      came to lie stays on it). On the rendered flat box under the sweeping bar (drawn
      at 8 times, trajectory 2, frame 12) 30 of the 37 points lay 7-16 px from their
      true projections and dragged the fit 1.7 degrees off.
    - `iterations`: Gauss-Newton steps per round; `min_scale`: the least robust scale
      (px) of the residuals (below it, noise-free residuals would reject everything);
      `min_rows`: the fewest measurement rows with a nonzero weight a pose needs (an
      edge match gives one, a point two); with fewer, the frame keeps the previous
      pose, `ok` False.
    - `grazing`: faces seen at more than this angle (degrees) from their normal give
      no edges (`edge_samples`); an edge whose faces change between seen and not
      forgets its contrasts.
    - `choose`: which image edge a sample takes (`moving_edges`'s `choose`).
    - `ratio`: each sample expects the contrast (sign and size, within this factor) the
      match nearest to it on the model had on the last frame (`moving_edges`'s
      `contrast` and `ratio`); None: the sign only.
    - `edges`: `"all"` the edges seen, or `"outline"` only those where the object meets
      what lies behind it (for objects whose faces are alike, where creases hardly
      show).
    - `predict`: the first guess of a frame's pose: `"velocity"` (the last motion
      repeated; with no motion yet, just after a (re)initialisation, the pose the KLT
      points alone give) or `"still"` (the last pose).
    - `recast`: find the KLT points' model points again at every frame's pose (the
      points then measure the motion from frame to frame, and their tracking drift does
      not pile up in the model; the edges hold the pose to the model). False: once,
      when a point is detected.
    - `use_edges`, `use_points`: which measurements take part.
    - `recheck_ratio`: a tracked frame whose edges' RMS residual is over this ratio to
      the usual one (the median of the last tracked frames') is fitted again without
      the contrasts remembered, and the fit with the lower residual kept (where an
      occluder slides along an edge its contrast changes); None: never.
    - `min_support`, `max_rms_ratio`, `min_rms`: when a frame's measurements support
      its pose (otherwise the frame is `"lost"`): at least `min_rows` weighted rows, at
      least `min_support` of the visible edge samples matched with a nonzero weight
      (with edges), and a weighted RMS residual of the edges (of the points without
      edges) at most `max_rms_ratio` times the median of the last tracked frames' (the
      limit never below `min_rms` px).
    - `min_edge_length`: the least length (px) of the model's visible edges matched
      (matched samples times `spacing`) that supports a pose (with edges). A small
      projection of the model fits clutter by chance (on `box.mp4`, recognition from
      the mesh found the box four times too far, fitted to the printed lines of its
      face: 54-81% of its visible samples matched, as at the right pose (67-73%), but
      13-24 samples against 102-122), so a pose measured on less is not supported; the fraction
      alone cannot tell it from the true object, which has as many more samples as it
      is larger. A point measurement with a weight (a KLT point followed from the last
      frame, a textured model's keypoint matched near the prediction; a pose found afresh
      is fitted on edges alone) counts as two samples: it gives two rows, and an occluder
      that leaves fewer edges does not make a frame tracked on the points too a chance
      fit.
    - `exposure`: the fraction of the frame interval the shutter is open: an edge
      sample whose projection moved `v` px along its normal since the last frame is
      looked for as a ramp `exposure * v` wide where the frame shows such ramps
      (`moving_edges`'s `smear`; 0: never). On the rendered benchmark's motion blur
      (the shutter open half the time), at the true poses (the later rounds' search
      of 4 px, three trajectories), 90% of the edge offsets within 0.56-0.79 px against
      0.59-1.19 for the photo-textured box, 0.34-0.39 against 0.44-0.67 for the prism,
      0.30-0.43 against 0.51-0.53 for the flat box; frames without blur unchanged.
    - `reinit_every`, `reinit_wait`: after a lost frame, `reinit` is tried on a frame
      only when at least `reinit_every` frames and `reinit_wait` seconds have passed
      since the end of its last try (the frames between are fitted from the last pose
      held, which is cheap): recognition takes about a second a try, so on a live
      stream a lost track would otherwise hold every frame that long.
    """

    spacing: float = 8.0
    search: int = 12
    refine_search: int = 4
    threshold: float = 8.0
    rounds: int = 3
    settle: float = 0.1
    init_rounds: int = 20
    init_max_scale: float | None = 0.35
    max_corners: int = 200
    min_corners: int = 60
    erode: int = 6
    fb_threshold: float = 1.0
    min_correlation: float = 0.5
    iterations: int = 3
    min_scale: float = 0.3
    min_rows: int = 12
    grazing: float = 90.0
    choose: str = "strongest"
    ratio: float | None = 2.0
    recheck_ratio: float | None = 1.3
    edges: str = "all"
    predict: str = "velocity"
    recast: bool = True
    use_edges: bool = True
    use_points: bool = True
    min_support: float = 0.3
    max_rms_ratio: float = 3.0
    min_rms: float = 1.0
    min_edge_length: float = 320.0
    reinit_every: int = 1
    reinit_wait: float = 0.0
    exposure: float = 0.5

    def __post_init__(self) -> None:
        for name, kind, bound in _CHECKS:
            _check_field(name, getattr(self, name), kind, bound)


#: Each field of `TrackOptions`, how it is checked and against what: `"int"` an int
#: >= bound, `"number"` a number > bound, `"choice"` one of bound, `"bool"` a bool,
#: `"ratio"` None or a number > bound, `"angle"` a number in (0, bound], `"length"` a
#: finite number >= 0, `"correlation"` a number in [-1, 1].
_CHECKS: tuple[tuple[str, str, object], ...] = (
    ("spacing", "number", 0),
    ("search", "int", 2),
    ("refine_search", "int", 2),
    ("threshold", "number", 0),
    ("rounds", "int", 1),
    ("settle", "length", None),
    ("init_rounds", "int", 1),
    ("init_max_scale", "ratio", 0),
    ("max_corners", "int", 1),
    ("min_corners", "int", 0),
    ("erode", "int", 0),
    ("fb_threshold", "number", 0),
    ("min_correlation", "correlation", None),
    ("iterations", "int", 1),
    ("min_scale", "number", 0),
    ("min_rows", "int", 0),
    ("grazing", "angle", 90),
    ("choose", "choice", ("strongest", "nearest")),
    ("ratio", "ratio", 1),
    ("recheck_ratio", "ratio", 1),
    ("edges", "choice", ("all", "outline")),
    ("predict", "choice", ("velocity", "still")),
    ("recast", "bool", None),
    ("use_edges", "bool", None),
    ("use_points", "bool", None),
    ("min_support", "fraction", None),
    ("max_rms_ratio", "number", 1),
    ("min_rms", "number", 0),
    ("min_edge_length", "length", None),
    ("reinit_every", "int", 1),
    ("reinit_wait", "length", None),
    ("exposure", "fraction", None),
)


def _check_field(name: str, value, kind: str, bound) -> None:
    """ValueError naming `options.<name>` when `value` is not of its `kind` within
    `bound` (see `_CHECKS`)."""
    number = not isinstance(value, bool) and isinstance(value, int | float)
    if kind == "int":
        good, want = number and isinstance(value, int) and value >= bound, f"an int >= {bound}"
    elif kind == "number":
        good, want = number and value > bound, f"a number > {bound}"
    elif kind == "choice":
        good, want = value in bound, f"one of {bound}"
    elif kind == "bool":
        good, want = isinstance(value, bool), "a bool"
    elif kind == "correlation":
        good, want = number and -1 <= value <= 1, "a number in [-1, 1]"
    elif kind == "fraction":
        good, want = number and 0 <= value <= 1, "a number in [0, 1]"
    elif kind == "length":
        good, want = number and 0 <= value < float("inf"), "a finite number >= 0"
    elif kind == "ratio":
        good, want = value is None or (number and value > bound), f"> {bound} or None"
    else:  # "angle"
        good, want = number and 0 < value <= bound, f"in (0, {bound}]"
    if not good:
        raise ValueError(f"options.{name} must be {want}, got {value!r}")
