"""What a database failure is (``classify``): the kind an ``ArchiveError`` carries — refused,
locked, timed out, read-only, denied, unreachable or failed — from PostgreSQL's SQLSTATE where
there is one, else the driver's exception; and its cause as one line, secrets hidden.
"""

from __future__ import annotations

import sqlite3

from sqlalchemy import exc as sa

from benchctl.redact import redact_text

# errors raised while a record's values are bound, not by the database (an integer out of
# SQLite's range, a lone surrogate that cannot be encoded): the record is refused
RECORD_ERRORS: tuple[type[Exception], ...] = (UnicodeError, OverflowError, ValueError, TypeError)


_PG_KINDS = {"55P03": "locked", "40P01": "locked", "57014": "timed out",
             "25006": "read-only", "42501": "read-only"}


_PG_CLASSES = {"22": "refused", "23": "refused", "54": "refused", "28": "denied",
               "08": "unreachable", "57": "unreachable", "3D": "unreachable"}


def classify(e: BaseException) -> str:
    """What a database failure is, as it is: ``refused`` (the database will not take this
    record: a value it cannot store — a NUL character, a number out of range — or a broken
    constraint; storing it again fails again), ``locked`` (another session holds what the
    statement needs: lock timeout, deadlock, a busy SQLite file), ``timed out`` (the statement
    timeout), ``read-only`` (a read-only database, file or transaction, or no right to write),
    ``denied`` (the login: password, role), ``unreachable`` (no connection, or it was lost)
    or ``failed`` (anything else). From PostgreSQL's SQLSTATE where there is one, else
    the driver's exception class and message."""
    orig = getattr(e, "orig", None) if isinstance(e, sa.DBAPIError) else None
    inner = orig if orig is not None else e
    if isinstance(inner, RECORD_ERRORS) and not isinstance(inner, sa.SQLAlchemyError):
        return "refused"
    state = getattr(inner, "sqlstate", None)
    if isinstance(state, str) and len(state) == 5:
        if state in _PG_KINDS:
            return _PG_KINDS[state]
        if state[:2] in _PG_CLASSES:
            return _PG_CLASSES[state[:2]]
    msg = str(inner).lower()
    if isinstance(inner, sqlite3.Error):
        if isinstance(inner, sqlite3.IntegrityError | sqlite3.DataError):
            return "refused"
        if "locked" in msg or "busy" in msg:
            return "locked"
        if "readonly" in msg or "read-only" in msg:
            return "read-only"
        if "unable to open" in msg:
            return "unreachable"
        if "too big" in msg:
            return "refused"
        return "failed"
    if isinstance(e, sa.DataError | sa.IntegrityError):
        return "refused"
    if "authentication failed" in msg or "no password supplied" in msg:
        return "denied"
    if isinstance(e, sa.StatementError) and not isinstance(e, sa.DBAPIError):
        return "refused"  # a value SQLAlchemy could not bind
    if isinstance(e, sa.OperationalError | sa.InterfaceError) or "connection" in msg:
        return "unreachable"
    return "failed"


def cause_line(e: BaseException) -> str:
    orig = getattr(e, "orig", None)
    text_ = str(orig if orig is not None else e).strip().splitlines()
    return redact_text(text_[0]) if text_ else type(e).__name__
