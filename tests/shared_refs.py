"""Where the team's reference files live: `../shared` beside the checkout (CI lays it there), read in place.

The NIST I++ DME test files, NIST's DMIS program and its output, the NIST CAD part, the QIF schemas and the
OPC UA nodesets are other people's files: they are never copied into the project. `CMM_SHARED` names the folder
when it is elsewhere; otherwise the nearest `shared/` folder above the checkout is taken (a git worktree sits
deeper than the checkout CI makes). A test that needs a missing folder is skipped with the reason.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_REPO = Path(__file__).resolve().parents[1]


def shared_root() -> Path | None:
    """The shared reference folder, or None when this checkout has none beside it."""
    named = os.environ.get("CMM_SHARED")
    if named:
        return Path(named)
    for parent in _REPO.parents:
        if (parent / "shared" / "docs").is_dir():
            return parent / "shared"
    return None


def shared_path(*parts: str) -> Path:
    """A path under the shared folder (it may not exist: see `require`)."""
    root = shared_root()
    return (root if root is not None else _REPO.parent / "shared").joinpath(*parts)


def require(*parts: str) -> Path:
    """The shared path, or skip the calling test with the reason when it is absent."""
    path = shared_path(*parts)
    if not path.exists():
        pytest.skip(f"the reference files {path} are not here (set CMM_SHARED to the team's shared folder)")
    return path
