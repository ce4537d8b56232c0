"""Public names of :mod:`surfidx.db` (imported on first use, see ``__init__.py``)."""

from .catalog import Catalog as Catalog
from .search import SearchIndex as SearchIndex
from .filters import where_sql as where_sql, FIELDS as FIELDS
