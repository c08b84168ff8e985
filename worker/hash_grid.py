"""The hashed grid of the paper's §4.1 for fixed-radius caustic-photon queries.

Photons are binned into a regular grid of cell size 2r; only occupied cells are stored
(a sorted array of collision-free integer cell keys with the photon ranges behind them),
so a query ball of radius r touches exactly the 2x2x2 cells around its centre and is
answered with 8 binary-search lookups. Building (worker.kernels.hash_grid_build) and the query
(worker.kernels.photon_query) are compiled; numpy serves the rank-mapped key space of huge extents.
"""
from __future__ import annotations

import numpy as np

from .kernels import hash_grid_build, photon_query

# Cell coordinates beyond this would overflow int64 arithmetic (and floats lost integer
# precision long before); photons there are refused, queries there simply find nothing.
_CELL_LIMIT = float(2 ** 60)
_RADIX_LIMIT = 2 ** 62
# Key spaces up to this many cells keep an occupancy bitmap (at most 2 MiB a set) that lets a
# query skip the binary search for empty cells.
_BITMAP_CELLS = 2 ** 24

KERNELS = ("constant", "cone", "epanechnikov")


def _cells(x: np.ndarray, inv_cell: float) -> np.ndarray:
    """Integer cell coordinates floor(x / (2r)); non-finite or far rows become a sentinel."""
    c = np.floor(x * inv_cell)
    bad = ~np.all(np.isfinite(c) & (np.abs(c) < _CELL_LIMIT), axis=1)
    c[bad] = 0.0
    out = c.astype(np.int64)
    out[bad] = np.iinfo(np.int64).min
    return out


SPAN_MARGIN = 1e-9  # relative widening of a query's cell span (see HashGrid._query_numpy)


class HashGrid:
    """Photons in a hashed grid of cell size 2 * radius."""

    def __init__(self, points: np.ndarray, radius: float) -> None:
        radius = float(radius)
        if not (np.isfinite(radius) and radius > 0):
            raise ValueError(f"radius must be finite and > 0, got {radius}")
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        self.points = pts
        self.radius = radius
        self.cell_size = 2.0 * radius
        self._inv = 1.0 / self.cell_size
        n = len(pts)
        if n == 0:
            self._keys = np.empty(0, np.int64)
            self._starts = np.empty(0, np.int64)
            self._counts = np.empty(0, np.int64)
            self._order = np.empty(0, np.int64)
            self._occupied = np.empty(0, np.uint8)
            return
        # The usual case in one compiled call; a huge key space (tiny radius, far-apart photons)
        # is ranked per axis below.
        status, origin, ext, order, keys, starts, counts, occupied = hash_grid_build.build(
            pts, self._inv, _CELL_LIMIT, _RADIX_LIMIT, _BITMAP_CELLS)
        if status == hash_grid_build.NON_FINITE:
            raise ValueError("photon positions must be finite")
        if status == hash_grid_build.OVERFLOW:
            raise ValueError("photon positions too large for this radius (cell index overflow)")
        if status == hash_grid_build.OK:
            self._axes, self._origin, self._ext = None, origin, ext
            self._order, self._keys, self._starts, self._counts, self._occupied = order, keys, starts, counts, occupied
            return
        self._build_numpy(pts)

    def _build_numpy(self, pts: np.ndarray) -> None:
        """The build in vectorized numpy, any key space (huge ones ranked per axis; the compiled
        build's oracle in the tests)."""
        cells = _cells(pts, self._inv)
        if np.any(cells[:, 0] == np.iinfo(np.int64).min):
            raise ValueError("photon positions too large for this radius (cell index overflow)")
        self._build_key_space(cells)
        keys = self._key(cells)[0]
        # Sorting by key groups photons of one cell together; np.unique gives the ranges.
        self._order = np.argsort(keys, kind="stable")
        self._keys, self._starts, self._counts = np.unique(
            keys[self._order], return_index=True, return_counts=True)
        self._occupied = np.empty(0, np.uint8)
        cells_total = float(np.prod(self._ext.astype(np.float64))) if self._axes is None else np.inf
        if cells_total <= _BITMAP_CELLS:
            self._occupied = np.zeros((int(cells_total) + 7) // 8, np.uint8)
            np.bitwise_or.at(self._occupied, self._keys >> 3, (1 << (self._keys & 7)).astype(np.uint8))

    # -- collision-free cell keys ------------------------------------------------------
    def _build_key_space(self, cells: np.ndarray) -> None:
        """Choose a key map that cannot collide: mixed radix over the occupied bounding box,
        or, when that box has >= 2^62 cells (huge extents, tiny radius), over the ranks of
        the occupied coordinates per axis (at most N values each, and pairs ranked again so
        the product stays below N^2)."""
        self._origin = cells.min(axis=0)
        ext = cells.max(axis=0) - self._origin + 1
        if int(ext[0]) * int(ext[1]) * int(ext[2]) < _RADIX_LIMIT:
            self._axes = None
            self._ext = ext
            return
        self._axes = [np.unique(cells[:, a]) for a in range(3)]
        rx, ry = (np.searchsorted(self._axes[a], cells[:, a]) for a in (0, 1))
        self._xy = np.unique(rx * len(self._axes[1]) + ry)

    def _key(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(keys, valid): valid is False where the cell cannot hold a photon."""
        valid = cells[:, 0] != np.iinfo(np.int64).min
        if self._axes is None:
            rel = cells - self._origin
            valid &= np.all((rel >= 0) & (rel < self._ext), axis=1)
            ey, ez = int(self._ext[1]), int(self._ext[2])
            keys = (rel[:, 0] * ey + rel[:, 1]) * ez + rel[:, 2]
            return np.where(valid, keys, -1), valid
        ranks = []
        for a in range(3):
            u = self._axes[a]
            r = np.minimum(np.searchsorted(u, cells[:, a]), len(u) - 1)
            valid &= u[r] == cells[:, a]
            ranks.append(r)
        xy = ranks[0] * len(self._axes[1]) + ranks[1]
        rxy = np.minimum(np.searchsorted(self._xy, xy), len(self._xy) - 1)
        valid &= self._xy[rxy] == xy
        keys = rxy * len(self._axes[2]) + ranks[2]
        return np.where(valid, keys, -1), valid

    # -- queries -----------------------------------------------------------------------
    def query(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All (photon, query) pairs with |photon - x[query]| <= r.

        Returns (photon_index, query_index) int64 arrays, grouped by ascending query index.
        Reads the 2x2x2 cells with lower corner floor(x/(2r) - 0.5) per query.
        """
        q = np.ascontiguousarray(x, dtype=np.float64).reshape(-1, 3)
        empty = (np.empty(0, np.int64), np.empty(0, np.int64))
        if len(q) == 0 or len(self._keys) == 0:
            return empty
        r = self.radius
        if self._axes is None:  # the usual mixed-radix key space: the compiled query
            return photon_query.query(q, r, r * (1.0 + SPAN_MARGIN), self._inv, self._origin,
                                      np.asarray(self._ext, np.int64),
                                      self._keys, self._starts, self._counts, self._order, self.points,
                                      self._occupied)
        return self._query_numpy(q)

    def _query_numpy(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """query() in vectorized numpy: any key space (the kernels' oracle in the tests)."""
        empty = (np.empty(0, np.int64), np.empty(0, np.int64))
        if len(q) == 0 or len(self._keys) == 0:
            return empty
        r = self.radius
        # floor(x/(2r) - 0.5) written as floor((x - r)/(2r)): the same cell in exact
        # arithmetic, and monotone rounding makes it never above a photon's floor(p/(2r))
        # for p >= x - r, so no photon of the ball is lost at a cell border. The span is
        # widened by SPAN_MARGIN of r: a photon just outside the ball whose rounded distance
        # is r (x - r - 4e-22 at r = 0.25) is inside by the distance test, so its cell is read.
        w = r * (1.0 + SPAN_MARGIN)
        lo = _cells(q - w, self._inv)
        hi = _cells(q + w, self._inv)
        ok = lo[:, 0] != np.iinfo(np.int64).min
        span = np.where(ok[:, None], hi - lo, 1)
        # The ball is exactly one cell wide, so hi - lo is 1 (or 0); rounding can make it 2
        # for balls touching borders on both sides: those rare queries read a third layer.
        offsets = [(dx, dy, dz) for dx in range(3) for dy in range(3) for dz in range(3)]
        base = np.flatnonzero(ok)
        wide = np.flatnonzero(ok & np.any(span >= 2, axis=1))
        qi_parts, start_parts, count_parts = [], [], []
        for off in offsets:
            if max(off) < 2:
                sel = base
            else:
                if len(wide) == 0:
                    continue
                need = np.all([span[wide, a] >= 2 for a in range(3) if off[a] == 2], axis=0)
                sel = wide[need]
                if len(sel) == 0:
                    continue
            keys, valid = self._key(lo[sel] + np.asarray(off, np.int64))
            pos = np.minimum(np.searchsorted(self._keys, keys), len(self._keys) - 1)
            hit = valid & (self._keys[pos] == keys)
            qi_parts.append(sel[hit])
            start_parts.append(self._starts[pos[hit]])
            count_parts.append(self._counts[pos[hit]])
        qi = np.concatenate(qi_parts)
        starts = np.concatenate(start_parts)
        counts = np.concatenate(count_parts)
        total = int(counts.sum())
        if total == 0:
            return empty
        # Expand each (start, count) range: position = start + (running index - range offset).
        first = np.cumsum(counts) - counts
        pos = np.repeat(starts - first, counts) + np.arange(total)
        pidx = self._order[pos]
        qidx = np.repeat(qi, counts)
        d = self.points[pidx] - q[qidx]
        keep = np.einsum("ij,ij->i", d, d) <= r * r
        pidx, qidx = pidx[keep], qidx[keep]
        order = np.argsort(qidx, kind="stable")
        return pidx[order], qidx[order]

    def gather(self, x: np.ndarray, normals: np.ndarray | None, photon_power: np.ndarray,
               photon_dirs: np.ndarray | None = None, kernel: str = "constant",
               photon_normals: np.ndarray | None = None) -> np.ndarray:
        """Density estimate of photon power (irradiance) at each query point.

        x: (Q, 3) positions; normals: (Q, 3) query normals (needed when photon_normals or
        photon_dirs are given). photon_power: (N,) or (N, C). Optional same-side tests:
        photon_normals (N, 3) counts a photon only if dot(photon normal, query normal) > 0
        (drops photons of the other side of a thin wall); photon_dirs (N, 3), the photon's
        propagation direction, counts it only if dot(dir, query normal) < 0 (it arrived from
        the side the normal faces).

        kernel (each integrates to 1 over the disc of radius r, as the estimate needs):
          "constant"     1 / (pi r^2)                          (the paper's fixed radius)
          "cone"         (1 - d/r) / ((1 - 2/3) pi r^2)         (Jensen's cone filter, k=1)
          "epanechnikov" 2 (1 - d^2/r^2) / (pi r^2)
        Returns (Q,) + photon_power.shape[1:] float64.
        """
        if kernel not in KERNELS:
            raise ValueError(f"unknown kernel {kernel!r}; choose one of {KERNELS}")
        q = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        power = np.asarray(photon_power, dtype=np.float64)
        if len(power) != len(self.points):
            raise ValueError(f"photon_power has {len(power)} rows for {len(self.points)} photons")
        out = np.zeros((len(q),) + power.shape[1:], dtype=np.float64)
        pidx, qidx = self.query(q)
        if len(pidx) == 0:
            return out
        keep = np.ones(len(pidx), dtype=bool)
        if photon_normals is not None or photon_dirs is not None:
            if normals is None:
                raise ValueError("query normals are needed for the same-side test")
            qn = np.asarray(normals, dtype=np.float64).reshape(-1, 3)[qidx]
            if photon_normals is not None:
                pn = np.asarray(photon_normals, dtype=np.float64).reshape(-1, 3)[pidx]
                keep &= np.einsum("ij,ij->i", pn, qn) > 0
            if photon_dirs is not None:
                pd = np.asarray(photon_dirs, dtype=np.float64).reshape(-1, 3)[pidx]
                keep &= np.einsum("ij,ij->i", pd, qn) < 0
            pidx, qidx = pidx[keep], qidx[keep]
        r2 = self.radius * self.radius
        area = np.pi * r2
        if kernel == "constant":
            w = np.full(len(pidx), 1.0 / area)
        else:
            d = self.points[pidx] - q[qidx]
            d2 = np.einsum("ij,ij->i", d, d)
            if kernel == "cone":
                w = (1.0 - np.sqrt(d2) / self.radius) * (3.0 / area)
            else:
                w = (1.0 - d2 / r2) * (2.0 / area)
        # bincount sums per query far faster than np.add.at; one pass per channel.
        flat = power.reshape(len(power), -1)
        res = out.reshape(len(q), -1)
        for c in range(flat.shape[1]):
            res[:, c] = np.bincount(qidx, weights=flat[pidx, c] * w, minlength=len(q))
        return out

    def __len__(self) -> int:
        return len(self.points)
