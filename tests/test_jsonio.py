"""The one JSON conversion (sonicskin.jsonio) and the one t interval (sonicskin.metrics): known answers."""

import json
import math

import numpy as np
import pytest

from sonicskin.jsonio import OMIT, json_safe
from sonicskin.metrics import t_interval


def test_json_safe_gives_strict_plain_json():
    doc = {1: np.float32(0.5), "a": (np.int64(3), np.bool_(True)), "arr": np.array([[1.0, np.nan]]), "inf": -math.inf}
    assert json_safe(doc) == {"1": 0.5, "a": [3, True], "arr": [[1.0, None]], "inf": None}
    assert json.dumps(json_safe(doc), allow_nan=False)  # no NaN literal left
    kept = json_safe(doc, keep_nonfinite=True)  # a writer that names the field holding it afterwards
    assert math.isnan(kept["arr"][0][1]) and kept["inf"] == -math.inf
    assert type(json_safe(np.float64(2.0))) is float and type(json_safe(np.int32(2))) is int


def test_json_safe_convert_hook_replaces_or_omits():
    class Mean(float):
        pass

    def convert(o):
        return {"mean": float(o)} if isinstance(o, Mean) else OMIT if callable(o) else o

    got = json_safe({"m": Mean(2.0), "f": len, "xs": [Mean(1.0), print, np.nan]}, convert=convert)
    assert got == {"m": {"mean": 2.0}, "xs": [{"mean": 1.0}, None]}


def test_t_interval_known_answer():
    x = np.array([0.03, 0.01, 0.04])
    half = 4.302652729911275 * x.std(ddof=1) / np.sqrt(3)  # t(0.975, 2 dof)
    assert t_interval(x) == pytest.approx([x.mean() - half, x.mean() + half])
    lo90, hi90 = t_interval(x, level=0.90)
    assert x.mean() - half < lo90 < hi90 < x.mean() + half  # a narrower level, a narrower interval
    assert t_interval(x, (0.02, 1.0))[0] == 0.02
    assert all(math.isnan(v) for v in t_interval([1.0]))
