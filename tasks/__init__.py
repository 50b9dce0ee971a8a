"""Prefect tasks: library calls wrapped with caching, retries, artefacts and tracking.

Importing this package configures the embedded environment (Prefect home and result
storage under the data folder) before Prefect itself is imported."""

from app.environment import configure

configure()
