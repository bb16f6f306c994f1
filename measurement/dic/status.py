"""Status flags of a DIC point: why a point has a number, or why it is NaN."""
from __future__ import annotations

from enum import IntEnum


class Status(IntEnum):
    """Outcome of one point of interest.

    Only ``CONVERGED`` points carry numbers; every other status leaves u, v and the shape parameters NaN.
    """

    CONVERGED = 0           #: increment norm fell below the tolerance
    MAX_ITERATIONS = 1      #: iteration cap reached before the increment fell below the tolerance
    DIVERGED = 2            #: the warp became singular, left every sensible range, or the deformed subset is flat
    OUT_OF_IMAGE = 3        #: the reference or deformed subset (with its interpolation support) leaves the image
    LOW_TEXTURE = 4         #: too little contrast / a singular Hessian, or (auto ROI) fails :func:`.roi.texture_mask`
    LOW_CORRELATION = 5     #: converged, but ZNCC is below the acceptance threshold
    NOT_REACHED = 6         #: not connected to any seed by reliability-guided propagation
    INVALID_IMAGE = 7       #: NaN or masked pixels in the subset
    NO_INITIAL_GUESS = 8    #: the initial-guess search found no acceptable match
    INCONSISTENT = 9        #: converged, but disagrees with its neighbours (auto ROI, :func:`.roi.consistency_flags`)


# Plain ints for numba kernels.
CONVERGED = int(Status.CONVERGED)
MAX_ITERATIONS = int(Status.MAX_ITERATIONS)
DIVERGED = int(Status.DIVERGED)
OUT_OF_IMAGE = int(Status.OUT_OF_IMAGE)
LOW_TEXTURE = int(Status.LOW_TEXTURE)
LOW_CORRELATION = int(Status.LOW_CORRELATION)
NOT_REACHED = int(Status.NOT_REACHED)
INVALID_IMAGE = int(Status.INVALID_IMAGE)
NO_INITIAL_GUESS = int(Status.NO_INITIAL_GUESS)
INCONSISTENT = int(Status.INCONSISTENT)
