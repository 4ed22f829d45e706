"""One strict JSON encoder for everything benchctl writes or prints.

JSON has no ``NaN`` or ``Infinity``; Python's ``json`` writes them anyway unless told not to,
and most readers (JavaScript, PostgreSQL's ``jsonb``, jq) reject such a file. Every output goes
through :func:`dumps` / :func:`dump`: the value is first made plain (:func:`plain`) — a
non-finite float becomes ``null``, numpy scalars and arrays become numbers and lists, tuples
and sets lists, paths and datetimes strings, dataclasses dicts — then encoded with
``allow_nan=False``, so a value that slips through raises instead of writing bad JSON.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import enum
import json
import math
import sys
from collections.abc import Callable, Mapping
from pathlib import Path, PurePath
from typing import IO, Any

from benchctl.errors import DataError


def plain(obj: Any) -> Any:
    """``obj`` as plain JSON types: dict (str keys), list, str, int, finite float, bool, None.

    Non-finite floats → None; numpy scalars/arrays → Python numbers/lists; tuples and sets →
    lists; paths, datetimes and enums → strings; dataclasses → dicts; anything else → ``str``.
    """
    if obj is None or isinstance(obj, bool | str):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return float(obj) if math.isfinite(obj) else None
    np = sys.modules.get("numpy")  # numpy values exist only once numpy is imported
    if np is not None:
        if isinstance(obj, np.generic):
            return plain(obj.item())
        if isinstance(obj, np.ndarray):
            return _array(np, obj)
    if isinstance(obj, Mapping):
        return {_key(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | set | frozenset):
        items = sorted(obj, key=repr) if isinstance(obj, set | frozenset) else obj
        if all(type(v) is float for v in items):  # a series: no call per value
            return [v if v - v == 0.0 else None for v in items]  # v − v: NaN unless finite
        return [plain(v) for v in items]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return plain(dataclasses.asdict(obj))
    if isinstance(obj, enum.Enum):
        return plain(obj.value)
    if isinstance(obj, _dt.datetime | _dt.date | _dt.time):
        return obj.isoformat()
    if isinstance(obj, PurePath):
        return str(obj)
    return str(obj)


def _array(np: Any, a: Any) -> list[Any]:
    """A numpy array as a list, as :func:`plain` makes each element: a flat numeric array in
    one step (``tolist`` gives Python numbers; its non-finite floats then ``None``), any other
    element by element."""
    if a.ndim == 1 and a.dtype.kind in "biuf":
        out: list[Any] = a.tolist()
        if a.dtype.kind == "f":
            for i in np.flatnonzero(~np.isfinite(a)).tolist():
                out[i] = None
        return out
    return [plain(v) for v in a.tolist()]


def _key(k: Any) -> str:
    if isinstance(k, str):
        return k
    p = plain(k)
    return "null" if p is None else str(p)


def dumps(obj: Any, *, indent: int | None = None, sort_keys: bool = False) -> str:
    """Strict JSON text of ``obj`` (see the module notes); never ``NaN``/``Infinity``."""
    return json.dumps(plain(obj), indent=indent, sort_keys=sort_keys, allow_nan=False)


def dump(obj: Any, fp: IO[str], *, indent: int | None = None) -> None:
    """Write :func:`dumps` of ``obj`` to the text stream ``fp``."""
    fp.write(dumps(obj, indent=indent))


def loads_strict(text: str) -> Any:
    """Parse JSON refusing ``NaN``/``Infinity``/``-Infinity`` (what :func:`dumps` never
    writes): a ``ValueError`` names the constant."""

    def refuse(name: str) -> Any:
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


def load_object(path: str | PurePath, name: str, what: str,
                validate: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
    """A JSON object from ``path`` (or ``path/name`` when it is a folder), parsed strictly and
    checked by ``validate`` (which raises ``DataError``); every failure is a ``DataError``
    naming the file and ``what`` it should have held."""

    p = Path(path)
    if p.is_dir():
        p = p / name
    try:
        data = loads_strict(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise DataError(f"{p}: cannot read the {what}: {e.strerror}") from None
    except ValueError as e:
        raise DataError(f"{p}: not valid JSON: {e}") from None
    if not isinstance(data, dict):
        raise DataError(f"{p}: expected a JSON object, found {type(data).__name__}")
    try:
        validate(data)
    except DataError as e:
        raise DataError(f"{p}: {e}") from None
    return data


__all__ = ["dump", "dumps", "load_object", "loads_strict", "plain"]
