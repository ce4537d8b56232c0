"""Topology repair: any triangle mesh brought to closed genus-0 pieces, the additions recorded.

Its steps, one module each (:mod:`.repair` runs them and says why in this order): :mod:`.analysis`
(what a mesh is), :mod:`.pinch` (pinched vertices split), :mod:`.pieces` (connected pieces, tiny
ones dropped), :mod:`.handles` (handles cut), :mod:`.holes` (boundary loops capped by virtual
patches), :mod:`.patches` (the closed piece as a mesh with its virtual faces labelled);
:mod:`.options` holds :class:`RepairOptions`. :mod:`.model` brings a model as read
(:func:`surfidx.io.read_geometry`) to the parts stored (:func:`repair_model`, :class:`Model`).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
