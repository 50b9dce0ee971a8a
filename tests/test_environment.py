"""The embedded environment keeps a run's files inside its data folder: temporary files too (a run killed
with SIGKILL cannot clean up, so what it leaves must not land in the system's /tmp)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _probe(data: Path, env: dict[str, str]) -> str:
    code = (
        "import tempfile\n"
        "from app.environment import configure\n"
        "from touch2robot.settings import DataLayout\n"
        "from pathlib import Path\n"
        f"configure(DataLayout(Path({str(data)!r})))\n"
        "print(tempfile.gettempdir())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    return out.stdout.strip().splitlines()[-1]


def test_temporary_files_go_inside_the_data_folder(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "TMPDIR"}
    assert Path(_probe(tmp_path / "data", env)) == tmp_path / "data" / "tmp"


def test_a_users_own_tmpdir_stands(tmp_path: Path) -> None:
    (tmp_path / "mine").mkdir()
    env = {**os.environ, "TMPDIR": str(tmp_path / "mine")}
    assert Path(_probe(tmp_path / "data", env)) == tmp_path / "mine"
