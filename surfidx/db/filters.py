"""A small filter language on the stored figures of models, for ``query --where`` and
``ls --where``: clauses ``FIELD OP VALUE`` joined by ``and``.

>>> where_sql("surfels >= 10000 and colour = true and psnr_d1 > 45.5")    # doctest: +SKIP
('m.n_surfels >= ? AND m.has_color = ? AND a.psnr_d1 > ?', [10000, 1, 45.5])

Fields are a fixed list (:data:`FIELDS`) mapped to columns, values are bound as SQL parameters,
so no text of the filter reaches SQL as code.
"""

from __future__ import annotations

import re

from ..errors import InputError

__all__ = ["FIELDS", "OPERATORS", "where_sql"]

#: The fields a filter may name, and the column of ``models m`` / ``assets a`` each reads.
FIELDS = {
    "id": "m.id", "name": "m.name", "surfels": "m.n_surfels", "colour": "m.has_color",
    "color": "m.has_color", "has_color": "m.has_color", "ingested_at": "m.ingested_at",
    "bytes": "a.bytes", "bits_per_surfel": "a.bits_per_surfel", "psnr_d1": "a.psnr_d1",
    "psnr_d2": "a.psnr_d2", "psnr_y": "a.psnr_y", "version": "m.version",
    "source": "m.source", "source_bytes": "m.source_bytes", "surfidx_version": "m.surfidx_version",
}

#: The comparison operators, as written in a filter and as SQL.
OPERATORS = {"=": "=", "==": "=", "!=": "!=", "<": "<", "<=": "<=", ">": ">", ">=": ">=",
             "like": "LIKE"}

_CLAUSE = re.compile(r"""\s*(?P<field>[A-Za-z_][A-Za-z0-9_]*)\s*
                         (?P<op>==|!=|<=|>=|=|<|>|(?i:like)\b)\s*
                         (?P<value>'[^']*'|"[^"]*"|[^\s'"]+)\s*""", re.X)


def _value(text: str):
    if text[:1] in "'\"":
        return text[1:-1]
    low = text.lower()
    if low in ("true", "false"):
        return int(low == "true")
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def where_sql(text: str) -> tuple:
    """The SQL condition and its parameters of a filter.

    Parameters
    ----------
    text : str
        ``FIELD OP VALUE [and FIELD OP VALUE ...]``: a field of :data:`FIELDS`, an operator of
        :data:`OPERATORS`, a number, ``true``/``false`` or a quoted string (an ISO date for
        ``ingested_at``, a ``LIKE`` pattern for ``name like``).

    Returns
    -------
    sql : str
        Conditions on ``models m`` and ``assets a``, joined by ``AND``.
    args : list
        Their parameters, in order.

    Raises
    ------
    InputError
        A clause that does not parse, an unknown field, an empty filter.
    """
    parts = re.split(r"\s+and\s+", str(text).strip(), flags=re.I)
    if parts == [""]:
        raise InputError("the filter is empty; write FIELD OP VALUE, e.g. 'surfels > 10000'")
    sql, args = [], []
    for part in parts:
        m = _CLAUSE.fullmatch(part)
        if m is None:
            raise InputError(f"cannot read the filter clause {part!r}; write FIELD OP VALUE "
                             f"with OP one of {', '.join(OPERATORS)} (clauses joined by 'and')")
        field = m["field"].lower()
        if field not in FIELDS:
            raise InputError(f"unknown filter field {m['field']!r}; use one of "
                             + ", ".join(sorted(FIELDS)))
        sql.append(f"{FIELDS[field]} {OPERATORS[m['op'].lower()]} ?")
        args.append(_value(m["value"]))
    return " AND ".join(sql), args
