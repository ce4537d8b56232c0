"""Public names of :mod:`surfidx.db` (imported on first use, see ``__init__.py``)."""

from .database import Database as Database, QueryExample as QueryExample
from .search import SearchIndex as SearchIndex
