"""Arrivals: surface points y that rays from receivers reached, each to send the light it
reflects back along its ray to its receiver — the final gather's points (worker.final_gather:
the clamp compensation's near points, the ends of mirror/glass chains from
worker.indirect_caustics)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Arrivals:
    """Surface points y reached by rays, each sending its light back to a receiver: the
    receiver's row ``parent`` gets ``factor`` × the radiance y reflects along -``direction``."""

    position: np.ndarray  # (n, 3)
    ns: np.ndarray  # (n, 3)
    ng: np.ndarray  # (n, 3)
    material: np.ndarray  # (n,) material index (negative: none)
    uv: np.ndarray  # (n, 2)
    t: np.ndarray  # (n,) ray length to y
    direction: np.ndarray  # (n, 3) world direction of the ray that reached y
    segments: np.ndarray  # (n,) eye segments once y is reached
    parent: np.ndarray  # (n,) receiver row
    factor: np.ndarray  # (n, 3) sample weight toward the receiver
    level: np.ndarray  # (n,) compensation level of y (0: y's own clamped light is not compensated)

    def __len__(self) -> int:
        return len(self.parent)

    @staticmethod
    def concat(parts: "list[Arrivals | None]") -> "Arrivals | None":
        """The arrivals of ``parts`` in order (None: there are none)."""
        parts = [p for p in parts if p is not None and len(p)]
        if len(parts) <= 1:
            return parts[0] if parts else None
        return Arrivals(*(np.concatenate([getattr(p, f) for p in parts]) for f in _FIELDS))

    def rows(self, idx: np.ndarray) -> "Arrivals":
        return Arrivals(*(getattr(self, f).take(idx, axis=0) for f in _FIELDS))


_FIELDS = tuple(Arrivals.__dataclass_fields__)
