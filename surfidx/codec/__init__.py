"""The codec: a spherical map's surfels to one embedded bitstream and back.

Its steps, one module each, in the order a stream is made: :mod:`.resample` (x, y, z, r, g, b on
the icosahedral grid), :mod:`.colorgrid` (colour on its own finer grid, from the texture, and
the order of geometry and colour bit planes), :mod:`.klt` (decorrelation of the layers), :mod:`.wavelets` (lifted
butterfly wavelets), :mod:`.density` (the surfel-density weight field), :mod:`.zerotree` and
:mod:`.entropy` (bit-plane coding), :mod:`.mask` and :mod:`.restore` (the repaired surface's
virtual patches), :mod:`.container` (the file format); :mod:`.encoder` runs them
(:class:`Encoder`, :func:`encode`, :func:`decode`).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
