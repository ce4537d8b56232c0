"""Shape and texture descriptors of a model's spherical representation.

:func:`describe_grid` turns the resampled grid layers into descriptor vectors invariant to
rotation, translation and scale (:mod:`.descriptors`); :class:`DescriptorSet` carries them with
the conventions that made them.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
