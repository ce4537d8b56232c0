"""Public names of :mod:`surfidx.describe` (imported on first use, see ``__init__.py``)."""

from .descriptors import (DescriptorSet, describe_grid, descriptor_distance, descriptor_params,
                          DEFAULT_LMAX, SH_NORMALIZATION, DESCRIPTOR_VERSION)
from .options import DescribeOptions
