"""A model's up axis: the coordinate axis that points up in the frame its file uses.

File formats keep different conventions: meshes (OBJ, glTF/GLB, PLY, OFF, STL) are +Y up, as
glTF's specification and most modelling tools have it, and scans (point clouds from terrestrial
and mobile scanners) are +Z up, the scanner's vertical. The readers' table
(:mod:`surfidx.io.registry`) says which format keeps which; a user may override it
(``ProcessOptions.up``, ``surfidx ingest --up``). Renderers turn the model so that this axis
shows upwards (:func:`up_rotation`).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["UP_AXES", "MESH_UP", "SCANNER_UP", "check_up", "up_rotation"]

#: Rotations taking each up axis to +y (rows: where the model's x, y and z go). The front view
#: then looks along -z of the rotated frame: along -z for +y up, along +y for +z up (the camera
#: on -y, +x to the right, as Blender's front view).
_ROTATIONS = {
    "+y": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "+z": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
    "+x": ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    "-y": ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "-z": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    "-x": ((0, 1, 0), (-1, 0, 0), (0, 0, 1)),
}

#: The up axes a model may have, in their one spelling (a sign and a lower-case letter).
UP_AXES = tuple(_ROTATIONS)

#: Up axis of the mesh formats (OBJ, glTF/GLB, PLY, OFF, STL).
MESH_UP = "+y"

#: Up axis of the scanners' point-cloud formats (XYZ, PTS, PCD): the scanner's vertical.
SCANNER_UP = "+z"


def check_up(value) -> str:
    """An up axis in its one spelling.

    Parameters
    ----------
    value : str
        ``"+y"``, ``"-z"``...; the sign may be left out for a positive axis (``"z"``) and the
        letter may be upper-case (``"+Z"``), as users type it.

    Returns
    -------
    str
        One of :data:`UP_AXES`.

    Raises
    ------
    InputError
        For anything else.
    """
    text = value.strip().lower() if isinstance(value, str) else None
    if text is not None and len(text) == 1:
        text = "+" + text
    if text not in _ROTATIONS:
        raise InputError(f"unknown up axis {value!r}; use one of {', '.join(UP_AXES)} (the "
                         "model axis that points up; the sign may be left out for +)")
    return text


def up_rotation(up: str) -> np.ndarray:
    """The rotation that turns a model so its up axis points along +y.

    Parameters
    ----------
    up : str
        An up axis (:func:`check_up` spellings).

    Returns
    -------
    (3, 3) float64
        A proper rotation ``R``: ``R @ p`` is the point ``p`` in the turned frame.

    Raises
    ------
    InputError
        For an unknown up axis.
    """
    return np.array(_ROTATIONS[check_up(up)], float)
