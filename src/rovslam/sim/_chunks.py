"""An unbounded texel grid generated in square chunks on demand, cached (LRU), thread-safe.

The procedural seabed (albedo) and its relief are both such grids: every texel is a pure
function of its position, a chunk is generated once and kept while it is used, and a
region is assembled from the chunks it overlaps, so chunks join without seams and a
region does not depend on which chunks were generated before.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np


class ChunkedGrid:
    """Base of a chunked texel grid: subclasses implement ``_generate_chunk(ci, cj)``.

    A chunk is ``(C, C) + texel_shape`` of ``dtype`` (C = ``chunk_texels``), holding texels
    ``ci * C .. ci * C + C - 1`` (rows) and likewise for columns.
    """

    def __init__(self, chunk_texels: int, cache_chunks: int, texel_shape: tuple[int, ...], dtype) -> None:
        self._chunk_texels = int(chunk_texels)
        self._cache_chunks = int(cache_chunks)
        self._texel_shape = tuple(texel_shape)
        self._dtype = np.dtype(dtype)
        self._cache: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    def region(self, row0: int, col0: int, n_rows: int, n_cols: int) -> np.ndarray:
        """Texels ``row0 .. row0 + n_rows - 1`` x ``col0 .. col0 + n_cols - 1``, assembled from cached chunks."""
        c = self._chunk_texels
        out = np.empty((n_rows, n_cols) + self._texel_shape, dtype=self._dtype)
        for ci in range(row0 // c, (row0 + n_rows - 1) // c + 1):
            r_lo, r_hi = max(row0, ci * c), min(row0 + n_rows, (ci + 1) * c)
            for cj in range(col0 // c, (col0 + n_cols - 1) // c + 1):
                c_lo, c_hi = max(col0, cj * c), min(col0 + n_cols, (cj + 1) * c)
                chunk = self.chunk(ci, cj)
                out[r_lo - row0 : r_hi - row0, c_lo - col0 : c_hi - col0] = chunk[
                    r_lo - ci * c : r_hi - ci * c, c_lo - cj * c : c_hi - cj * c
                ]
        return out

    def chunk(self, ci: int, cj: int) -> np.ndarray:
        """Chunk ``(ci, cj)``, generated on first use and cached read-only."""
        key = (int(ci), int(cj))
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
            data = self._generate_chunk(*key)
            data.setflags(write=False)
            self._cache[key] = data
            while len(self._cache) > self._cache_chunks:
                self._cache.popitem(last=False)
            return data

    def _generate_chunk(self, ci: int, cj: int) -> np.ndarray:
        raise NotImplementedError
