"""Process environment for the embedded defaults: Prefect's home and result storage and
MuJoCo's headless renderer, all under the data folder. Values the user already set
(e.g. PREFECT_API_URL for a real server) are left alone. Call before importing prefect."""

from __future__ import annotations

import os
import tempfile

from touch2robot.settings import DataLayout


def configure(layout: DataLayout | None = None) -> DataLayout:
    layout = layout or DataLayout.from_env()
    os.environ["TOUCH2ROBOT_DATA"] = str(layout.root)  # subprocesses and workers agree on the folder
    defaults = {
        "PREFECT_HOME": str(layout.prefect_home),
        "PREFECT_LOCAL_STORAGE_PATH": str(layout.results),
        "PREFECT_RESULTS_PERSIST_BY_DEFAULT": "true",
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        # the ephemeral API server takes 15-27 s to start on 2 cores; Prefect's default is 20 s
        "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "120",
        "PREFECT_LOGGING_LEVEL": "INFO",
        "MUJOCO_GL": "egl",
    }
    for key, value in defaults.items():
        os.environ.setdefault(key, value)
    layout.root.mkdir(parents=True, exist_ok=True)
    if "TMPDIR" not in os.environ:  # a user's own choice stands
        layout.tmp.mkdir(exist_ok=True)
        os.environ["TMPDIR"] = str(layout.tmp)
        tempfile.tempdir = None  # recomputed from TMPDIR on next use
    return layout
