"""Points-of-interest files (``rovslam navigate --poi POI.csv``), validated where they enter.

A UTF-8 CSV with a header and one row per point, visited in the file's order::

    name,x_m,y_m,hold_s          name,landmark_id
    rock,0.40,-0.20,15           start,0
    crack,-0.35,0.10,            big stone,12

``x_m, y_m``: the point in the map frame (metres; x north, y east, the origin where the dive
started); ``landmark_id``: a landmark of the online map (its position is read from the map as
it is when the vehicle goes there); ``hold_s`` (optional): how long to keep station there
(empty: the ``--hold-s`` of the command). A file may have both ``x_m, y_m`` and ``landmark_id``
columns; each row then fills one or the other. Any bad row is a :class:`~rovslam.errors.PoiFormatError`
naming the file, line and column.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rovslam.core import Goal
from rovslam.errors import PoiFormatError
from rovslam.io.text import float_cell, read_csv_table

__all__ = ["MAX_POI_DISTANCE_M", "read_poi_csv"]

MAX_POI_DISTANCE_M = 1000.0  # farther from the start than this is a typing error (units?)


def read_poi_csv(path: str | Path) -> list[Goal]:
    """The points of ``path`` as :class:`~rovslam.nav.guidance.Goal` records, in the file's order."""
    p = Path(path)
    header, rows = read_csv_table(p, ("name",), PoiFormatError)
    has_xy = "x_m" in header and "y_m" in header
    if not has_xy and "landmark_id" not in header:
        if "x_m" in header or "y_m" in header:
            raise PoiFormatError(
                f"{p}: the header has only one of x_m, y_m; a point needs both (name,x_m,y_m[,hold_s])."
            )
        raise PoiFormatError(
            f"{p}: the header needs x_m,y_m or landmark_id beside name "
            "(name,x_m,y_m[,hold_s] or name,landmark_id[,hold_s])."
        )
    goals: list[Goal] = []
    seen: dict[str, int] = {}
    for line, row in rows:
        where = f"{p}, line {line}"
        goals.append(_row_goal(row, where, has_xy, "landmark_id" in header))
        name = goals[-1].name
        if name in seen:
            raise PoiFormatError(
                f"{where}, column 'name': {name!r} is already the name of the point on line "
                f"{seen[name]}; give each point its own name."
            )
        seen[name] = line
    if not goals:
        raise PoiFormatError(f"{p}: no point of interest (only the header); add one row per point.")
    return goals


def _row_goal(row: dict[str, str], where: str, has_xy: bool, has_landmark: bool) -> Goal:
    name = (row.get("name") or "").strip()
    if not name:
        raise PoiFormatError(f"{where}, column 'name': empty; every point needs a name.")
    lm_text = (row.get("landmark_id") or "").strip() if has_landmark else ""
    xy_given = has_xy and any((row.get(k) or "").strip() for k in ("x_m", "y_m"))
    if lm_text and xy_given:
        raise PoiFormatError(f"{where}: both x_m,y_m and landmark_id are given; a point is one or the other.")
    hold = float_cell(row, "hold_s", where, optional=True, error=PoiFormatError) if "hold_s" in row else None
    if hold is not None and hold < 0:
        raise PoiFormatError(f"{where}, column 'hold_s': {hold:g} s is negative; give a time >= 0 (or leave it empty).")
    if lm_text:
        try:
            lm = int(lm_text)
        except ValueError:
            raise PoiFormatError(f"{where}, column 'landmark_id': not a whole number: {lm_text!r}.") from None
        if lm < 0:
            raise PoiFormatError(f"{where}, column 'landmark_id': {lm} is negative; landmark ids start at 0.")
        return Goal(name, None, hold_s=hold, landmark_id=lm)
    if not has_xy:
        raise PoiFormatError(f"{where}, column 'landmark_id': empty; it needs a landmark id.")
    x = float_cell(row, "x_m", where, error=PoiFormatError)
    y = float_cell(row, "y_m", where, error=PoiFormatError)
    for key, v in (("x_m", x), ("y_m", y)):
        if abs(v) > MAX_POI_DISTANCE_M:  # type: ignore[arg-type]
            raise PoiFormatError(
                f"{where}, column '{key}': {v:g} m is more than {MAX_POI_DISTANCE_M:g} m from the "
                "start; coordinates are metres in the map frame."
            )
    return Goal(name, np.array([x, y]), hold_s=hold)
