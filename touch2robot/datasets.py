"""The catalog of the data folder: every dataset named once.

Lake tables: where each lives (``<data>/lake/<table>``), its partition keys and Arrow schema (from
``schemas.tables``) and how its files are named: a typed key (a NamedTuple) and an :class:`IdFormat`
that builds the file id from it and parses it back, raising :class:`DatasetIdError` (naming the id
and what it should be) for an id that does not fit. The data folder's other datasets: the recordings,
training checkpoints, LeRobot datasets and policy training folders. Readiness: which inputs of a stage
exist (the ingested glove sessions, the retargeted demonstrations, the teachers' rollouts).

Flows and tasks ask this module instead of spelling paths and ids; ``touch2robot.lake`` stays the one
atomic write point beneath it.

Who writes the lake: the library computes tables and returns them; the Prefect task of a stage writes
them, through :meth:`LakeTable.write`. Two library functions write because the write is their
algorithm: ingestion (``touch2robot.ingest``: stream tables first, the ``recordings`` row last as the
commit marker) and the evaluation's :func:`touch2robot.evaluate.replace_table` (a table's whole
content replaced, stale files pruned).
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import pyarrow as pa

from schemas import tables
from schemas.vocabulary import Origin, RecordingKind, RecordingStatus, Source
from touch2robot import lake as lake_io
from touch2robot import scenes
from touch2robot.ingest import recording_rows
from touch2robot.ingest.scan import Scan, find_recordings
from touch2robot.settings import DataLayout


class DatasetIdError(ValueError):
    """A file id, or a part of one, that does not fit its dataset's format; the message names both."""


# --------------------------------------------------------------------------- id formats


@dataclass(frozen=True)
class Part:
    """What one field of an id may hold: a regular expression and its description for errors."""

    pattern: Callable[[], str]
    describe: Callable[[], str]


def one_of(values: Callable[[], Sequence[str]]) -> Part:
    """A field from a closed vocabulary, looked up when used (the vocabulary may grow at run time)."""
    return Part(lambda: "|".join(re.escape(v) for v in values()), lambda: f"one of {tuple(values())}")


# letters, digits, '_', '.', '-': no '/', nothing hidden (leading '.'), never empty
NAME = Part(lambda: r"[A-Za-z0-9_][A-Za-z0-9_.-]*", lambda: "a name of letters, digits, '_', '.', '-'")
CONFIG_KEY = Part(lambda: r"[0-9a-f]{12}", lambda: "12 hex digits (a configuration digest)")

TASK = one_of(lambda: scenes.TASKS)
ORIGIN = one_of(lambda: tuple(Origin))
SEED = Part(lambda: r"0|[1-9][0-9]*", lambda: "a sweep seed (a whole number >= 0)")
_FIELD = re.compile(r"\{(\w+)\}")


@dataclass(frozen=True)
class IdFormat[K: NamedTuple]:
    """A spelling such as ``{origin}-{task}``: fields of the key ``K`` between literal text. Fields
    not in ``parts`` are :data:`NAME`. A free field may hold '-', so a field next to it must be
    closed (a vocabulary, a digest): :meth:`build` proves every id parses back to its key."""

    key: type[K]
    spelling: str
    parts: Mapping[str, Part] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if tuple(_FIELD.findall(self.spelling)) != self.key._fields:
            raise ValueError(f"id format {self.spelling!r} does not spell the fields {self.key._fields}")

    def _part(self, name: str) -> Part:
        return self.parts.get(name, NAME)

    def _regex(self) -> re.Pattern[str]:
        pieces = _FIELD.split(self.spelling)  # literal, field, literal, field, ..., literal
        return re.compile(
            "".join(f"(?P<{p}>{self._part(p).pattern()})" if i % 2 else re.escape(p) for i, p in enumerate(pieces))
        )

    def _expected(self) -> str:
        return ", ".join(f"{f} {self._part(f).describe()}" for f in self.key._fields)

    def build(self, key: K) -> str:
        """The file id of ``key``."""
        for name, value in zip(self.key._fields, key, strict=True):
            if not isinstance(value, str) or not re.fullmatch(self._part(name).pattern(), value):
                raise DatasetIdError(f"{self.spelling}: {name} {value!r} is not {self._part(name).describe()}")
        file_id = self.spelling.format(**key._asdict())
        if self.parse(file_id) != key:
            raise DatasetIdError(f"{self.spelling}: {key} spells {file_id!r}, which reads back differently")
        return file_id

    def parse(self, file_id: str) -> K:
        """The key a file id names."""
        match = self._regex().fullmatch(file_id)
        if match is None:
            raise DatasetIdError(f"{file_id!r} is not a {self.spelling} id ({self._expected()})")
        return self.key._make(match.groups())  # groups in spelling order, which is the fields' order


class RecordingKey(NamedTuple):
    recording_id: str


class RolloutsKey(NamedTuple):
    origin: str
    task: str
    seed: str


class RolloutContactsKey(NamedTuple):
    origin: str
    method: str
    seed: str


class TaskKey(NamedTuple):
    task: str
    seed: str


class MethodTaskKey(NamedTuple):
    method: str
    task: str
    seed: str


class TeacherRunKey(NamedTuple):
    task: str
    method: str
    config: str


class StudentRunKey(NamedTuple):
    variant: str
    config: str


class PolicyRunKey(NamedTuple):
    method: str
    task: str
    seed: str
    config: str


RECORDING_ID = IdFormat(RecordingKey, "{recording_id}")
ROLLOUTS_ID = IdFormat(RolloutsKey, "{origin}-{task}-seed{seed}", {"origin": ORIGIN, "task": TASK, "seed": SEED})
ROLLOUT_CONTACTS_ID = IdFormat(RolloutContactsKey, "{origin}-{method}-seed{seed}", {"origin": ORIGIN, "seed": SEED})
TASK_ID = IdFormat(TaskKey, "{task}-seed{seed}", {"task": TASK, "seed": SEED})
METHOD_TASK_ID = IdFormat(MethodTaskKey, "{method}-{task}-seed{seed}", {"task": TASK, "seed": SEED})
TEACHER_RUN_ID = IdFormat(TeacherRunKey, "{task}-{method}-{config}", {"task": TASK, "config": CONFIG_KEY})
STUDENT_RUN_ID = IdFormat(StudentRunKey, "{variant}-{config}", {"config": CONFIG_KEY})
POLICY_RUN_ID = IdFormat(
    PolicyRunKey, "{method}-{task}-seed{seed}-{config}", {"task": TASK, "seed": SEED, "config": CONFIG_KEY}
)


@dataclass(frozen=True)
class KeyedIdFormat:
    """The evaluation tables' ids: one file per group of ``columns`` values, joined by ``__``.
    Characters outside ``[A-Za-z0-9_.-]`` (and a leading dot, which would hide the file) become
    ``-`` and a short hash of the exact key is then appended, so two keys never share a file and
    the id stays readable; such an id parses to its readable form, not its key (that is in its rows)."""

    columns: tuple[str, ...]

    def build(self, key: Sequence[str]) -> str:
        if len(key) != len(self.columns):
            raise DatasetIdError(f"{'__'.join(self.columns)}: key {tuple(key)} has not {len(self.columns)} parts")
        return safe_file_id(*key)

    def parse(self, file_id: str) -> tuple[str, ...]:
        parts = tuple(file_id.split("__"))
        if len(parts) != len(self.columns) or safe_file_id(*parts) != file_id:
            raise DatasetIdError(
                f"{file_id!r} is not a {'__'.join(self.columns)} id (or is one whose key held unsafe characters)"
            )
        return parts


def safe_file_id(*parts: str) -> str:
    """``parts`` joined by ``__`` as a safe, unique file name (see :class:`KeyedIdFormat`)."""
    raw = "__".join(parts)
    safe = re.sub(r"[^A-Za-z0-9_.-]|^\.", "-", raw)
    return safe if safe == raw else f"{safe}-{hashlib.sha256(raw.encode()).hexdigest()[:8]}"


# --------------------------------------------------------------------------- lake tables


@dataclass(frozen=True)
class LakeTable:
    """One table of the lake. ``ids`` names its files; where the spelling depends on the first
    partition value (``contacts``: a recording id for human and real contacts, origin and method for
    rollouts' contacts), ``ids_by_partition`` says so."""

    name: str
    ids: IdFormat[Any] | KeyedIdFormat
    ids_by_partition: Mapping[str, IdFormat[Any]] = field(default_factory=dict)

    @property
    def schema(self) -> pa.Schema:
        return tables.SCHEMAS[self.name]

    @property
    def partition_keys(self) -> tuple[str, ...]:
        return tables.PARTITIONS.get(self.name, ())

    def folder(self, lake: Path) -> Path:
        return Path(lake) / self.name

    def id_format(self, partition: Mapping[str, str]) -> IdFormat[Any] | KeyedIdFormat:
        first = partition.get(self.partition_keys[0]) if self.partition_keys else None
        return self.ids_by_partition.get(str(first), self.ids)

    def _partition(self, partition: Mapping[str, str]) -> dict[str, str] | None:
        # in the table's key order (keyword order is the caller's), anything else left for lake_io to reject
        ordered = {k: partition[k] for k in self.partition_keys if k in partition} | dict(partition)
        return ordered or None

    def path(self, lake: Path, key: Sequence[str], **partition: str) -> Path:
        """The file of ``key`` (in the partition ``partition``)."""
        return lake_io.file_path(Path(lake), self.name, self.file_id(key, partition), self._partition(partition))

    def write(self, lake: Path, key: Sequence[str], rows: pa.Table, **partition: str) -> Path:
        """Write (replace) the file of ``key``, atomically, its rows checked against the schema."""
        file_id = self.file_id(key, partition)
        return lake_io.write_rows(Path(lake), self.name, file_id, rows, self._partition(partition))

    def file_id(self, key: Sequence[str], partition: Mapping[str, str]) -> str:
        try:
            return self.id_format(partition).build(key)
        except DatasetIdError as e:
            raise DatasetIdError(f"lake table {self.name!r}: {e}") from None

    def files(self, lake: Path) -> list[Path]:
        return lake_io.files(Path(lake), self.name)

    def entries(self, lake: Path) -> Iterator[tuple[Any, dict[str, str], Path]]:
        """Every file as (its key, its partition, its path), in path order; a file whose id or folder
        does not fit the table raises :class:`DatasetIdError` naming it."""
        for path in self.files(lake):
            folders = path.relative_to(self.folder(lake)).parts[:-1]
            partition = {k: v for k, _, v in (f.partition("=") for f in folders)}
            if tuple(partition) != self.partition_keys or any("=" not in f for f in folders):
                expected = "/".join(f"{k}=<{k}>" for k in self.partition_keys)
                raise DatasetIdError(
                    f"{path}: expected lake/{self.name}/{expected + '/' if expected else ''}<id>.parquet"
                )
            try:
                yield self.id_format(partition).parse(path.stem), partition, path
            except DatasetIdError as e:
                raise DatasetIdError(f"{path}: {e}") from None


def check_ids(lake: Path, tables: Iterable[str]) -> None:
    """Every file of ``tables`` named as its table names files, or :class:`DatasetIdError` naming the first
    that is not (e.g. a file written before the sweep seeds, which a stage would otherwise read twice over)."""
    for name in tables:
        for _ in LAKE[name].entries(lake):
            pass


# the tables ingestion writes, one file per recording
_RECORDING_TABLES = (
    *("recordings", "taxels", "hand_joints", "hand_keypoints", "wrist_pose", "object_pose"),
    *("robot_joint_states", "robot_joint_targets", "twintac", "fsr", "time_map", "thresholds"),
)

# the tables the evaluation rewrites whole, one file per group of these columns
EVALUATION_IDS = {
    "contact_metrics": KeyedIdFormat(("source", "method")),
    "onset_errors": KeyedIdFormat(("source", "method")),
    "comparison": KeyedIdFormat(("reference_source", "source")),
    "user_study": KeyedIdFormat(("ratings_file",)),
    "replays": KeyedIdFormat(("task", "method", "seed")),
}

LAKE: dict[str, LakeTable] = {
    **{name: LakeTable(name, RECORDING_ID) for name in _RECORDING_TABLES},
    "contacts": LakeTable(
        "contacts", RECORDING_ID, {Source.SIM: ROLLOUT_CONTACTS_ID, Source.RECONSTRUCTED: ROLLOUT_CONTACTS_ID}
    ),
    "retargeted": LakeTable("retargeted", RECORDING_ID),
    "rollouts": LakeTable("rollouts", ROLLOUTS_ID),
    "student_dataset": LakeTable("student_dataset", TASK_ID),
    "student_predictions": LakeTable("student_predictions", METHOD_TASK_ID),
    "policy_eval": LakeTable("policy_eval", METHOD_TASK_ID),
    "student_variants": LakeTable("student_variants", KeyedIdFormat(("method", "variant", "seed"))),
    **{name: LakeTable(name, ids) for name, ids in EVALUATION_IDS.items()},
}
RECORDINGS = LAKE["recordings"]
CONTACTS = LAKE["contacts"]
RETARGETED = LAKE["retargeted"]
ROLLOUTS = LAKE["rollouts"]
STUDENT_DATASET = LAKE["student_dataset"]
STUDENT_PREDICTIONS = LAKE["student_predictions"]
POLICY_EVAL = LAKE["policy_eval"]
STUDENT_VARIANTS = LAKE["student_variants"]

# the lake files a demonstration reference is built from (see touch2robot.teachers.reference)
REFERENCE_TABLES = ("retargeted", "object_pose", "hand_keypoints")


def human_contacts(lake: Path, recording: Mapping[str, str]) -> Path:
    """The human contacts file of one glove session (a recordings row)."""
    return CONTACTS.path(lake, RecordingKey(recording["recording_id"]), source=Source.HUMAN, task=recording["task"])


def reference_files(lake: Path, recording: Mapping[str, str]) -> list[Path]:
    """Every lake file the demonstration reference of one glove session reads."""
    rid = RecordingKey(recording["recording_id"])
    return [*(LAKE[t].path(lake, rid) for t in REFERENCE_TABLES), human_contacts(lake, recording)]


def rollouts_key(origin: str, task: str, seed: int) -> RolloutsKey:
    return RolloutsKey(origin, task, str(seed))


def with_seed(rows: pa.Table, seed: int | None) -> pa.Table:
    """``rows`` of a seeded table with the sweep seed that made them (``schemas.tables.unseeded``); None for
    rows no sweep made (the glove's contacts, a replay recorded without one)."""
    if "seed" in rows.column_names:
        rows = rows.drop_columns(["seed"])
    return rows.append_column("seed", pa.array([seed] * len(rows), pa.int64()))


def teacher_rollouts(lake: Path, method: str, task: str, seed: int) -> Path:
    """The rollouts file of the teacher of ``method`` on ``task``, of sweep seed ``seed``."""
    return ROLLOUTS.path(lake, rollouts_key(Origin.TEACHER, task, seed), method=method)


# --------------------------------------------------------------------------- the data folder's other datasets


def recording_files(folder: Path) -> Scan:
    """The MCAP recordings under ``folder`` (default of a flow: ``<data>/recordings``), sorted, and every other
    entry named like one with the reason it is skipped (a directory, a FIFO, a dangling or looping link)."""
    return find_recordings(Path(folder))


def teacher_checkpoints(layout: DataLayout, task: str, method: str, config: str) -> Path:
    """The checkpoints folder of one teacher training (``config``: its settings' digest)."""
    return layout.checkpoints / "teachers" / TEACHER_RUN_ID.build(TeacherRunKey(task, method, config[:12]))


def student_checkpoints(layout: DataLayout, variant: str, config: str) -> Path:
    """The checkpoints folder of one student variant's training."""
    return layout.checkpoints / "student" / STUDENT_RUN_ID.build(StudentRunKey(variant, config[:12]))


def policy_dataset(layout: DataLayout, method: str, task: str, seed: int) -> Path:
    """The LeRobot dataset of one task x method's robot demonstrations of sweep seed ``seed``."""
    return layout.datasets / METHOD_TASK_ID.build(MethodTaskKey(method, task, str(seed)))


def lerobot_repo_id(method: str, task: str, seed: int) -> str:
    """LeRobot ``repo_id`` of a task x method x seed dataset (local only: never pushed)."""
    return f"touch2robot/{METHOD_TASK_ID.build(MethodTaskKey(method, task, str(seed)))}"


def policy_training(layout: DataLayout, method: str, task: str, seed: int, config: str) -> Path:
    """The training folder (LeRobot checkpoints, MLflow run id) of one task x method x seed's policy."""
    return layout.policies / POLICY_RUN_ID.build(PolicyRunKey(method, task, str(seed), config[:12]))


# --------------------------------------------------------------------------- readiness


def glove_sessions(lake: Path) -> list[dict]:
    """The ingested glove sessions (``recordings`` rows), in file-name order (stable across runs)."""
    rows = recording_rows(Path(lake)).to_pylist()
    return sorted(
        (r for r in rows if r["status"] == RecordingStatus.INGESTED and r["kind"] == RecordingKind.GLOVE_SESSION),
        key=lambda r: r["file_name"],
    )


def demonstration(recording: Mapping[str, Any]) -> dict:
    """What a stage needs of one demonstration: recording id, task, subject."""
    return {k: recording[k] for k in ("recording_id", "task", "subject")}


def retargeted_demonstrations(lake: Path, tasks: Iterable[str] | None = None) -> list[dict]:
    """The glove sessions (of ``tasks``, default all) with retargeted rows, as :func:`demonstration`
    dicts in file-name order."""
    wanted = None if tasks is None else set(tasks)
    return [
        demonstration(r)
        for r in glove_sessions(lake)
        if (wanted is None or r["task"] in wanted) and RETARGETED.path(lake, RecordingKey(r["recording_id"])).is_file()
    ]


def taught_demonstrations(lake: Path, method: str, seed: int) -> list[dict]:
    """The retargeted demonstrations whose task has rollouts of the teacher of ``method`` of sweep seed ``seed``."""
    return [r for r in retargeted_demonstrations(lake) if teacher_rollouts(lake, method, r["task"], seed).is_file()]


# --------------------------------------------------------------------------- content digests


def file_digest(path: str | Path) -> str:
    """sha256 of a file's content: a path alone is no cache key."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def references_digest(lake: Path, recordings: Iterable[Mapping[str, str]]) -> str:
    """Content hash of every lake file the references of ``recordings`` read: a new retargeting
    or new contacts retrain the teacher, an unchanged lake hits the cache."""
    h = hashlib.sha256()
    for r in sorted(recordings, key=lambda r: r["recording_id"]):
        for p in reference_files(lake, r):
            h.update(p.name.encode())
            h.update(file_digest(p).encode() if p.is_file() else b"missing")
    return h.hexdigest()


def folder_digest(folders: Iterable[Path]) -> str:
    """sha256 over the names and contents of the Parquet files in ``folders``: a cache key that
    changes when a file is written with other rows, added or removed, and not when one is rewritten
    with the same rows. Hidden files (a write in progress) are not part of it."""
    h = hashlib.sha256()
    for folder in folders:
        h.update(folder.as_posix().encode())
        for p in sorted(folder.rglob("*.parquet")) if folder.is_dir() else []:
            if not p.name.startswith("."):
                h.update(f"{p.relative_to(folder).as_posix()}\0{file_digest(p)}\n".encode())
    return h.hexdigest()
