"""Public names of :mod:`surfidx.topology` (imported on first use, see ``__init__.py``)."""

from .repair import (RepairOptions as RepairOptions, TopologyReport as TopologyReport,
                     RepairReport as RepairReport, CutCycle as CutCycle,
                     ClosedSurface as ClosedSurface, Part as Part, Parts as Parts,
                     analyse as analyse, close_surface as close_surface, split_parts as split_parts,
                     closed_mesh as closed_mesh, patch_cuts as patch_cuts)
from .model import (Model as Model, join_surfels as join_surfels, repair_model as repair_model,
                    read_model as read_model)
