"""Where a result came from: the code's version, for reports and every MLflow run."""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import subprocess
from pathlib import Path

# The packages whose code makes the figures (the code digest of a copy that is not a git checkout).
CODE_PACKAGES = ("touch2robot", "schemas", "tasks", "flows", "app")


@functools.cache
def git_commit() -> str | None:
    """The commit of the git checkout the code runs from, with '+changes' when tracked files differ from
    it; None outside a checkout (an installed package) or without git. Looked up once per process."""
    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()
        changed = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + (" +changes" if changed else "")


@functools.cache
def code_version() -> str:
    """'git <commit>' in a checkout, else the package version and a digest of the code's Python files
    (computed once per process)."""
    commit = git_commit()
    if commit is not None:
        return f"git {commit}"
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for package in CODE_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode() + path.read_bytes())
    return f"touch2robot {importlib.metadata.version('touch2robot')}, code {digest.hexdigest()[:16]}"
