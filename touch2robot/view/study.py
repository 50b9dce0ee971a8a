"""The user-study protocol: participants, a counterbalanced condition order, the questionnaire after each
condition, and the ratings file that ``evaluate`` reads (long form: participant, condition, question,
rating, as ``touch2robot.stats.user_study`` expects)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from touch2robot.lake import replace_text
from touch2robot.stats import CONDITIONS, QUESTIONS, RATING_MAX, RATING_MIN

STUDY_RATINGS_FILE = "ratings_study.csv"
# The questionnaire, one 7-point item per question (1 = strongly disagree, 7 = strongly agree). The paper's
# Table X asks Q1..Q4 about the interface; these are the project's wording of its four items.
QUESTIONNAIRE: dict[str, str] = {
    "Q1": "I could tell when the robot hand touched the object.",
    "Q2": "I could tell which parts of the robot hand were in contact.",
    "Q3": "The feedback helped me make the contacts I intended.",
    "Q4": "I am confident the robot would reproduce my demonstration.",
}
assert tuple(QUESTIONNAIRE) == QUESTIONS
PARTICIPANT_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}")
RATINGS_COLUMNS = ("participant", "condition", "question", "rating", "position", "recording_id", "submitted_at")


class StudyError(ValueError):
    """Input the protocol refuses (a participant id, a rating); the message says which."""


def read_ratings(path: Path) -> pd.DataFrame:
    """The study's ratings so far (no file: none)."""
    if not path.is_file():
        return pd.DataFrame(columns=list(RATINGS_COLUMNS))
    return pd.read_csv(path, dtype={"participant": str})


def condition_order(n_before: int) -> tuple[str, str]:
    """Counterbalanced (AB/BA by arrival): the k-th participant starts with Visual Feedback when k is even."""
    return CONDITIONS if n_before % 2 == 0 else (CONDITIONS[1], CONDITIONS[0])


@dataclass
class Participant:
    """One participant's session: the order of the two conditions and the answers given so far."""

    participant: str
    order: tuple[str, str]
    recording_id: str
    answers: dict[str, dict[str, int]] = field(default_factory=dict)  # condition -> question -> rating

    @property
    def current(self) -> str | None:
        """The condition to run next, or None once both are answered."""
        return next((c for c in self.order if c not in self.answers), None)

    def answer(self, ratings: dict[str, int]) -> None:
        """The questionnaire of the current condition."""
        condition = self.current
        if condition is None:
            raise StudyError(f"participant {self.participant!r} has answered both conditions")
        if set(ratings) != set(QUESTIONS):
            raise StudyError(f"the questionnaire needs an answer to each of {', '.join(QUESTIONS)}")
        for question, rating in ratings.items():
            if not (isinstance(rating, int) and RATING_MIN <= rating <= RATING_MAX):
                raise StudyError(f"{question}: rating {rating!r} is not an integer in {RATING_MIN}..{RATING_MAX}")
        self.answers[condition] = dict(ratings)


def start(path: Path, participant: str, recording_id: str) -> Participant:
    """A new participant in the ratings file at ``path``, its conditions counterbalanced by arrival."""
    if not PARTICIPANT_PATTERN.fullmatch(participant):
        raise StudyError(
            f"participant id {participant!r}: 1-32 letters, digits, '_' or '-', starting with a letter or digit"
        )
    before = read_ratings(path)
    if participant in set(before["participant"].astype(str)):
        raise StudyError(f"participant {participant!r} is already in {path.name}: choose another id")
    return Participant(participant, condition_order(before["participant"].nunique()), recording_id)


def save(path: Path, session: Participant) -> int:
    """Append a participant's answers to the ratings file (rewritten whole, temp + rename: a crash leaves the
    old file). Returns the number of rows added."""
    if session.current is not None:
        raise StudyError(f"participant {session.participant!r} has not answered {session.current!r} yet")
    now = datetime.now(UTC).isoformat(timespec="seconds")
    rows = pd.DataFrame(
        [
            (
                session.participant,
                condition,
                question,
                rating,
                session.order.index(condition) + 1,
                session.recording_id,
                now,
            )
            for condition in session.order
            for question, rating in session.answers[condition].items()
        ],
        columns=list(RATINGS_COLUMNS),
    )
    before = read_ratings(path)
    if session.participant in set(before["participant"].astype(str)):
        raise StudyError(f"participant {session.participant!r} is already in {path.name}")
    path.parent.mkdir(parents=True, exist_ok=True)
    replace_text(pd.concat([before, rows], ignore_index=True).to_csv(index=False), path)
    return len(rows)
