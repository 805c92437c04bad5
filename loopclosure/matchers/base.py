"""The one interface behind which all eight shape matchers of the paper live.

A matcher turns a `Polygon` into a descriptor once (`describe`) and compares
descriptors (`distance`, and the batched `distances` of one query against many).
Distances are >= 0, 0 meaning a perfect match, and always finite: a matcher
never returns NaN (degenerate input gets a defined descriptor or an error at
`describe`).

Batched comparison: `stack` packs many descriptors into one object (usually an
array with a leading database axis) so that `distances` runs without a Python
loop over the database.  Matchers whose descriptors are fixed-length vectors
stack into ``(M, D)`` arrays; others pad or keep the per-entry structure and
vectorise over the database axis in their inner loop.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from loopclosure.polygon import Polygon

Descriptor = Any
Stacked = Any


class Matcher(ABC):
    """A shape matcher: ``describe(polygon)``, ``distance(a, b)``, ``distances(q, stacked)``.

    Class attributes:
        name: the CLI name (``fft``, ``integral``, ``ring``, ``shape-context``,
            ``tangent``, ``scanline``, ``mrm``, ``flirt``).
        rotation_invariant: the distance is unchanged when a polygon is rotated
            about the sensor origin (property-tested).
    """

    name: str = ""
    rotation_invariant: bool = False

    @abstractmethod
    def describe(self, polygon: Polygon) -> Descriptor:
        """Descriptor of one polygon (computed once per keyframe/shape)."""

    @abstractmethod
    def distance(self, a: Descriptor, b: Descriptor) -> float:
        """Dissimilarity of two descriptors, >= 0 and finite."""

    def stack(self, descriptors: Sequence[Descriptor]) -> Stacked:
        """Pack many descriptors for `distances` (default: an ``(M, D)`` array)."""
        return np.stack([np.asarray(d, dtype=float) for d in descriptors])

    def distances(self, query: Descriptor, stacked: Stacked) -> NDArray[np.float64]:
        """``(M,)`` distances of `query` to every stacked descriptor.

        The default is for fixed-length vector descriptors with Euclidean distance;
        matchers with other descriptors override it (vectorised over the database).
        """
        q = np.asarray(query, dtype=float)
        return np.linalg.norm(np.asarray(stacked) - q[None, :], axis=1)

    def pairwise(self, descriptors: Sequence[Descriptor]) -> NDArray[np.float64]:
        """``(M, M)`` matrix of all distances (row i: query i against all)."""
        stacked = self.stack(descriptors)
        return np.stack([self.distances(d, stacked) for d in descriptors])
