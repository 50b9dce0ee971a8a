"""Prefect flows: each only sequences tasks. Importing configures the embedded
environment (Prefect home/results under the data folder) before Prefect is imported."""

from app.environment import configure

configure()
