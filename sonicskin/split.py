"""Which sessions train, validate and test (:class:`Split`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .dataset import FeatureTable

__all__ = ["Split"]


@dataclasses.dataclass(frozen=True)
class Split:
    """Which sessions train, validate and test.  Never a random split of chirps: sessions (or
    people, for leave-subjects-out) are the unit, so nothing of a test press leaks into training."""

    train: tuple[str, ...]
    val: tuple[str, ...]
    test: tuple[str, ...]

    @classmethod
    def make(cls, t: FeatureTable, *, train_sessions=None, val_sessions=None, test_subjects=None,
             allow_no_test: bool = False) -> Split:
        sessions = sorted(set(t["session"]))
        if test_subjects:
            subj = {s: set(t["subject"][(t["session"] == s) & (t["location"] >= 0)]) for s in sessions}
            test = [s for s in sessions if subj[s] & set(test_subjects)]
            rest = [s for s in sessions if s not in test]
            if not test or len(rest) < 2:
                raise ValueError(f"leave-subjects-out with test subjects {list(test_subjects)} leaves "
                                 f"{len(rest)} training and {len(test)} test sessions; need >= 2 and >= 1")
            return cls(tuple(rest[:-1]), tuple(rest[-1:]), tuple(test))
        train = list(train_sessions or sessions[:1])
        unknown = set(train) - set(sessions)
        if unknown:
            raise ValueError(f"training sessions {sorted(unknown)} are not in the dataset ({', '.join(sessions)})")
        rest = [s for s in sessions if s not in train]
        if val_sessions is None:
            val = rest[:1] if len(rest) >= 2 else []
        else:  # never a session that trains (validation would score training data) or one the data lacks
            val = list(val_sessions)
            for bad, why in ((sorted(set(val) - set(sessions)), "are not in the dataset"),
                             (sorted(set(val) & set(train)), "are training sessions too")):
                if bad:
                    raise ValueError(f"validation sessions {', '.join(map(str, bad))} {why} (train {', '.join(train)}); "
                                     f"validate on sessions that do not train: {', '.join(rest) or 'none left'}")
        test = [s for s in rest if s not in val]
        if not test and not allow_no_test:
            raise ValueError(f"no session left to test on (sessions {', '.join(sessions)}; train {', '.join(train)}; val "
                             f"{', '.join(val) or 'none'}): leave one out of the training and validation sessions")
        return cls(tuple(train), tuple(val), tuple(test))

    def mask(self, t: FeatureTable, part: str) -> np.ndarray:
        return np.isin(t["session"], getattr(self, part))

    def to_dict(self) -> dict:
        return {"train": list(self.train), "val": list(self.val), "test": list(self.test)}
