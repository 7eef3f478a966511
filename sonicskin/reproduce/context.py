"""What the experiments share: the simulated datasets of one simulator seed, and each model fitted, exported and
replayed as deployed once per (dataset, training chirps, bins, reference settings, seed)."""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np

from .. import kinds
from ..compare import replay_sessions, stream_metrics
from ..dataset import Dataset, FeatureTable, Split
from ..feature_cache import load_features_cached
from ..features import FeatureSpec
from ..fit import prepare, write_artifact
from ..head import Predictions
from ..kinds import BASELINE, CLOSED_FORM, NETWORK
from ..ospa import select_bins
from ..plots import pyplot as plt
from ..rig import Rig
from ..runtime import SkinRuntime
from ..sim.generate import simulate_dataset
from ..sim.scenario import Scenario

__all__ = ["Context", "datasets", "MATERIALS", "USES", "QUICK_SIZE", "MODEL", "net_available", "plt", "first_session_split",
           "deployed_data"]

MATERIALS = ("cfrp", "aluminium", "abs", "glass", "wood")
# --quick: every press half as long (1.5 s of 3 s) and 5 s of moving no-touch (of 10 s), on top of each
# experiment's fewer sessions: about 0.6x the chirps of the same sessions in full.
QUICK_SIZE = {"touch_s": 1.5, "moving_s": 5.0}
MODEL = {k: kinds.labels()[k] for k in (BASELINE, NETWORK)}  # the paper's model and ours
#: the datasets each experiment reads (``--only`` simulates these only)
USES = {"fig6b": ("moving",), "fig11": ("moving",), "fig12": ("drift-2h", "drift-2months"), "fig13": ("stationary",),
        "table1": ("stationary", "moving", "multi-person"),
        "fig16": tuple(f"two-points-{m}" for m in MATERIALS) + ("plate-aluminium",)}
#: Alg. 2 never refreshing: the longest ``alpha`` an artifact holds (115 days, longer than any simulated stream)
NEVER_S = 1e7


def net_available() -> bool:
    try:
        import lightning  # noqa: F401
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


def datasets(quick: bool) -> dict[str, tuple[str, dict]]:
    """Every simulated dataset of the experiments: name -> (scenario, what the experiments change in it)."""
    n_people = 6 if quick else 12
    d = {"moving": ("moving", {"sessions": 3}), "stationary": ("stationary", {"sessions": 3}),
         "multi-person": ("multi-person", {"sessions": n_people, "subjects": list(range(n_people))}),
         # quick: power-on training, then 30 / 60 / 90 / 120 min (two simulator seeds must stay CI-sized)
         "drift-2h": ("drift-2h", {"sessions": 5, "session_interval_s": 1800} if quick else {}),
         "drift-2months": ("drift-2h", {"sessions": 5 if quick else 10, "session_interval_s": 6.37 * 86400, "start_s": 3600,
                                        "temperature": {"ambient_c": 23.0, "warmup_c": 0.0, "warmup_tau_s": 5400.0,
                                                        "swing_c": 3.0, "swing_period_s": 86400.0}, "seed": 31})}
    for mat in MATERIALS:
        d[f"two-points-{mat}"] = ("two-points", {"material": mat, "sessions": 2 if quick else 3, "repeats": 3 if quick else 6})
    d["plate-aluminium"] = ("plate-aluminium", {"sessions": 2 if quick else 3})
    return d


def _key(*parts) -> str:
    h = hashlib.blake2b(digest_size=12)
    for p in parts:
        h.update(p.tobytes() if isinstance(p, np.ndarray) else repr(p).encode())
        h.update(b"\0")
    return h.hexdigest()


def mask_key(m: np.ndarray) -> str:
    return _key(np.packbits(np.asarray(m, bool)), len(m))


def sessions_of(t: FeatureTable, mask: np.ndarray) -> tuple[str, ...]:
    return tuple(str(s) for s in dict.fromkeys(t["session"][mask]))


class Context:
    """One simulator seed's datasets, feature tables, OSPA orders, artifacts and replays."""

    def __init__(self, out: Path, quick: bool, log, rig: Rig | None = None):
        self.out, self.quick, self.log = Path(out), quick, log
        self.rig = rig or Rig.load("jaco")
        self.epochs = 10 if quick else 60  # quick: the network checked to train, not tuned (full: 60)
        self.net = net_available()
        self.figs: list[Path] = []
        self.sim_seed = 0      # which simulated rig: seed 0 is the scenarios' own link and sessions
        self.plots = True      # figures are drawn for the first simulator seed only
        self.progress = True   # progress bars of simulation (off in worker processes)
        self._tables: dict = {}
        self._orders: dict = {}
        self._data: dict = {}
        self._svm: dict = {}
        self._arts: dict = {}
        self._preds: dict = {}
        self.shared = {"fits": 0, "fits_reused": 0, "replays_reused": 0}

    @property
    def kinds(self) -> list[str]:
        return [BASELINE, NETWORK] if self.net else [BASELINE]

    def save(self, fig, name: str, res: dict) -> dict:
        """Write the figure (the first simulator seed draws it) and return the results."""
        if not self.plots:
            plt().close(fig)
            return res
        fig.tight_layout()
        fig.savefig(self.out / name, dpi=100)
        plt().close(fig)
        self.figs.append(self.out / name)
        return res

    # -- data ------------------------------------------------------------------------------------------------------
    def dataset(self, name: str) -> Dataset:
        """The simulated dataset ``name`` of the current seed ``k``: link ``link_seed + k``, presses and noise ``seed + 1000 k``."""
        path = self.out / "data" / ("" if self.rig.name == "jaco-link" else self.rig.name) / (
            name if self.sim_seed == 0 else f"{name}-seed{self.sim_seed}")
        if not (path / "dataset.json").is_file() or not all((path / s / "session.json").exists() for s in Dataset(path).sessions):
            scenario, over = datasets(self.quick)[name]
            d = {**Scenario.load(scenario).to_dict(), **(QUICK_SIZE if self.quick else {}), **over, "name": name}
            d["seed"] = int(d["seed"]) + 1000 * self.sim_seed
            d["link_seed"] = int(d["link_seed"]) + self.sim_seed
            simulate_dataset(Scenario.from_dict(d), self.rig, path, mode="overwrite", progress=self.progress, log=self.log)
        return Dataset(path)

    def table(self, ds: Dataset) -> FeatureTable:
        """The dataset's feature table, loaded once per process (``load_features_cached`` keeps it on disk)."""
        key = str(ds.root)
        if key not in self._tables:
            self._tables[key] = load_features_cached(ds, progress=False)
        return self._tables[key]

    def bins(self, ds: Dataset, t: FeatureTable, train: np.ndarray, n: int) -> np.ndarray:
        """OSPA's first ``n`` bins on the training rows (one stable order per dataset and rows: every gamma a prefix)."""
        key = (str(ds.root), mask_key(train))
        have = self._orders.get(key)
        if have is None or len(have) < n:
            self._orders[key] = have = select_bins(t.select(train), ds.rig, max(n, min(1000, int(ds.rig.allowed_mask.sum()))))
        return have[:n]

    def data(self, ds: Dataset, *, train: np.ndarray, bins, alpha_s: float = FeatureSpec.alpha_s, keep: np.ndarray | None = None,
             notches: bool = True, n_svm: int | None = None):
        """The :class:`~sonicskin.fit.TrainingData` of the sessions holding ``train`` rows on ``bins``."""
        t = self.table(ds)
        bins = np.asarray(bins, np.int64)
        key = _key(str(ds.root), mask_key(train), bins, alpha_s, None if keep is None else mask_key(keep), notches, n_svm)
        if key not in self._data:
            split = Split(sessions_of(t, train), (), sessions_of(t, ~train))
            rig = ds.rig if notches else Rig.from_dict({**ds.rig.to_dict(), "pwm_hz": []})
            d = prepare(ds, table=t, split=split, bins=bins, alpha_s=alpha_s, rig=rig, log=lambda m: None)
            if keep is not None:
                d = dataclasses.replace(d, usable=d.usable & keep)
            if n_svm is not None:
                d.n_svm = int(min(n_svm, len(bins)))
            self._data[key] = (d, key)
        return self._data[key]

    # -- models ----------------------------------------------------------------------------------------------------
    def artifact(self, kind: str, data_key, *, seed: int = 0) -> Path:
        """The exported artifact of model ``kind`` trained on ``data_key``, each fitted and exported once."""
        data, dkey = data_key
        key = (dkey, kind, seed if kind == NETWORK else 0, self.epochs if kind == NETWORK else 0)
        if key in self._arts:
            self.shared["fits_reused"] += 1
            return self._arts[key]
        quiet = lambda m: None  # noqa: E731
        closed = self._svm.setdefault(dkey, {})
        if BASELINE not in closed:  # the paper's SVM, once per training data
            closed[BASELINE] = kinds.get(BASELINE).fit(data, fitted={}, select=False, log=quiet)
        path = self.out / "work" / f"seed{self.sim_seed}" / _key(*key)
        if kind == BASELINE:
            write_artifact(data, path, {BASELINE: closed[BASELINE]}, log=quiet)
        else:
            if CLOSED_FORM not in closed:
                closed[CLOSED_FORM] = kinds.get(CLOSED_FORM).fit(data, fitted=closed, log=quiet)
            net = kinds.get(NETWORK, fitting=True).fit(data, fitted=closed, seed=seed, epochs=self.epochs, log=quiet)
            write_artifact(data, path, {NETWORK: net}, log=quiet)
        self.shared["fits"] += 1
        self._arts[key] = path
        return path

    def predict(self, kind: str, data_key, test: np.ndarray, *, seed: int = 0, one_stream: bool = False) -> Predictions:
        """Predictions of the ``test`` rows replayed as the live loop runs (``one_stream``: sessions are gaps in one stream)."""
        data, dkey = data_key
        key = (dkey, kind, seed if kind == NETWORK else 0, mask_key(test), one_stream)
        if key in self._preds:
            self.shared["replays_reused"] += 1
            return self._preds[key]
        rt = SkinRuntime(self.artifact(kind, data_key, seed=seed), kind)
        t = data.table
        if one_stream:
            p = rt.replay(t.X, t["time_s"]).take(np.asarray(test, bool))
        else:
            p = replay_sessions(rt, t.select(test), sessions_of(t, test))
        self._preds[key] = p
        return p

    def evaluate(self, kind: str, data_key, test: np.ndarray, *, seed: int = 0, one_stream: bool = False) -> dict:
        """Localization, detection and force of the deployed model on the ``test`` rows, as ``compare`` reports them."""
        data = data_key[0]
        p = self.predict(kind, data_key, test, seed=seed, one_stream=one_stream)
        te = data.table.select(test)
        r = stream_metrics(p, te, data.layout)
        L = r["localization"]
        det = r["detection"]
        return {"accuracy": L["accuracy"], "within_2cm": L["within_2cm"], "within_3cm": L["within_3cm"],
                "errors_cm": np.asarray(r["errors_cm"]), "confusion": np.asarray(L["confusion"]),
                "force": r["force"] if r["force"].get("measurable", True) else {"rmse_n": float("nan"),
                                                                                 "sigma_n": float("nan"),
                                                                                 "xcorr": float("nan")},
                "false_touch": det.get("false_touch_rate", float("nan")),
                "missed_touch": det.get("missed_touch_rate", float("nan"))}


def first_session_split(ctx: Context, name: str):
    """A simulated dataset, its features, the one-shot split (the first session trains) and OSPA's 300 bins."""
    ds = ctx.dataset(name)
    t = ctx.table(ds)
    first = sorted(set(t["session"]))[0]
    train = t["session"] == first
    return ds, t, train, ~train, ctx.bins(ds, t, train, 300)


def deployed_data(ctx: Context, ds: Dataset, train: np.ndarray, **kw):
    """The two models' training data as deployed: the SVM on OSPA's first 300 bins, the network on every usable bin."""
    t = ctx.table(ds)
    return ctx.data(ds, train=train, bins=ctx.bins(ds, t, train, int(ds.rig.allowed_mask.sum())), n_svm=300, **kw)
