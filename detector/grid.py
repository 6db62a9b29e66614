"""The scan as an unrolled grid: rows = azimuth around the sensor's forward axis, columns = beam
angle away from forward.

A plane at servo angle ``alpha`` holds two half-planes ("areas I and II" in the thesis): beams
with ``beta > 0`` look towards roll ``alpha`` and beams with ``beta < 0`` towards
``alpha + pi``. Stacking the half-planes by roll gives a ``(2P, K)`` grid whose neighbours are
neighbours on the pipe wall, which the detectors use to find connected regions (openings,
outlines) with :func:`label_regions`. Column ``k`` holds ``|beta| = k``-th smallest non-negative
beam angle; the forward beam (``beta = 0``) appears in both half-planes. Rows wrap around
(the last row neighbours the first) when the planes cover the half circle evenly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy import ndimage

from detector.scan import Scan


@dataclass(frozen=True, eq=False)
class ScanGrid:
    """Index maps from the unrolled grid to the scan arrays.

    Attributes:
        plane: (2P, K) plane index of each cell.
        beam: (2P, K) beam index of each cell (-1 where the half-plane has no such beam).
        roll: (2P,) roll angle of each row, radians in [0, 2 pi).
        wraps: whether the first and the last row are neighbours.
    """

    plane: NDArray[np.intp]
    beam: NDArray[np.intp]
    roll: NDArray[np.float64]
    wraps: bool

    @property
    def shape(self) -> tuple[int, int]:
        return self.plane.shape

    def take(self, values: NDArray, fill: float | bool = np.nan) -> NDArray:
        """Scatter a (P, B) per-beam array onto the grid; missing cells get ``fill``."""
        out = values[self.plane, np.maximum(self.beam, 0)]
        if np.any(self.beam < 0):
            out = np.where(self.beam < 0, fill, out)
        return out


def build_grid(scan: Scan) -> ScanGrid:
    """The unrolled grid of ``scan`` (see module docstring)."""
    beta = scan.beam_angles
    pos = np.flatnonzero(beta >= -1e-12)
    neg = np.flatnonzero(beta <= 1e-12)
    pos = pos[np.argsort(beta[pos], kind="stable")]
    neg = neg[np.argsort(-beta[neg], kind="stable")]
    k = max(pos.size, neg.size)
    beams_pos = np.full(k, -1, dtype=np.intp)
    beams_neg = np.full(k, -1, dtype=np.intp)
    beams_pos[: pos.size] = pos
    beams_neg[: neg.size] = neg
    n_p = scan.n_planes
    alpha = np.mod(scan.plane_angles, 2.0 * math.pi)
    roll = np.concatenate([alpha, np.mod(alpha + math.pi, 2.0 * math.pi)])
    plane = np.concatenate([np.arange(n_p), np.arange(n_p)])
    beam = np.concatenate([np.tile(beams_pos, (n_p, 1)), np.tile(beams_neg, (n_p, 1))])
    order = np.argsort(roll, kind="stable")
    roll = roll[order]
    plane_grid = np.repeat(plane[order][:, None], k, axis=1)
    beam = beam[order]
    wraps = False
    if roll.size >= 3:
        steps = np.diff(roll)
        closing = roll[0] + 2.0 * math.pi - roll[-1]
        med = float(np.median(steps))
        wraps = bool(med > 0 and closing <= 1.5 * med + 1e-9)
    return ScanGrid(plane_grid, beam, roll, wraps)


def label_regions(mask: NDArray[np.bool_], wraps: bool) -> tuple[NDArray[np.int32], int]:
    """Connected regions (8-neighbourhood) of a grid mask, joined across the row seam when the
    grid wraps (and has at least three rows). Returns ``(labels, n)`` with labels 1..n,
    numbered in the raster order of each region's first cell, and 0 for background (compiled:
    :func:`label_grid`)."""
    m = np.ascontiguousarray(mask, dtype=np.bool_)
    if m.ndim != 2:
        raise ValueError(f"mask must be a 2D grid, got shape {m.shape}")
    labels, n = label_grid(m, bool(wraps) and m.shape[0] >= 3)
    return labels, int(n)


@njit(cache=True)
def find_root(parent: NDArray[np.int64], x: int) -> int:
    """The root of ``x`` in the union-find forest ``parent`` (halving the path)."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@njit(cache=True)
def _union(parent: NDArray[np.int64], a: int, b: int) -> None:
    """Join the sets of ``a`` and ``b`` (the smaller root becomes the parent: a set's root is
    its first member)."""
    ra, rb = find_root(parent, a), find_root(parent, b)
    if ra < rb:
        parent[rb] = ra
    elif rb < ra:
        parent[ra] = rb


@njit(cache=True)
def join_neighbours(
    cells: NDArray[np.int64], parent: NDArray[np.int64], g: int, k: int, wraps: bool
) -> None:
    """Join (union-find ``parent``, one entry per cell) the set cells ``cells`` (ascending flat
    indices of a ``(g, k)`` grid) that are 8-neighbours: each with those before it in raster
    order, left and the three above it in the row above; the first row also with the last one
    when the grid ``wraps``. Pointers into the ascending cells find them (``q`` in the row
    above, ``q_last`` in the last row), so the work is in the set cells, not the grid."""
    n = cells.size
    last_row = g - 1 if wraps else -1
    q = 0
    q_last = 0
    for j in range(n):
        c = cells[j]
        row = c // k
        col = c - row * k
        if col > 0 and j > 0 and cells[j - 1] == c - 1:
            _union(parent, j, j - 1)
        above = row - 1 if row > 0 else last_row
        if above < 0:
            continue
        lo = above * k + max(col - 1, 0)
        hi = above * k + min(col + 1, k - 1)
        t = q if row > 0 else q_last
        while t < n and cells[t] < lo:
            t += 1
        if row > 0:
            q = t
        else:
            q_last = t
        while t < n and cells[t] <= hi:
            _union(parent, j, t)
            t += 1


@njit(cache=True)
def label_grid(mask: NDArray[np.bool_], wraps: bool) -> tuple[NDArray[np.int32], int]:
    """The labelling of :func:`label_regions`, compiled (callable from other compiled code):
    union-find over the set cells alone (:func:`join_neighbours`); ``wraps``: the first and
    last rows are neighbours."""
    g, k = mask.shape
    n = 0
    for r in range(g):
        for c in range(k):
            if mask[r, c]:
                n += 1
    cells = np.empty(n, dtype=np.int64)
    j = 0
    for r in range(g):
        for c in range(k):
            if mask[r, c]:
                cells[j] = r * k + c
                j += 1
    parent = np.arange(n)
    join_neighbours(cells, parent, g, k, wraps and g > 1)
    # (labels 1..n in the raster order of each region's first cell: its root)
    labels = np.zeros((g, k), dtype=np.int32)
    number = np.zeros(n, dtype=np.int32)
    n_lab = 0
    for j in range(n):
        root = find_root(parent, j)
        if number[root] == 0:
            n_lab += 1
            number[root] = n_lab
        c = cells[j]
        labels[c // k, c - (c // k) * k] = number[root]
    return labels, n_lab


def region_stats(labels: NDArray[np.int32], n_lab: int) -> tuple[NDArray, NDArray]:
    """(cells, grid rows spanned) of each label 0..n_lab of a labelled grid (both (n_lab + 1,)
    integers; 0 for the background, label 0)."""
    return label_stats(np.ascontiguousarray(labels, dtype=np.int32), int(n_lab))


@njit(cache=True)
def label_stats(labels: NDArray[np.int32], n_lab: int) -> tuple[NDArray, NDArray]:
    """:func:`region_stats` compiled (callable from other compiled code)."""
    g, k = labels.shape
    counts = np.zeros(n_lab + 1, dtype=np.int64)
    rows = np.zeros(n_lab + 1, dtype=np.int64)
    last_row = np.full(n_lab + 1, -1, dtype=np.int64)
    for r in range(g):
        for c in range(k):
            lab = labels[r, c]
            if lab == 0:
                continue
            counts[lab] += 1
            if last_row[lab] != r:
                last_row[lab] = r
                rows[lab] += 1
    return counts, rows


def dilate(mask: NDArray[np.bool_], wraps: bool, iterations: int = 1) -> NDArray[np.bool_]:
    """8-neighbourhood dilation of a grid mask, wrapping rows when the grid wraps."""
    if iterations <= 0:
        return mask.copy()
    if wraps:
        pad = np.concatenate([mask[-iterations:], mask, mask[:iterations]], axis=0)
        out = ndimage.binary_dilation(pad, np.ones((3, 3), dtype=bool), iterations=iterations)
        return out[iterations:-iterations]
    return ndimage.binary_dilation(mask, np.ones((3, 3), dtype=bool), iterations=iterations)
