"""The validator's scores on disk, so a restarted validator still has them (JSON lines, no ROS).

One line per scored pull, appended and flushed as it is scored. A line cut short by a crash (the
last one) or otherwise unreadable is skipped and counted, never fatal.
"""
from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import List, Tuple

from .errors import CorrectionError
from .scoring import PullScoreResult


@dataclass(frozen=True)
class LoggedScore:
    """One pull's score as the validator published it."""

    pull_id: int
    set_id: int
    start_ns: int
    status: int
    detail: str
    result: PullScoreResult


class ScoreLog:
    """Append-only score file at ``path`` (created with its folder on first write)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def check_writable(self) -> None:
        """CorrectionError unless the file can be appended to (its folder is made if missing): a state_file that
        cannot be written is refused when the validator starts, not found out at its first score."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with self.path.open('a', encoding='utf-8'):
                pass
        except OSError as exc:
            raise CorrectionError(f'state_file {str(self.path)!r} cannot be written ({exc.strerror or exc}); '
                                  'expected a file in a folder this user may write') from None

    def load(self) -> Tuple[List[LoggedScore], int]:
        """(the scores in the file, in order; the number of unreadable lines skipped)."""
        if not self.path.exists():
            return [], 0
        try:
            text = self.path.read_text(encoding='utf-8')
        except OSError as exc:
            raise CorrectionError(f'score log {str(self.path)!r} cannot be read: {exc}') from None
        out, bad = [], 0
        for line in text.splitlines():
            try:
                d = json.loads(line)
                out.append(LoggedScore(int(d['pull_id']), int(d['set_id']), int(d['start_ns']), int(d['status']),
                                       str(d['detail']), PullScoreResult(**d['result'])))
            except (ValueError, KeyError, TypeError):
                bad += 1
        return out, bad

    def append(self, score: LoggedScore) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        record = {**{f.name: getattr(score, f.name) for f in dataclasses.fields(score) if f.name != 'result'},
                  'result': dataclasses.asdict(score.result)}
        with self.path.open('a', encoding='utf-8') as fh:
            fh.write(json.dumps(record) + '\n')
            fh.flush()
            os.fsync(fh.fileno())
