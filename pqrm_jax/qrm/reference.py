"""One-triple-at-a-time reference of the QRM update (M§VI.B steps 1–9, literally).

Used as the oracle for the batched fixed point (tests) and as the "one triple at a time"
baseline of the benchmark: each measured relation is intersected into the map on its own and
propagated with a worklist (unary pseudo-measurements and compositions through every fourth
landmark, in both argument positions), in plain Python over integer bitmasks. Same
algorithm, same fixed point (the greatest one below the measurements), no batching.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .spec import QRMSpec


class ReferenceMap:
    """Map of capacity ``n`` stored as a dict-free (n, n, n) array of Python-int masks."""

    def __init__(self, spec: QRMSpec, n: int):
        self.spec = spec
        self.n = n
        self.rel = np.full((n, n, n), spec.full, dtype=np.int64)
        self.inv = [int(x) for x in spec.inverse]
        self.left = [int(x) for x in spec.left]
        self.right = [int(x) for x in spec.right]
        self.ct = [[int(x) for x in row] for row in spec.compose]
        self.q = spec.num_states
        self._row = {}  # cache: (i, S2) -> COMPOSE({i}, S2)

    def _lift(self, tab, s):
        out = 0
        i = 0
        while s:
            if s & 1:
                out |= tab[i]
            s >>= 1
            i += 1
        return out

    def compose(self, s1: int, s2: int) -> int:
        out = 0
        i = 0
        while s1:
            if s1 & 1:
                key = (i, s2)
                r = self._row.get(key)
                if r is None:
                    r = self._lift(self.ct[i], s2)
                    self._row[key] = r
                out |= r
            s1 >>= 1
            i += 1
        return out

    def update(self, triple, mask: int) -> bool:
        """Intersect one measured relation ``XY:Z`` and propagate.

        False if inconsistent (then the map is left as it was).
        """
        backup = self.rel.copy()
        a, b, c = (int(x) for x in triple)
        new = int(self.rel[a, b, c]) & int(mask)
        if new == self.rel[a, b, c]:
            return True
        self.rel[a, b, c] = new
        if not self._propagate(deque([(a, b, c)])):
            self.rel = backup
            return False
        return True

    def _set(self, t, mask, work) -> bool:
        old = int(self.rel[t])
        new = old & mask
        if new != old:
            self.rel[t] = new
            work.append(t)
        return new != 0

    def _propagate(self, work) -> bool:
        n = self.n
        while work:
            a, b, c = work.popleft()
            s = int(self.rel[a, b, c])
            if s == 0:
                return False
            ok = (self._set((b, a, c), self._lift(self.inv, s), work)
                  and self._set((b, c, a), self._lift(self.left, s), work)
                  and self._set((c, a, b), self._lift(self.right, s), work))
            if not ok:
                return False
            for d in range(n):
                if d in (a, b, c):
                    continue
                # (a,b,c) as first argument: AB:C, BC:D -> AB:D
                if not self._set((a, b, d), self.compose(s, int(self.rel[b, c, d])), work):
                    return False
                # (a,b,c) as second argument: DA:B, AB:C -> DA:C
                if not self._set((d, a, c), self.compose(int(self.rel[d, a, b]), s), work):
                    return False
        return True
