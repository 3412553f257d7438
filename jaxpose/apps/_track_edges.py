"""The tracker's edge measurements (issue #32): the moving edges along a pose's visible
model edges, each sample held to its own edge's territory, as image lines in the
pinhole frame.

**Territories.** Where two projected model edges run side by side a few pixels apart (a
face seen nearly edge-on: a sliver between a crease and the outline), the stronger image
edge answers both samples' searches, and a pose that hides the sliver fits its outline
to the crease. Each sample therefore takes only a match nearer its own edge than any
other model edge running alongside it (within `ALONGSIDE` degrees) predicted to cross
its search line (`TERRITORY`: half the way to the nearest such crossing on either side),
as though each image edge belonged to the nearest projected edge. Measured on the
rendered flat box under the partial occlusion (trajectory 2, frame 12, drawn at 8 times;
Intel Xeon with AVX-512): a crease beside such a sliver matched the outline 0.5-3.8 px
away, and the fit from the true pose settled 7.4 degrees off; with the territories, 0.3
degree. Edges meeting at a corner are not held apart (they cross each other's normals
only near the corner, where the start of a fit a few pixels off needs the reach: held
apart there too, the photo-textured box in clutter, recognised 1-2 degrees off, was
fitted 1.9 degrees off on its first frame instead of 0.24).
"""

from __future__ import annotations

import numpy as np

from ..features._moving_edges import moving_edges
from ..geometry import undistort_pixels
from ._track_contrasts import _expected
from ._visibility import MeshGeometry, edge_samples, project

__all__: list[str] = []

#: A sample's match lies at most this fraction of the way to the nearest other model edge
#: running alongside it predicted to cross its search line, on either side (one half: the
#: image edge goes to the nearer projected edge).
TERRITORY = 0.5
#: Other model edges within this angle (degrees, projected) of a sample's edge run
#: alongside it and bound its territory.
ALONGSIDE = 35.0


def _undistort(pixels: np.ndarray, K: np.ndarray, dist) -> np.ndarray:
    """Pixels of the pinhole camera `K` from distorted ones (`undistort_pixels`;
    unchanged without `dist`, and an empty set as given)."""
    return pixels if len(pixels) == 0 else np.asarray(undistort_pixels(pixels, K, dist))


def _crossings(geo: MeshGeometry, K, dist, R, t, samples) -> tuple[np.ndarray, np.ndarray]:
    """`(offsets, alongside)`, both `(S, M)`: where each of the `M` model edges seen
    (those with a visible sample) crosses each sample's normal line, as an offset along
    the normal (px; NaN where the line misses the edge's projected segment, and for the
    sample's own edge), and whether that edge runs within `ALONGSIDE` degrees of the
    sample's own."""
    seen = np.unique(samples.edge[samples.visible])
    ends = np.asarray(geo.model.edges)[seen]
    px = project(geo.model.vertices @ R.T + t, K, dist)
    a, b = px[ends[:, 0]], px[ends[:, 1]]  # (M, 2): straight between the vertices' pixels
    n = samples.normals / np.maximum(np.linalg.norm(samples.normals, axis=1, keepdims=True), 1e-12)
    # p + s n = a + l (b - a), solved for (s, l) by Cramer's rule
    ab, rhs = (b - a)[None, :, :], a[None, :, :] - samples.pixels[:, None, :]
    det = ab[..., 0] * n[:, None, 1] - n[:, None, 0] * ab[..., 1]
    solvable = np.abs(det) > 1e-9
    det = np.where(solvable, det, 1.0)
    s = (ab[..., 0] * rhs[..., 1] - rhs[..., 0] * ab[..., 1]) / det
    along = (n[:, None, 0] * rhs[..., 1] - n[:, None, 1] * rhs[..., 0]) / det
    crossed = solvable & (along >= 0) & (along <= 1) & (seen[None, :] != samples.edge[:, None])
    # (|n . (b - a)| / |b - a|: the sine of the angle between the other edge and the own)
    dot = n[:, None, 0] * ab[..., 0] + n[:, None, 1] * ab[..., 1]
    sine = np.abs(dot) / np.maximum(np.linalg.norm(b - a, axis=1), 1e-12)[None, :]
    return np.where(crossed, s, np.nan), crossed & (sine < np.sin(np.radians(ALONGSIDE)))


def _territories(offsets: np.ndarray, alongside: np.ndarray) -> np.ndarray:
    """`(S, 2)`: the least and greatest offset each sample's match may take
    (`TERRITORY` of the way to the nearest crossing of an edge alongside, below and
    above; -inf, inf where none)."""
    below = np.where(alongside & (offsets < 0), offsets, -np.inf).max(axis=1, initial=-np.inf)
    above = np.where(alongside & (offsets > 0), offsets, np.inf).min(axis=1, initial=np.inf)
    return TERRITORY * np.column_stack([below, above])


def _edge_measurements(grey, geo, K, dist, R, t, size, search, contrasts, options, last=None):
    """The edge matches of the pose `(R, t)` within `search` px: `(model points (E, 3),
    image lines (E, 3) of the pinhole frame, keys (E,) where each lies on the model,
    signed contrasts (E,), the number of visible samples wanted)`; `last`, the last
    frame's pose, sets how far each edge smeared (`options.exposure`)."""
    samples = edge_samples(geo, K, dist, R, t, spacing=options.spacing, image_size=size,
                           margin=search + 2.0, grazing=options.grazing)  # fmt: skip
    smear = None  # (each sample's motion along its normal since the last frame held)
    if last is not None and options.exposure > 0:
        before = project(samples.points @ last[0].T + last[1], K, dist)
        smear = options.exposure * np.abs(((samples.pixels - before) * samples.normals).sum(1))
    ends = np.asarray(geo.model.edges)[samples.edge]
    a, b = geo.model.vertices[ends[:, 0]], geo.model.vertices[ends[:, 1]]
    frac = ((samples.points - a) * (b - a)).sum(axis=1) / np.maximum(
        ((b - a) ** 2).sum(axis=1), 1e-300
    )
    keys = samples.edge + np.clip(frac, 0.0, 0.999)
    offsets, alongside = _crossings(geo, K, dist, R, t, samples)
    # (with the smear, other image edges looked for as far as the first round's search,
    # those of the model's other edges not counted)
    found = moving_edges(grey, samples.pixels, samples.normals, search=search,
                         threshold=options.threshold, mask=samples.visible,
                         contrast=_expected(contrasts, keys), choose=options.choose,
                         ratio=options.ratio, smear=smear, reach=options.search,
                         others=None if smear is None else offsets,
                         limits=_territories(offsets, alongside))  # fmt: skip
    wanted = samples.visible & (samples.outline | (options.edges == "all"))
    keep = found.valid & wanted
    if found.rival is not None:  # a crease merged with another edge (blurred frames): out
        keep &= samples.outline | ~found.rival
    q = found.matched[keep]
    ahead = q + np.column_stack([found.normals[keep, 1], -found.normals[keep, 0]])
    qu, au = _undistort(q, K, dist), _undistort(ahead, K, dist)
    d = au - qu
    n = np.column_stack([-d[:, 1], d[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    lines = np.column_stack([n, -(n * qu).sum(axis=1)])
    return samples.points[keep], lines, keys[keep], found.strength[keep], int(wanted.sum())
