"""Prefect flows: each only sequences tasks. Importing configures the embedded
environment (Prefect home/results under the data folder) before Prefect is imported."""

from touch2robot.environment import configure

configure()
