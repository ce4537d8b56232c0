"""The store: models, streams, descriptors and thumbnails in one SQLite file.

:class:`Database` (:mod:`.database`) is the one entry point: ingest, query by example, get an
asset at any rate, manage models. Below it, :mod:`.catalog` holds the tables (schema,
migrations, transactions), :mod:`.search` the exact descriptor search and :mod:`.ann` the
approximate index for large archives.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
