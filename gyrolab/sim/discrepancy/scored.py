"""A candidate as a channel scored it: one record type for every channel (the
``steps[].candidates`` entries of ``discrepancy.json``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class Scored:
    """One candidate's score against the current model on its channel's data."""

    effect: str
    channel: str
    score: float
    significant: bool
    evidence: dict[str, Any]
    theta: float | None = None
    """Gyro terms: the shape value its own scan chose (added with it)."""
    form: dict[str, float] = field(default_factory=dict)
    """Gyro terms: the other shape values of the candidate's fit, added with it: its wider
    form's, and the model's own shapes where they were scanned again with it."""
    fit: Any = None
    """Gyro terms: the candidate's own fit (base + it), for the look-alike tests."""

    def to_json(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "channel": self.channel,
            "score": self.score,
            "significant": self.significant,
            "evidence": self.evidence,
        }
