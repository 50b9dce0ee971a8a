"""The compose stack and the images, checked without a Docker engine: the compose file
parses, every image is pinned, ports listen on 127.0.0.1 only, long-running services have
healthchecks, every ${VAR} has an entry in .env.example (with no real secret in it),
the Dockerfiles copy files that exist and that their ignore files let through, and the
server images run the same Prefect/MLflow versions as the client (uv.lock)."""

from __future__ import annotations

import fnmatch
import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
INFRA = ROOT / "infra"
COMPOSE = INFRA / "docker-compose.yml"
ENV_EXAMPLE = INFRA / ".env.example"

# ${VAR}, ${VAR:-default}, ${VAR-default}, ${VAR:?error}, ${VAR?error}; $$ is a literal $
VAR = re.compile(r"(?<!\$)\$\{([A-Za-z_][A-Za-z0-9_]*)(?:(:?[-?])([^}]*))?\}")


def env_example() -> dict[str, str]:
    values = {}
    for line in ENV_EXAMPLE.read_text().splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            key, _, value = line.partition("=")
            values[key.strip()] = value.strip()
    return values


def interpolated(text: str, env: dict[str, str]) -> str:
    """The compose file with variables substituted as `docker compose` would."""

    def sub(m: re.Match[str]) -> str:
        name, op, arg = m.group(1), m.group(2), m.group(3)
        if name in env and (env[name] != "" or op not in (":-", ":?")):
            return env[name]
        if op in (":-", "-"):
            return arg
        raise KeyError(f"{name} is required: {arg}")

    return VAR.sub(sub, text).replace("$$", "$")


def compose() -> dict:
    return yaml.safe_load(interpolated(COMPOSE.read_text(), env_example()))


def services() -> dict[str, dict]:
    return compose()["services"]


def is_one_shot(service: dict) -> bool:
    return str(service.get("restart", "no")) == "no"


def locked_version(package: str) -> str:
    lock = tomllib.loads((ROOT / "uv.lock").read_text())
    return next(p["version"] for p in lock["package"] if p["name"] == package)


def dockerfiles() -> list[tuple[Path, Path]]:
    """(Dockerfile, build context) of every service that builds an image."""
    found = set()
    for service in services().values():
        build = service.get("build")
        if build:
            context = (INFRA / build["context"]).resolve()
            found.add((context / build.get("dockerfile", "Dockerfile"), context))
    return sorted(found)


def ignored(path: str, patterns: list[str]) -> bool:
    """Whether a .dockerignore excludes ``path`` (last matching rule wins; ``!`` re-includes)."""
    excluded = False
    for pattern in patterns:
        negate = pattern.startswith("!")
        pattern = pattern.removeprefix("!").rstrip("/")
        if fnmatch.fnmatch(path, pattern) or fnmatch.fnmatch(path.split("/")[0], pattern):
            excluded = not negate
    return excluded


def test_compose_parses_with_the_expected_services() -> None:
    assert set(services()) == {
        "prefect-db",
        "redis",
        "prefect-server",
        "prefect-services",
        "mlflow-db",
        "s3",
        "create-bucket",
        "mlflow",
        "worker",
    }


def test_every_variable_is_in_env_example() -> None:
    used = set(VAR.findall(COMPOSE.read_text()))
    names = {name for name, _, _ in used}
    assert names, "the compose file takes its settings from .env"
    missing = names - set(env_example())
    assert not missing, f"used in docker-compose.yml but not in .env.example: {sorted(missing)}"


def test_env_example_holds_no_real_secret() -> None:
    for key, value in env_example().items():
        if any(word in key for word in ("PASSWORD", "SECRET")):
            assert value.startswith("change-me"), f"{key} in .env.example must be a change-me placeholder"
    assert "/infra/.env" in (ROOT / ".gitignore").read_text().splitlines()


def test_every_image_is_pinned() -> None:
    images = [s["image"] for s in services().values() if "image" in s]
    images += [
        line.split()[1]
        for path, _ in dockerfiles()
        for line in path.read_text().splitlines()
        if line.startswith("FROM ")
    ]
    assert len(images) >= 9
    for image in images:
        name, _, tag = image.rpartition(":")
        assert name and "/" not in tag, f"{image}: no tag"
        assert "latest" not in tag and re.search(r"\d+\.\d+", tag), f"{image}: tag {tag!r} is not a pinned version"


def test_server_images_match_the_locked_clients() -> None:
    """A server of another version than the client is asking for API mismatches."""
    prefect = locked_version("prefect")
    for name in ("prefect-server", "prefect-services"):
        assert services()[name]["image"].startswith(f"prefecthq/prefect:{prefect}-"), name
    requirements = (INFRA / "mlflow" / "requirements.txt").read_text()
    assert f"mlflow=={locked_version('mlflow')}" in requirements.splitlines()


def test_ports_are_published_on_loopback_only() -> None:
    published = [(name, str(p)) for name, s in services().items() for p in s.get("ports", [])]
    assert {name for name, _ in published} == {"prefect-server", "mlflow", "s3"}
    for name, port in published:
        assert port.startswith("127.0.0.1:"), f"{name} publishes {port} beyond loopback"


def test_long_running_services_have_healthchecks_and_dependencies_wait_for_them() -> None:
    all_services = services()
    for name, service in all_services.items():
        if not is_one_shot(service):
            assert service.get("healthcheck", {}).get("test"), f"{name} has no healthcheck"
        for dep, how in (service.get("depends_on") or {}).items():
            assert dep in all_services, f"{name} depends on unknown {dep}"
            expected = "service_completed_successfully" if is_one_shot(all_services[dep]) else "service_healthy"
            assert how["condition"] == expected, f"{name} -> {dep}"


def test_volumes_are_named_and_declared() -> None:
    config = compose()
    declared = set(config["volumes"])
    used = set()
    for name, service in config["services"].items():
        for mount in service.get("volumes", []):
            source = str(mount).split(":")[0]
            assert not source.startswith((".", "/")), f"{name} bind-mounts {source}: use a named volume"
            used.add(source)
    assert used == declared


def test_worker_polls_the_docker_pool_of_prefect_yaml() -> None:
    pools = yaml.safe_load((ROOT / "prefect.yaml").read_text())["definitions"]["work_pools"]
    command = " ".join(services()["worker"]["command"])
    assert f"--pool {pools['docker']['name']}" in command
    assert f"app.deploy --pool {pools['docker']['name']}" in command
    env = services()["worker"]["environment"]
    assert env["PREFECT_API_URL"] == "http://prefect-server:4200/api"
    assert env["MLFLOW_TRACKING_URI"] == "http://mlflow:5000"


def test_dockerfiles_copy_files_that_exist_and_are_not_ignored() -> None:
    pairs = dockerfiles()
    assert {p.relative_to(ROOT).as_posix() for p, _ in pairs} == {"infra/Dockerfile", "infra/mlflow/Dockerfile"}
    for dockerfile, context in pairs:
        assert dockerfile.is_file()
        ignore = dockerfile.with_name(dockerfile.name + ".dockerignore")
        if not ignore.exists():
            ignore = context / ".dockerignore"
        patterns = (
            [p.strip() for p in ignore.read_text().splitlines() if p.strip() and not p.startswith("#")]
            if ignore.exists()
            else []
        )
        copies = [
            line.split()[1:-1]
            for line in dockerfile.read_text().splitlines()
            if line.startswith("COPY ") and "--from" not in line
        ]
        assert copies
        for sources in copies:
            for source in sources:
                assert (context / source).exists(), f"{dockerfile}: COPY {source} does not exist in {context}"
                assert not ignored(source, patterns), f"{dockerfile}: COPY {source} is excluded by {ignore.name}"
    # the big image must not ship the virtual environment or a data folder
    patterns = [
        p.strip()
        for p in (INFRA / "Dockerfile.dockerignore").read_text().splitlines()
        if p.strip() and not p.startswith("#")
    ]
    for path in (".venv", "data", "infra/.env", "tests"):
        assert ignored(path, patterns), path


def test_image_renders_headless_with_egl() -> None:
    text = (INFRA / "Dockerfile").read_text()
    assert "MUJOCO_GL=egl" in text
    for package in ("libegl1", "libgl1-mesa-dri", "libgles2"):
        assert package in text
    assert "uv sync --frozen" in text and "--extra dask" in text


def compose_plugin() -> bool:
    if shutil.which("docker") is None:
        return False
    return subprocess.run(["docker", "compose", "version"], capture_output=True, check=False).returncode == 0


@pytest.mark.skipif(not compose_plugin(), reason="the docker compose plugin is not installed here")
def test_docker_compose_config_is_clean() -> None:
    out = subprocess.run(
        ["docker", "compose", "-f", str(COMPOSE), "--env-file", str(ENV_EXAMPLE), "config", "--quiet"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    assert not out.stderr.strip(), out.stderr  # no warnings either
