"""Public names of :mod:`surfidx.db` (imported on first use, see ``__init__.py``)."""

from .database import Database, QueryExample
from .search import SearchIndex
