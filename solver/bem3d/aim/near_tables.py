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

Tables of a pair computed directly in both orders agree to 5e-13 relative or better (measured on
PoCL for touching pairs of aluminium, whose singular rules map the two elements by other
transforms; regular pairs to 1e-15); taken from one order, Z is exactly symmetric.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.bem3d.elements import TABLE, ElementIntegrals
from wavebrdf.solver.bem3d.mesh import BEMMesh

__all__ = ["REPEATING_STORE_BYTES", "TRANSPOSE", "RepeatingTables", "TransposedTables"]

# bound on RepeatingTables' kept tables (past it a call keeps only the tables it uses): on faceted
# relief Δz00 differs across the facets' edges, so few pairs repeat and an unbounded cache grows
# with the patch (docs/aim.md, "Faceted relief")
REPEATING_STORE_BYTES = 256 * 2**20

# the table of (B, A) from that of (A, B): slots (a, b) → (b, a) of L_vec (0–15) and K (17–32)
_SLOTS = np.arange(16).reshape(4, 4).T.ravel()
TRANSPOSE = np.concatenate([_SLOTS, [16], 17 + _SLOTS])


class RepeatingTables:
    """Drop-in for ElementIntegrals.indexed_tables that computes each geometrically distinct pair
    once.

    Two element pairs are identical when the index offset, the shapes (z10, z01, z11) of both
    elements and the height offset Δz00 are equal bit for bit (flat, tilted or 1-D periodic
    patches). Tables are cached across calls, so strips of a large patch share them, up to
    ``max_bytes`` (beyond it a call keeps only the tables it uses); a call returns the whole
    cache and each pair's row in it (nothing is copied per pair).
    """

    def __init__(self, integrals: ElementIntegrals, max_bytes: int = REPEATING_STORE_BYTES):
        self.integrals = integrals
        self.max_bytes = max_bytes
        self.scratch_pair_map, self.release_pair_map = integrals.scratch_pair_map, integrals.release_pair_map
        mesh = integrals.mesh
        _, self.shape_ids = np.unique(mesh.geometry[:, 3:6], axis=0, return_inverse=True)
        self.shape_ids = self.shape_ids.ravel().astype(np.int64)
        self.n_shapes = int(self.shape_ids.max()) + 1
        self.z00 = mesh.geometry[:, 2].copy()
        self.st = mesh.element_st
        self.cells = mesh.cells
        self._keys: dict = {}
        self._store = np.zeros((0, 2, TABLE), dtype=complex)

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

    def _keep_only(self, keys: list, index: np.ndarray) -> None:
        """Shrink the cache to the rows ``index`` (of ``keys``; −1: not cached) uses, renumbering
        ``index`` in place."""
        cached = index >= 0
        used = np.unique(index[cached])
        renumber = np.full(len(self._store), -1, dtype=np.int64)
        renumber[used] = np.arange(len(used))
        self._store = self._store[used]
        index[cached] = renumber[index[cached]]
        self._keys = {key: int(row) for key, row in zip(keys, index.tolist()) if row >= 0}

    def indexed_tables(self, test, source, wavenumbers, *, scratch: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """As ElementIntegrals.indexed_tables (the cache is returned, so ``scratch`` changes nothing)."""
        test = np.asarray(test, dtype=np.int64)
        source = np.asarray(source, dtype=np.int64)
        keys, first, inverse = self._distinct(test, source)
        index = np.array([self._keys.get(key, -1) for key in keys], dtype=np.int64)
        missing = np.flatnonzero(index < 0)
        row_bytes = 2 * TABLE * np.dtype(complex).itemsize
        if len(missing) and (len(self._store) + len(missing)) * row_bytes > self.max_bytes:
            self._keep_only(keys, index)
        if len(missing):
            fresh, order = self.integrals.indexed_tables(test[first[missing]], source[first[missing]], wavenumbers)
            index[missing] = len(self._store) + order
            self._store = np.concatenate([self._store, fresh]) if len(self._store) else fresh
            self._keys.update(zip((keys[u] for u in missing), index[missing].tolist()))
        return self._store, index[inverse]


@dataclass
class _KeptBlock:
    """Tables one call kept for later calls: their pairs' sorted keys, their store rows (within
    the ``count`` rows of the ring from ``start``), and the last line of their elements."""

    keys: np.ndarray
    rows: np.ndarray
    start: int
    last_line: int

    @property
    def count(self) -> int:
        return len(self.keys)


class TransposedTables:
    """Drop-in for ElementIntegrals.indexed_tables that computes each unordered element pair once
    (module doc): a pair's index is its table's row r in the store, or −1 − r where row r holds
    the table of its other order (assembly.basis_pair_entries reads it transposed). Calls in order
    of increasing rows (the assembly's strips) find the other order of their pairs kept; any order
    of calls gives the same tables, computing more.

    Kept: the tables of each call whose pair has an element on or beyond the call's last test
    line (where a later call's test elements lie), dropped once a call's first test line has
    passed both elements' lines. The store is one array (one device buffer for the gather): a
    ring of kept blocks, each computed into its place, then the scratch rows of the call's other
    fresh tables. Nothing is copied except when the store grows.
    """

    def __init__(self, integrals: ElementIntegrals):
        self.integrals = integrals
        self.scratch_pair_map, self.release_pair_map = integrals.scratch_pair_map, integrals.release_pair_map
        mesh = integrals.mesh
        self.n_elements = mesh.n_elements
        self.line = mesh.element_st[:, 1].astype(np.int64)
        self._store = np.zeros((0, 2, TABLE), dtype=complex)
        self._ring = 0  # rows of the ring of kept blocks; the scratch rows follow
        self._head = 0  # where the ring's next block starts
        self._kept: list[_KeptBlock] = []
        self.counts = {"requested": 0, "computed": 0, "growths": 0, "wraps": 0}

    def store_rows(self, pairs: int) -> tuple[int, int]:
        """(rows the store a call with ``pairs`` element pairs returns may have at most, of which
        those the kept blocks hold before it): the ring, grown for the pairs if they do not fit,
        and the pairs' scratch rows."""
        live = sum(block.count for block in self._kept)
        return max(self._ring, (live + pairs) * 3 // 2) + pairs, live

    def _lookup(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the kept block holding each key, −1 if none; its position in that block). Positions
        stay valid when the store grows (the blocks move, their order and contents do not)."""
        block = np.full(len(keys), -1, dtype=np.int64)
        position = np.zeros(len(keys), dtype=np.int64)
        for i, kept in enumerate(self._kept):
            pos = np.minimum(np.searchsorted(kept.keys, keys), kept.count - 1)
            hit = (block < 0) & (kept.keys[pos] == keys)
            block[hit], position[hit] = i, pos[hit]
        return block, position

    def _place(self, kept: int, scratch: int) -> int:
        """First row of ``kept`` consecutive ring rows clear of the live blocks, with ``scratch``
        scratch rows (the store grows when they do not fit)."""
        start = self._head if self._head + kept <= self._ring else 0

        def clear(start):
            return start + kept <= self._ring and all(start + kept <= b.start or b.start + b.count <= start
                                                      for b in self._kept)

        if not clear(start) or scratch > len(self._store) - self._ring:
            self._grow(kept, scratch)
            start = self._head
        elif start < self._head:
            self.counts["wraps"] += 1
        self._head = start + kept
        return start

    def _grow(self, kept: int, scratch: int) -> None:
        """A larger store: the live blocks moved to the front of a ring with room for them, the new
        block and half as much again, then the scratch rows."""
        self.counts["growths"] += 1
        live = sum(b.count for b in self._kept)
        ring = max(self._ring, (live + kept) * 3 // 2)
        scratch = max(len(self._store) - self._ring, scratch + scratch // 4)
        store = np.empty((ring + scratch, 2, TABLE), dtype=complex)
        row = 0
        for block in self._kept:
            n = block.count
            store[row : row + n] = self._store[block.start : block.start + n]
            block.rows += row - block.start
            block.start = row
            row += n
        self._store, self._ring, self._head = store, ring, row

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
        self._kept = [block for block in self._kept if block.last_line >= first_line]
        low, high = np.minimum(test, source), np.maximum(test, source)
        keys = low * ne + high
        block, position = self._lookup(keys)
        missing = np.flatnonzero(block < 0)
        unique_keys, first, inverse = np.unique(keys[missing], return_index=True, return_inverse=True)
        pairs = missing[first]
        # kept for later calls: pairs with an element on or beyond this call's last test line
        reach = line[high[pairs]].clip(min=line[low[pairs]])
        later = reach >= last_line
        kept, other = np.flatnonzero(later), np.flatnonzero(~later)
        start = self._place(len(kept), len(other))  # may move the kept blocks: their rows are read after it
        rows = np.empty(n, dtype=np.int64)
        for i, kept_block in enumerate(self._kept):
            hit = block == i
            rows[hit] = kept_block.rows[position[hit]]
        fresh_rows = np.empty(len(pairs), dtype=np.int64)
        for chosen, at in ((kept, start), (other, self._ring)):
            if len(chosen):
                out = self._store[at : at + len(chosen)]
                _, index = self.integrals.indexed_tables(low[pairs[chosen]], high[pairs[chosen]], wavenumbers, out=out)
                fresh_rows[chosen] = at + index
        if len(kept):
            self._kept.append(_KeptBlock(unique_keys[kept], fresh_rows[kept], start, int(reach[kept].max())))
        rows[missing] = fresh_rows[inverse]
        self.counts["computed"] += len(pairs)
        self.counts["requested"] += n
        used = max(self._ring + len(other), 1)
        return self._store[:used], np.where(test > source, -1 - rows, rows)
