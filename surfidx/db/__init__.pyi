"""Public names of :mod:`surfidx.db` (imported on first use, see ``__init__.py``)."""

from .database import Database as Database
from .search import SearchIndex as SearchIndex
