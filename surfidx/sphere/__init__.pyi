"""Public names of :mod:`surfidx.sphere` (imported on first use, see ``__init__.py``)."""

from .mapping import parameterize, SphericalMap, Stage
from .options import MapOptions, METHODS, STAGES
from .quality import count_folds, area_distortion, sparse_sampling, landmark_stress, SPARSE_QUANTILE
