"""Typed configuration: a *profile* (smoke, local, paper, or your own YAML file) holds one
section per stage. Every section's defaults are the paper's values; the profile files
under ``touch2robot/profiles/`` only override sizes. Unknown keys are errors."""

from __future__ import annotations

import types
import typing
from importlib import resources
from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from touch2robot.comparison.config import ComparisonConfig
from touch2robot.contacts.config import ContactsConfig
from touch2robot.policy.config import PolicyConfig
from touch2robot.retarget.config import RetargetConfig
from touch2robot.runner_config import RunnerConfig
from touch2robot.student.config import StudentConfig
from touch2robot.synth.config import SynthConfig
from touch2robot.teachers.config import TeacherConfig
from touch2robot.twin.config import TwinConfig
from touch2robot.twin.plan import ReplayConfig

BUILTIN_PROFILES = ("smoke", "local", "paper")


class Profile(BaseModel):
    """All stage configurations of one run."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = "paper"
    description: str = ""
    synth: SynthConfig = SynthConfig()
    contacts: ContactsConfig = ContactsConfig()
    retarget: RetargetConfig = RetargetConfig()
    runner: RunnerConfig = RunnerConfig()
    # torch keeps one RNG per process: trainings side by side in threads would take turns on it
    # and none would repeat (nor equal the same training run alone), so they get processes
    training_runner: RunnerConfig = Field(
        default=RunnerConfig(kind="processes"),
        description="runner of the training fan-outs (teachers, student variants, policy): one process per training",
    )
    teacher: TeacherConfig = TeacherConfig()
    student: StudentConfig = StudentConfig()
    policy: PolicyConfig = PolicyConfig()
    replay: ReplayConfig = ReplayConfig()
    twin: TwinConfig = TwinConfig()
    comparison: ComparisonConfig = ComparisonConfig()
    seeds: tuple[int, ...] = Field(
        default=(0,),
        description="the sweep's seeds: the stochastic stages (teachers, student, twin replays, policies) run once "
        "per seed, each cached on its own; ingest, contacts and kinematic retargeting run once",
    )

    @field_validator("seeds")
    @classmethod
    def _seeds_are_a_set(cls, seeds: tuple[int, ...]) -> tuple[int, ...]:
        return check_seeds(seeds)

    def sweep(self, seeds: typing.Sequence[int] | None = None) -> tuple[int, ...]:
        """The seeds a flow runs: ``seeds`` when given (a command's ``--seeds``; ValueError when not a set of
        whole numbers >= 0), else the profile's."""
        if seeds is None:
            return self.seeds
        try:
            return check_seeds(seeds)
        except ValueError as e:
            raise ValueError(f"--seeds: {e}") from None

    def for_seed(self, seed: int) -> Profile:
        """The profile as sweep seed ``seed`` runs it: every stochastic stage's seed moved by ``seed`` (seed 0
        is the profile as written). The student's held-out split keeps ``student.seed``: every sweep seed is
        scored on the same demonstrations. The policy's evaluation episodes move by whole episode sets, so
        two seeds never share an episode."""
        return self.model_copy(
            update={
                "teacher": self.teacher.model_copy(update={"seed": self.teacher.seed + seed}),
                "student": self.student.model_copy(update={"seed": self.student.seed + seed}),
                "replay": self.replay.model_copy(update={"seed": self.replay.seed + seed}),
                "policy": self.policy.model_copy(
                    update={
                        "seed": self.policy.seed + seed,
                        "eval_seed": self.policy.eval_seed + seed * self.policy.eval_episodes,
                    }
                ),
            }
        )

    @model_validator(mode="after")
    def _one_training_per_process(self) -> Profile:
        t = self.training_runner
        if t.kind == "threads" and t.max_workers != 1:
            raise ValueError(
                "training_runner.kind 'threads' would train side by side in one process, where torch's one RNG "
                "makes no training repeat: use 'processes' (or 'dask' with threads_per_worker 1), or max_workers 1"
            )
        if t.kind == "dask" and t.dask_address is None and t.threads_per_worker != 1:
            raise ValueError(
                "training_runner.threads_per_worker must be 1: trainings sharing a worker process share torch's RNG"
            )
        return self


class ProfileError(ValueError):
    """A profile file that cannot be read or validated; the message names the file and field."""


def check_seeds(seeds: typing.Sequence[int]) -> tuple[int, ...]:
    """``seeds`` as a tuple, or ValueError: a sweep needs at least one seed, each once, none negative (checked
    before any compute: a duplicate would train the same models twice)."""
    seeds = tuple(seeds)
    if not seeds:
        raise ValueError("give at least one seed")
    if bad := [s for s in seeds if isinstance(s, bool) or not isinstance(s, int) or s < 0]:
        raise ValueError(f"seeds are whole numbers >= 0, got {bad[0]!r}")
    if dupes := sorted({s for s in seeds if seeds.count(s) > 1}):
        raise ValueError(f"seed {dupes[0]} is given {seeds.count(dupes[0])} times")
    return seeds


def _merged(defaults: dict, overrides: dict) -> dict:
    """``overrides`` deep-merged onto ``defaults``: a profile that sets one key of a nested
    section (say one reward weight of one method) keeps every other default of that section."""
    out = dict(defaults)
    for key, value in overrides.items():
        out[key] = _merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def load_profile(name_or_path: str | Path) -> Profile:
    """A built-in profile by name, or a YAML file by path."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise ProfileError(f"profile file {path} does not exist")
        text, origin = path.read_text(), str(path)
    elif str(name_or_path) in BUILTIN_PROFILES:
        res = resources.files("touch2robot.profiles") / f"{name_or_path}.yaml"
        text, origin = res.read_text(), f"built-in profile {name_or_path!r}"
    else:
        raise ProfileError(
            f"unknown profile {name_or_path!r}: use one of {', '.join(BUILTIN_PROFILES)} or a YAML file path"
        )
    try:
        data = yaml.load(text, Loader=UniqueKeyLoader)
    except yaml.YAMLError as e:
        raise ProfileError(f"{origin}: not valid YAML ({e})") from None
    if data is None:
        # an empty file would silently run every paper default (1500 PPO iterations per teacher)
        raise ProfileError(f"{origin}: the profile is empty; set at least its name (see the built-in profiles)")
    if not isinstance(data, dict):
        raise ProfileError(f"{origin}: expected a mapping of stage sections, got {type(data).__name__}")
    refuse_bools_as_numbers(Profile, data, origin, ())
    try:
        return Profile.model_validate(_merged(Profile().model_dump(), data))
    except ValidationError as e:
        fields = "; ".join(f"{'.'.join(map(str, err['loc']))}: {err['msg']}" for err in e.errors())
        raise ProfileError(f"{origin}: {fields}") from None


class UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, except that a key given twice in one mapping is an error (plain YAML keeps the
    last, so a profile could set a value that never takes effect)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: dict[object, yaml.Mark] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r} (first at line {seen[key].line + 1})", key_node.start_mark
                )
            seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


def _leaf_types(annotation: object) -> set[object]:
    if typing.get_origin(annotation) is typing.Annotated:  # a bounded number: Annotated[float, Field(ge=...)]
        return _leaf_types(typing.get_args(annotation)[0])
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return set().union(*(_leaf_types(a) for a in typing.get_args(annotation)))
    return {typing.get_origin(annotation) or annotation}


def refuse_bools_as_numbers(model: type[BaseModel], data: dict, origin: str, loc: tuple[str, ...]) -> None:
    """pydantic reads ``true`` as 1 where a number belongs (``n_envs: true`` would run one env): refuse it,
    naming the field."""
    for key, value in data.items():
        field = model.model_fields.get(str(key))
        if field is not None:
            _check_value(field.annotation, value, origin, (*loc, str(key)))


def _check_value(annotation: object, value: object, origin: str, loc: tuple[str, ...]) -> None:
    leaves = _leaf_types(annotation)
    if isinstance(value, bool) and bool not in leaves and leaves & {int, float}:
        raise ProfileError(f"{origin}: {'.'.join(loc)}: expected a number, got {value!r}")
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    for leaf in leaves:
        if isinstance(leaf, type) and issubclass(leaf, BaseModel) and isinstance(value, dict):
            refuse_bools_as_numbers(leaf, value, origin, loc)
    if typing.get_origin(annotation) is dict and isinstance(value, dict) and len(args) == 2:
        for key, item in value.items():
            _check_value(args[1], item, origin, (*loc, str(key)))
    if typing.get_origin(annotation) in (list, tuple) and isinstance(value, list) and args:
        for i, item in enumerate(value):
            _check_value(args[0], item, origin, (*loc, str(i)))
