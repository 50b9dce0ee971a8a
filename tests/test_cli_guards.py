"""The command checks what it is given before any compute: a data folder that cannot be one, a missing
input path, and a data folder another writing command holds are one-line errors, not tracebacks or a
silent exit 0."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from app.cli import app
from touch2robot.folder_lock import hold_data_folder

runner = CliRunner(env={"COLUMNS": "400"})


def _said(result) -> str:
    return " ".join(result.output.split())


@pytest.mark.parametrize("where", ["file", "under_file", "dev_null"])
def test_a_data_path_that_cannot_be_a_folder_is_refused(tmp_path: Path, where: str) -> None:
    (tmp_path / "file").write_text("x")
    data = {"file": tmp_path / "file", "under_file": tmp_path / "file" / "sub", "dev_null": Path(os.devnull)}[where]
    result = runner.invoke(app, ["retarget", "--data", str(data)])
    assert result.exit_code == 2
    said = _said(result)
    assert f"--data {data}:" in said and "Traceback" not in said
    assert ("not a folder" in said) or ("cannot create the folder" in said)


@pytest.mark.parametrize(("command", "option"), [("ingest", "--folder"), ("evaluate", "--ratings")])
def test_a_missing_input_path_is_an_error(tmp_path: Path, command: str, option: str) -> None:
    result = runner.invoke(app, [command, "--data", str(tmp_path / "data"), option, str(tmp_path / "missing")])
    assert result.exit_code == 2
    assert "does not exist" in _said(result)


def test_a_second_writing_command_on_a_held_folder_refuses_naming_the_holder(tmp_path: Path) -> None:
    data = tmp_path / "data"
    with hold_data_folder(data, "touch2robot run"):
        result = runner.invoke(app, ["retarget", "--data", str(data)])
    assert result.exit_code == 1
    assert f"is in use by pid {os.getpid()} (touch2robot run" in _said(result)
    # the refused command's log file is not left for a later command's workers (its folder may be gone by then)
    from tasks.logs import LOG_FILE_ENV

    assert LOG_FILE_ENV not in os.environ


@pytest.mark.parametrize(
    ("arguments", "profile", "message"),
    [
        (["--seeds", "0"], None, "Invalid value for '--seeds': Input should be greater than or equal to 1"),
        (["--seeds", "-2"], None, "Invalid value for '--seeds'"),
        ([], "seeds: [0, 2, 2]\n", "bad profile: .*seeds: Value error, seed 2 is given 2 times"),
        ([], "seeds: [-1]\n", "bad profile: .*seeds: Value error, seeds are whole numbers >= 0, got -1"),
    ],
)
def test_a_bad_seed_list_is_refused_before_any_compute(
    tmp_path: Path, arguments: list[str], profile: str | None, message: str
) -> None:
    import re

    data = tmp_path / "data"
    chosen = []
    if profile is not None:
        (tmp_path / "sweep.yaml").write_text("name: sweep\n" + profile)
        chosen = ["--profile", str(tmp_path / "sweep.yaml")]
    result = runner.invoke(app, ["run", "--data", str(data), *chosen, *arguments])
    assert result.exit_code == 2
    assert re.search(message, _said(result)), _said(result)
    assert not data.exists()  # nothing was made: not even the data folder


@pytest.mark.parametrize(
    ("args", "status", "said"), [(["--help"], 0, "Usage"), (["run", "-p", "/no/such.yaml"], 2, "/no/such.yaml")]
)
def test_the_console_script_keeps_its_status_and_output_when_it_skips_the_teardown(
    tmp_path: Path, args: list[str], status: int, said: str
) -> None:
    """The installed ``touch2robot`` ends with ``os._exit`` after its exit handlers: its status and its piped
    (block-buffered) output still come out whole."""
    import subprocess
    import sys

    script = Path(sys.executable).with_name("touch2robot")
    env = {**os.environ, "TOUCH2ROBOT_DATA": str(tmp_path / "data"), "COLUMNS": "200"}
    out = subprocess.run([str(script), *args], env=env, capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == status, out.stdout + out.stderr
    assert said in " ".join((out.stdout + out.stderr).split())
