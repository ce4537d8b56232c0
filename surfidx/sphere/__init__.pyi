"""Public names of :mod:`surfidx.sphere` (imported on first use, see ``__init__.py``)."""

from .mapping import parameterize as parameterize, SphericalMap as SphericalMap, Stage as Stage
from .options import (MapOptions as MapOptions, METHODS as METHODS, STAGES as STAGES,
                      MAP_VERSION as MAP_VERSION)
from .quality import (count_folds as count_folds, area_distortion as area_distortion,
                      sparse_sampling as sparse_sampling, landmark_stress as landmark_stress,
                      SPARSE_QUANTILE as SPARSE_QUANTILE)
