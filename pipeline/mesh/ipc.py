"""ipctk (the contact library: exact crossing tests, distances, the barrier) on one
thread: :func:`ipctk`; and which vertex pairs may collide: :class:`Filter`.

Its broad phase finds candidates in threads, in an order the scheduling decides, and
where several candidates give the same contact (a vertex nearest an edge that two faces
share) which one is kept follows that order: the rose bed's separation differed by 1e-14
from one run to the next. On one thread every list is the same every run."""

from __future__ import annotations

import numpy as np

_SET = False  #: whether ipctk has been put on one thread


def ipctk():
    """The ipctk module, on one thread (set at the first call only: the call is not free),
    its own log to errors only: its CCD warns of every pair that starts within the gap
    ("Initial distance ... returning toi=0!", nine lines for one of hallgeirl's bud
    searches), where the step it gives (0) is what Bloom asked and acts on, logged in
    its own words."""
    global _SET
    import ipctk as module

    if not _SET:
        module.set_num_threads(1)
        module.set_logger_level(module.LoggerLevel.error)
        _SET = True
    return module


class Filter:
    """Which vertex pairs of a collision mesh may collide: never two of one label (of
    each array of ``labels``: a petal, a flower, a spot of a petal left to itself), nor a
    vertex of petal ``a`` with one of petal ``b`` for a pair ``(a, b)`` of ``pairs``
    (``petal``: (V,) each vertex's; petals left through each other as modelled).

    ipctk filters vertex pairs by patches (two vertices of one patch never collide), and
    its filters combine by ``&``. A pair is one patch of its two petals; the pairs are
    coloured so that no petal is in two pairs of one colour (greedy: at most twice the
    most pairs of one petal), and each colour is one patches filter: two petals are kept
    apart exactly where they are not a pair, not where a chain of pairs joins them. The
    arrays the filters read live with this object: keep it as long as the mesh.

    ``selves=False``: a petal in no pair of a colour may collide with itself in that
    colour's filter (each of its vertices a patch of its own), so that only the petals of
    the pairs are kept from themselves (the report's exact test looks at those alone)."""

    def __init__(self, *labels, petal=None, pairs=(), selves: bool = True):
        self.arrays = [np.ascontiguousarray(a, dtype=np.int32) for a in labels]
        pairs = sorted({(min(int(a), int(b)), max(int(a), int(b))) for a, b in pairs})
        if pairs:
            petal = np.asarray(petal, dtype=np.int64)
            count = max(int(petal.max()), max(b for _, b in pairs)) + 1
            used: dict[int, set] = {}
            colours: list[list] = []
            for a, b in pairs:  # (greedy edge colouring: each colour a matching)
                c = 0
                while c in used.setdefault(a, set()) or c in used.setdefault(b, set()):
                    c += 1
                used[a].add(c)
                used[b].add(c)
                if c == len(colours):
                    colours.append([])
                colours[c].append((a, b))
            own = count + np.arange(len(petal))  # (a vertex's patch of its own)
            for matching in colours:
                label = np.arange(count, dtype=np.int64)
                for a, b in matching:
                    label[b] = a
                patch = label[petal]
                if not selves:
                    paired = np.zeros(count, dtype=bool)
                    paired[np.asarray(matching).ravel()] = True
                    patch = np.where(paired[petal], patch, own)
                self.arrays.append(np.ascontiguousarray(patch, dtype=np.int32))
        self._combine()

    def _combine(self) -> None:
        module = ipctk()
        self.filter = None
        for a in self.arrays:
            f = module.make_vertex_patches_filter(a)
            self.filter = f if self.filter is None else self.filter & f

    def also(self, *labels) -> Filter:
        """This filter, and never two vertices of one label of ``labels`` either (the
        pairs' arrays shared, not coloured again)."""
        out = Filter(*labels)
        out.arrays += self.arrays
        out._combine()
        return out

    def apply(self, mesh) -> None:
        """Give the mesh this filter (none: every pair may collide)."""
        if self.filter is not None:
            mesh.can_collide = self.filter
