"""Rig files: reading and checking them (schemas/rig.py says what they hold), writing the default one, and
finding the rig of each recording.

Every rig is checked before any recording is ingested: a rig file that does not validate, two files that
define one rig name differently, or a rig whose stream topic is in none of the recordings that name it stop
the ingest with the file and field named (a rig is configuration: one wrong topic name would otherwise
quarantine every recording it covers, one by one)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import yaml
from pydantic import ValidationError

from schemas.messages import STREAMS_BY_KIND
from schemas.rig import DEFAULT_RIG, RIG_SUFFIX, Rig, compact_ranges
from touch2robot import lake as lake_io
from touch2robot.config import ProfileError, UniqueKeyLoader, refuse_bools_as_numbers
from touch2robot.ingest.sources import SourceError, peek, read_sidecar, session_metadata, sidecar_path


class RigError(ValueError):
    """A rig file that cannot be used; the message names the file and the field."""


def load_rig(path: Path) -> Rig:
    """A rig file's rig, or RigError naming the file and field."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise RigError(f"rig file {path}: cannot be read ({type(e).__name__}: {e})") from None
    return parse_rig(text, str(path))


def parse_rig(text: str, origin: str) -> Rig:
    try:
        data = yaml.load(text, Loader=UniqueKeyLoader)
    except yaml.YAMLError as e:
        raise RigError(f"rig file {origin}: not valid YAML ({e})") from None
    if not isinstance(data, dict):
        raise RigError(
            f"rig file {origin}: expected a mapping (name, streams, glove, robot), got {type(data).__name__}"
        )
    try:
        refuse_bools_as_numbers(Rig, data, f"rig file {origin}", ())
        return Rig.model_validate(data)
    except ProfileError as e:
        raise RigError(str(e)) from None
    except ValidationError as e:
        raise RigError(f"rig file {origin}: {'; '.join(_field_error(err) for err in e.errors())}") from None


def _field_error(err: Mapping) -> str:
    """pydantic's error as ``glove.fingertip.T2.taxels: message``: a validator's own message may start with
    the path below its model's field."""
    loc = ".".join(str(part) for part in err["loc"])
    message = str(err["msg"]).removeprefix("Value error, ")
    head, sep, rest = message.partition(": ")
    if sep and " " not in head and head:
        return f"{loc + '.' if loc else ''}{head}: {rest}"
    return f"{loc}: {message}" if loc else message


def rig_yaml(rig: Rig) -> str:
    """A rig file's text: the rig with its taxel lists as ranges."""
    data = rig.model_dump(mode="json", exclude_none=True)
    for group in ("fingertip", "palm"):
        for name, region in data["glove"][group].items():
            region["taxels"] = compact_ranges(tuple(getattr(rig.glove, group)[name].taxels))
    header = (
        f"# touch2robot rig file: give a recording's session field rig: {rig.name} to read it with this rig.\n"
        "# streams: topic and rate per stream; glove: taxels per region (indices or inclusive ranges 'a-b'),\n"
        "# optional threshold_k per region; robot: joint names in the contract's order, sensor channels.\n"
    )
    return header + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120)


def write_rig(rig: Rig, folder: Path) -> Path:
    """Write ``<folder>/<name>.rig.yaml`` atomically (unchanged content is left as it is)."""
    path = Path(folder) / f"{rig.name}{RIG_SUFFIX}"
    text = rig_yaml(rig)
    if not path.is_file() or path.read_text() != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        lake_io.replace_text(text, path)
    return path


@dataclass(frozen=True)
class Rigs:
    """The rigs an ingest knows, by name, and the file each came from (None: built in)."""

    by_name: dict[str, Rig]
    files: dict[str, Path | None]

    def definitions(self) -> dict[str, dict]:
        """Every rig as plain data (a Prefect task's input: the ingest's cache key follows the rigs)."""
        return {name: rig.model_dump(mode="json") for name, rig in sorted(self.by_name.items())}


def find_rigs(folder: Path, extra: Iterable[Path] = ()) -> Rigs:
    """The built-in default rig, every ``*.rig.yaml`` at the top of ``folder`` and each file of ``extra``. A
    file may redefine the default's name; two files naming one rig differently are refused."""
    by_name: dict[str, Rig] = {DEFAULT_RIG.name: DEFAULT_RIG}
    files: dict[str, Path | None] = {DEFAULT_RIG.name: None}
    found = sorted(p for p in Path(folder).glob(f"*{RIG_SUFFIX}") if p.is_file()) if Path(folder).is_dir() else []
    for path in [*found, *(Path(p) for p in extra)]:
        if not path.is_file():
            raise RigError(f"rig file {path} does not exist")
        rig = load_rig(path)
        earlier = files.get(rig.name)
        if earlier is not None and earlier.resolve() != path.resolve() and by_name[rig.name] != rig:
            raise RigError(f"rig file {path}: name {rig.name!r} is also defined, differently, by {earlier}")
        by_name[rig.name], files[rig.name] = rig, path
    return Rigs(by_name, files)


def rigs_from(definitions: Mapping[str, Mapping]) -> dict[str, Rig]:
    return {name: Rig.model_validate(d) for name, d in definitions.items()}


def check_topics(recordings: Iterable[Path], rigs: Rigs, session: Mapping[str, str]) -> None:
    """Refuse (RigError) a rig file whose stream topic is in none of the recordings of a kind that name it.
    The built-in rig is the contract itself: a recording lacking one of its topics is that recording's fault
    and is quarantined by ingest, as is a recording whose container cannot be read."""
    seen: dict[tuple[str, str], list[tuple[Path, set[str]]]] = {}
    for path in recordings:
        try:
            topics, record, custom = peek(path)
            metadata = session_metadata(record, custom, read_sidecar(sidecar_path(path)), session)
        except (OSError, SourceError):
            continue
        name, kind = metadata.get("rig") or DEFAULT_RIG.name, metadata.get("kind", "")
        if rigs.files.get(name) is not None and kind in STREAMS_BY_KIND:
            seen.setdefault((name, kind), []).append((path, topics))
    for (name, kind), found in sorted(seen.items()):
        rig = rigs.by_name[name]
        for stream in STREAMS_BY_KIND[kind]:
            topic = rig.topic(stream)
            if not any(topic in topics for _, topics in found):
                path, topics = found[0]
                raise RigError(
                    f"rig file {rigs.files[name]}: streams.{stream}.topic: {topic} is in none of the {len(found)} "
                    f"{kind} recording(s) that name rig {name!r} ({path.name} has "
                    f"{', '.join(sorted(topics)) or 'no topics'})"
                )


def checked_rigs(folder: Path, extra: Iterable[Path | str], session: Mapping[str, str]) -> Rigs:
    """The rigs of an ingest of ``folder``, each checked against the recordings that name it (RigError)."""
    from touch2robot.ingest.scan import find_recordings

    rigs = find_rigs(Path(folder), [Path(p) for p in extra])
    check_topics(find_recordings(Path(folder)).recordings if Path(folder).is_dir() else [], rigs, session)
    return rigs
