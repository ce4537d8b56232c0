"""Public names of :mod:`surfidx.topology` (imported on first use, see ``__init__.py``)."""

from .repair import (RepairOptions, TopologyReport, RepairReport, CutCycle, ClosedSurface, Part,
                     Parts, analyse, close_surface, split_parts, closed_mesh, patch_cuts)
from .model import Model, join_surfels, repair_model
