"""The raw bytes of a batch's rows (keys for deduplicating states), shared
by IDS (`heuristic`) and the reward-lock check (`locks`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["row_bytes"]

Array = np.ndarray


def row_bytes(values: Mapping[str, Array], n: int) -> Array:
    """The raw bytes of every row of a batch, as an (n, width) uint8 array."""
    # (the width spelled out: numpy cannot infer -1 for an empty batch)
    parts = [
        np.ascontiguousarray(v).reshape(n, int(np.prod(v.shape[1:]))).view(np.uint8)
        for v in values.values()
    ]
    if not parts:
        return np.zeros((n, 0), dtype=np.uint8)
    return np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]
