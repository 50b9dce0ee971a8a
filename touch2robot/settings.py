"""Where everything lives: one data folder (default ``./data``, or ``$TOUCH2ROBOT_DATA``)
holds the recordings, the Parquet lake, the DuckDB catalog, MLflow's SQLite file and
artefacts, and Prefect's home and result storage. Nothing writes elsewhere by default."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Environment-driven settings (``TOUCH2ROBOT_DATA``)."""

    model_config = SettingsConfigDict(env_prefix="TOUCH2ROBOT_", extra="ignore")
    data: Path = Field(default=Path("data"), description="the project data folder")


@dataclass(frozen=True)
class DataLayout:
    """Paths inside the data folder. Absolute, so that code run from another working
    directory (a Prefect worker, a test) still writes in the same place."""

    root: Path

    @classmethod
    def from_env(cls, data: Path | str | None = None) -> DataLayout:
        return cls(Path(data if data is not None else Settings().data).expanduser().resolve())

    @property
    def recordings(self) -> Path:
        return self.root / "recordings"

    @property
    def groundtruth(self) -> Path:
        """Demonstrator ground truth, kept apart from the recordings; read only by tests."""
        return self.root / "groundtruth"

    @property
    def lake(self) -> Path:
        return self.root / "lake"

    @property
    def catalog(self) -> Path:
        return self.root / "catalog.duckdb"

    @property
    def mlflow_db(self) -> Path:
        return self.root / "mlflow.db"

    @property
    def mlartifacts(self) -> Path:
        return self.root / "mlartifacts"

    @property
    def prefect_home(self) -> Path:
        return self.root / "prefect"

    @property
    def results(self) -> Path:
        """Prefect's persisted task results (the cross-process cache)."""
        return self.root / "prefect" / "results"

    @property
    def user_study(self) -> Path:
        """Folder of user-study ratings files (the demonstrator writes a SYNTHETIC example)."""
        return self.recordings / "user_study"

    @property
    def synthetic_ratings(self) -> Path:
        return self.user_study / "ratings_SYNTHETIC.csv"

    @property
    def checkpoints(self) -> Path:
        """Training checkpoints (one folder per training, named by what it trains and a config key)."""
        return self.root / "checkpoints"

    @property
    def datasets(self) -> Path:
        """LeRobot datasets of the robot demonstrations (``<method>-<task>``)."""
        return self.root / "datasets"

    @property
    def policies(self) -> Path:
        """Diffusion Policy training folders (LeRobot checkpoints)."""
        return self.root / "policies"

    @property
    def tmp(self) -> Path:
        """Temporary files of the stages (MLflow's model staging, plots): inside the data folder, so a
        killed run leaves nothing in the system's /tmp."""
        return self.root / "tmp"

    @property
    def reports(self) -> Path:
        return self.root / "reports"

    def table(self, name: str) -> Path:
        return self.lake / name
