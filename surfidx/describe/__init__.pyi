"""Public names of :mod:`surfidx.describe` (imported on first use, see ``__init__.py``)."""

from .descriptors import (DescriptorSet as DescriptorSet, describe_grid as describe_grid,
                          descriptor_distance as descriptor_distance,
                          descriptor_params as descriptor_params, DEFAULT_LMAX as DEFAULT_LMAX,
                          SH_NORMALIZATION as SH_NORMALIZATION,
                          DESCRIPTOR_VERSION as DESCRIPTOR_VERSION)
from .options import DescribeOptions as DescribeOptions
from .distance import (weighted_l2 as weighted_l2, DEFAULT_SHAPE_WEIGHT as DEFAULT_SHAPE_WEIGHT,
                       DEFAULT_KINDS as DEFAULT_KINDS)
from .partial import (partial_l2 as partial_l2, is_partial as is_partial,
                      PARTIAL_SHARE as PARTIAL_SHARE,
                      PARTIAL_PART_WEIGHTS as PARTIAL_PART_WEIGHTS, part_slices as part_slices)
from .views import (partial_view_l2 as partial_view_l2, model_views as model_views,
                    scan_views as scan_views, scan_direction as scan_direction,
                    expand_by_first as expand_by_first, EXPANSION_WEIGHT as EXPANSION_WEIGHT)
