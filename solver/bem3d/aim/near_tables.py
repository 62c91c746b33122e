"""Element-pair tables of the near field computed once where two pairs share them.

Drop-ins for :meth:`ElementIntegrals.indexed_tables` (``(tables, index)``, pair p's table is
``tables[index[p]]``, or that of ``tables[-1 - index[p]]`` transposed where the index is
negative) used by the near-field assembly (near_assembly.py):

* :class:`RepeatingTables`: pairs of identical geometry (flat, tilted or 1-D periodic patches)
  share one table;
* :class:`TransposedTables`: the pair (B, A) is the pair (A, B) with test and source swapped, whose
  table is the transpose of (A, B)'s: L_vec[b][a] = L_vec[a][b], L_div the same and
  K[b][a] = K[a][b] (R → −R and t ↔ t' flip the sign of R · (t' × t) twice). Each unordered pair
  is computed once, as (min, max) of its element indices; the tables whose other order a later
  strip of rows will ask for are kept until the strips have passed both elements' lines.

Tables of a pair computed directly in both orders agree to the quadrature tolerance (the singular
rules map the two elements differently); taken from one order, Z is symmetric.
"""

from __future__ import annotations

import numpy as np

from wavebrdf.solver.bem3d.elements import TABLE, ElementIntegrals
from wavebrdf.solver.bem3d.mesh import BEMMesh

__all__ = ["TRANSPOSE", "RepeatingTables", "TransposedTables"]

# the table of (B, A) from that of (A, B): slots (a, b) → (b, a) of L_vec (0–15) and K (17–32)
_SLOTS = np.arange(16).reshape(4, 4).T.ravel()
TRANSPOSE = np.concatenate([_SLOTS, [16], 17 + _SLOTS])



class RepeatingTables:
    """Drop-in for ElementIntegrals.indexed_tables that computes each geometrically distinct pair
    once.

    Two element pairs are identical when the index offset, the shapes (z10, z01, z11) of both
    elements and the height offset Δz00 are equal bit for bit (flat, tilted or 1-D periodic
    patches). Tables are cached across calls, so strips of a large patch share them; a call
    returns the whole cache and each pair's row in it (nothing is copied per pair).
    """

    def __init__(self, integrals: ElementIntegrals):
        self.integrals = integrals
        mesh = integrals.mesh
        _, self.shape_ids = np.unique(mesh.geometry[:, 3:6], axis=0, return_inverse=True)
        self.shape_ids = self.shape_ids.ravel().astype(np.int64)
        self.n_shapes = int(self.shape_ids.max()) + 1
        self.z00 = mesh.geometry[:, 2].copy()
        self.st = mesh.element_st
        self.cells = mesh.cells
        self._keys: dict = {}
        self._store = np.zeros((0, 2, 33), dtype=complex)

    @staticmethod
    def worthwhile(mesh: BEMMesh, fraction: float = 0.25) -> bool:
        return len(np.unique(mesh.geometry[:, 3:6], axis=0)) <= max(1, fraction * mesh.n_elements)

    def _distinct(self, test, source):
        """(keys of the distinct pairs, first pair of each, inverse) — one int64 sort key for the
        offset and shapes, Δz00 compared bit for bit."""
        d = self.st[source] - self.st[test]
        span = 2 * self.cells + 1
        columns = [d[:, 0] + self.cells, d[:, 1] + self.cells, self.shape_ids[test], self.shape_ids[source]]
        if span * span * self.n_shapes**2 < 2**62:  # one int64 key for all but Δz00
            key = ((columns[0] * span + columns[1]) * self.n_shapes + columns[2]) * self.n_shapes + columns[3]
            columns = [key]
        columns.append((self.z00[source] - self.z00[test]).view(np.int64))
        order = np.lexsort(columns[::-1])
        new = np.zeros(len(order), dtype=bool)
        new[:1] = True
        for c in columns:
            sorted_c = c[order]
            new[1:] |= sorted_c[1:] != sorted_c[:-1]
        first = order[new]
        inverse = np.empty(len(order), dtype=np.int64)
        inverse[order] = np.cumsum(new) - 1
        return list(zip(*(c[first].tolist() for c in columns))), first, inverse

    def indexed_tables(self, test, source, wavenumbers, *, scratch: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """As ElementIntegrals.indexed_tables (the cache is returned, so ``scratch`` changes nothing)."""
        test = np.asarray(test, dtype=np.int64)
        source = np.asarray(source, dtype=np.int64)
        keys, first, inverse = self._distinct(test, source)
        index = np.array([self._keys.get(key, -1) for key in keys], dtype=np.int64)
        missing = np.flatnonzero(index < 0)
        if len(missing):
            fresh, order = self.integrals.indexed_tables(test[first[missing]], source[first[missing]], wavenumbers)
            index[missing] = len(self._store) + order
            self._store = np.concatenate([self._store, fresh])
            self._keys.update(zip((keys[u] for u in missing), index[missing].tolist()))
        return self._store, index[inverse]




class TransposedTables:
    """Drop-in for ElementIntegrals.indexed_tables that computes each unordered element pair once
    (module doc): a pair's index is its table's row r in the store, or −1 − r where row r holds
    the table of its other order (assembly.basis_pair_entries reads it transposed). Calls in order
    of increasing rows (the assembly's strips) find the other order of their pairs kept; any order
    of calls gives the same tables, computing more.

    Kept: the tables of each call whose pair has an element on or beyond the call's last test
    line (where a later call's test elements lie), dropped once a call's first test line has
    passed both elements' lines. The store holds the kept tables and the call's fresh ones; it
    is compacted (the kept tables moved to its front) when a call's fresh tables do not fit.
    """

    def __init__(self, integrals: ElementIntegrals):
        self.integrals = integrals
        mesh = integrals.mesh
        self.n_elements = mesh.n_elements
        self.line = mesh.element_st[:, 1].astype(np.int64)
        self._store = np.zeros((0, 2, TABLE), dtype=complex)
        self._used = 0
        self._kept: list[list] = []  # [sorted keys, their rows in the store, last line of their elements]
        self.counts = {"requested": 0, "computed": 0, "compactions": 0}

    def _lookup(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(which kept block holds each key, -1 if none; its position there)."""
        block = np.full(len(keys), -1, dtype=np.int64)
        position = np.zeros(len(keys), dtype=np.int64)
        for i, (kept_keys, _, _) in enumerate(self._kept):
            pos = np.minimum(np.searchsorted(kept_keys, keys), len(kept_keys) - 1)
            hit = (block < 0) & (kept_keys[pos] == keys)
            block[hit], position[hit] = i, pos[hit]
        return block, position

    def _reserve(self, n: int) -> None:
        """Room for n fresh rows after the used ones: the kept rows compacted to the front (into a
        larger store when they and n do not fit)."""
        if self._used + n <= len(self._store):
            return
        self.counts["compactions"] += 1
        rows = [kept[1] for kept in self._kept]
        kept_rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
        need = len(kept_rows) + n
        if need > len(self._store):
            store = np.empty((need + need // 2, 2, TABLE), dtype=complex)
            store[: len(kept_rows)] = self._store[kept_rows]
            self._store = store
        else:
            self._store[: len(kept_rows)] = self._store[kept_rows]  # the fancy read is a copy first
        start = 0
        for kept in self._kept:
            kept[1] = np.arange(start, start + len(kept[1]))
            start += len(kept[1])
        self._used = start

    def indexed_tables(self, test, source, wavenumbers, *, scratch: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """As ElementIntegrals.indexed_tables with the index codes above; the store is reused by
        the next call (``scratch`` changes nothing)."""
        test = np.asarray(test, dtype=np.int64)
        source = np.asarray(source, dtype=np.int64)
        n = len(test)
        if n == 0:
            return np.empty((0, 2, TABLE), dtype=complex), np.empty(0, dtype=np.int64)
        ne, line = self.n_elements, self.line
        first_line, last_line = int(line[test].min()), int(line[test].max())
        self._kept = [kept for kept in self._kept if kept[2] >= first_line]
        low, high = np.minimum(test, source), np.maximum(test, source)
        keys = low * ne + high
        block, position = self._lookup(keys)
        missing = np.flatnonzero(block < 0)
        unique_keys, first, inverse = np.unique(keys[missing], return_index=True, return_inverse=True)
        pairs = missing[first]
        self._reserve(len(pairs))
        rows = np.empty(n, dtype=np.int64)
        for i, (_, kept_rows, _) in enumerate(self._kept):
            hit = block == i
            rows[hit] = kept_rows[position[hit]]
        if len(pairs):
            start = self._used
            fresh = self._store[start : start + len(pairs)]
            _, index = self.integrals.indexed_tables(low[pairs], high[pairs], wavenumbers, out=fresh)
            self._used += len(pairs)
            fresh_rows = start + index  # of the unique pairs
            rows[missing] = fresh_rows[inverse]
            # kept for later calls: pairs with an element on or beyond this call's last test line
            reach = line[high[pairs]].clip(min=line[low[pairs]])
            later = np.flatnonzero(reach >= last_line)
            if len(later):
                self._kept.append([unique_keys[later], fresh_rows[later], int(reach[later].max())])
        self.counts["computed"] += len(pairs)
        self.counts["requested"] += n
        return self._store[: self._used], np.where(test > source, -1 - rows, rows)
