"""One writing run per data folder: a second one refuses at once naming the holder, and a holder killed with
SIGKILL leaves no stale lock."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from touch2robot.folder_lock import DataFolderBusy, hold_data_folder

ROOT = Path(__file__).resolve().parents[1]


def _holder(data: Path) -> subprocess.Popen:
    code = (
        "import sys, time\n"
        "from pathlib import Path\n"
        "from touch2robot.folder_lock import hold_data_folder\n"
        f"with hold_data_folder(Path({str(data)!r}), 'touch2robot run'):\n"
        "    print('held', flush=True)\n"
        "    time.sleep(120)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_writer_refuses_naming_the_holder_and_a_killed_holder_frees_the_folder(tmp_path: Path) -> None:
    data = tmp_path / "data"
    holder = _holder(data)
    try:
        busy = rf"in use by pid {holder.pid} \(touch2robot run, since"
        with pytest.raises(DataFolderBusy, match=busy), hold_data_folder(data, "touch2robot teachers"):
            pass
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(30)
    with hold_data_folder(data, "touch2robot teachers"):  # no stale lock after SIGKILL
        assert (data / ".run.lock").read_text().startswith('{"pid"')


def test_one_process_takes_the_lock_again_after_releasing_it(tmp_path: Path) -> None:
    for _ in range(2):
        with hold_data_folder(tmp_path, "touch2robot run"):
            pass
