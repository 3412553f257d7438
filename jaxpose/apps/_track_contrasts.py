"""The tracker's memory of its edges' contrasts (issue #32): the signed contrast each edge
match had on the last frame held, keyed by where it lies on the model, and which of them
a fit from another pose may expect (an edge whose faces changed between seen and not
changes its contrast)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._visibility import MeshGeometry, facing


class _Contrasts(NamedTuple):
    """The signed contrast each edge match had, keyed by `edge + fraction along it`
    (sorted), for the next frame's samples at the same places on the model."""

    keys: np.ndarray
    values: np.ndarray


_NO_CONTRAST = _Contrasts(np.zeros(0), np.zeros(0))


def _expected(table: _Contrasts, keys: np.ndarray, reach: float = 0.05) -> np.ndarray:
    """The contrast of the nearest entry on the same edge within `reach` (a fraction of
    the edge's length) of each key, 0 where none."""
    if len(table.keys) == 0 or len(keys) == 0:
        return np.zeros(len(keys))
    i = np.searchsorted(table.keys, keys).clip(1, len(table.keys) - 1)
    lo, hi = table.keys[i - 1], table.keys[i]
    j = np.where(np.abs(keys - lo) <= np.abs(hi - keys), i - 1, i)
    near = table.keys[j]
    same = (np.floor(near) == np.floor(keys)) & (np.abs(near - keys) <= reach)
    return np.where(same, table.values[j], 0.0)


def _sides(geo: MeshGeometry, R, t, grazing: float) -> np.ndarray:
    """`(E, 2)` bool: whether each edge's two faces are seen at pose `(R, t)` (False
    where an edge has no second face)."""
    seen = facing(geo, R, t, grazing)
    return np.where(geo.edge_faces >= 0, seen[np.maximum(geo.edge_faces, 0)], False)


def _remembered(memory, geo: MeshGeometry, R, t, grazing: float) -> _Contrasts:
    """The contrasts of the last frame held (`memory`: its table and its faces seen) that
    a fit from `(R, t)` may expect (`_unchanged`); none without a frame held."""
    if memory is None:
        return _NO_CONTRAST
    return _unchanged(memory[0], memory[1], _sides(geo, R, t, grazing))


def _unchanged(table: _Contrasts, old_sides, sides: np.ndarray) -> _Contrasts:
    """The entries of `table` (contrasts measured where the faces were seen as
    `old_sides`) on edges whose faces are seen as they were: an edge whose faces changed
    between seen and not changes its contrast."""
    if old_sides is None or len(table.keys) == 0:
        return table
    changed = np.any(sides != old_sides, axis=1)
    same = ~changed[np.floor(table.keys).astype(int)]
    return _Contrasts(table.keys[same], table.values[same])
