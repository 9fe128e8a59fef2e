"""Why a station did not start, in one sentence that names the real cause (every start-up failure was
headed "the machine did not answer on <port>", also for a full disk or a session database that was down).

:func:`startup_failure` looks through the exception and its causes for, in this order: a full disk (ENOSPC,
EDQUOT), the session database (the PostgreSQL store), a sessions folder that cannot be written, the modules
(some answered, not all), the port or the machine (nothing answered). Anything else is named with its type.
"""

from __future__ import annotations

import errno
import re
from typing import Any, Iterator

FULL = (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC))


def _chain(exc: BaseException) -> Iterator[BaseException]:
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        yield e
        e = e.__cause__ or e.__context__


def hide_password(url: str) -> str:
    """``postgresql://user:secret@host/db`` without its password."""
    return re.sub(r"(://[^:/@]+):[^@/]*@", r"\1:***@", str(url))


def startup_failure(exc: BaseException, *, port: Any, sessions: Any) -> str:
    """The one sentence ``cmm serve`` prints when the station did not start (see the module docstring)."""
    from ..journal.store import StoreError, is_url

    where = hide_password(str(sessions))
    chain = list(_chain(exc))
    for e in chain:
        if isinstance(e, OSError) and e.errno in FULL:
            return (f"the disk is full: the session journal cannot be written in {where} "
                    f"({e.strerror or e}). Free some space, or give --sessions a folder on another disk")
    for e in chain:
        if isinstance(e, StoreError) or type(e).__module__.split(".")[0] == "psycopg":
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            return (f"the session database {where} did not answer: {first}. Start the database, or record the "
                    "sessions in a folder (--sessions DIR)")
    for e in chain:
        if isinstance(e, OSError) and not _link_error(e) and getattr(e, "filename", None) is not None:
            return (f"cannot write the sessions in {where}: {e.strerror or e} ({e.filename}). Check the folder "
                    "and its permissions")
    for e in chain:
        if _link_error(e):
            text = str(e)
            if re.search(r"\bfound \d+ modules?\b|\bfound modules\b|\bexpected \d+\b|\bmodules? \d+(, \d+)* (did not|never)", text):
                return f"not every module answered on {port}: {text}"
            return f"the machine did not answer on {port}: {text}"
    if is_url(sessions) and isinstance(exc, (ConnectionError, TimeoutError)):
        return f"the session database {where} did not answer: {exc}"
    return f"the station did not start on {port}: {type(exc).__name__}: {exc}"


def _link_error(exc: BaseException) -> bool:
    """An error of the NMC link (the driver's NmcError and its kinds), told apart without importing the driver:
    the command line reaches the machine only through the station."""
    return any(k.__name__ == "NmcError" for k in type(exc).__mro__)
