"""One fit: a dataset's feature table and a split -> every model kind fitted, chosen on the validation presses,
refitted on every labelled press -> one artifact.

Every verb that trains goes through here: :func:`prepare` -> :class:`TrainingData`; each model kind
(:mod:`sonicskin.kinds`) fits itself on :meth:`TrainingData.folds`, then is refitted on the training and validation
sessions together (:meth:`TrainingData.refit`); :func:`write_artifact` seals ``skin.json``.  Only ``split.train`` and
``split.val`` rows are read for fitting (``tests/test_selection.py`` checks it)."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from . import kinds
from .artifact import PROBE_ROWS, atomic_artifact, skin_json
from .dataset import Dataset, FeatureTable, Split, wall_record
from .drift import DriftError, DriftTracker
from .feature_cache import load_features_cached
from .features import MIN_REST_CHIRPS, FeatureSpec, quiet_mask, rest_beta, training_targets, usable_bins
from .ospa import select_bins
from .selection import press_ids, press_passes, save_learning_curve, select_gamma_on_table

__all__ = ["TrainingData", "prepare", "fit_models", "write_artifact", "fit_artifact", "build_svm_artifact",
           "summary_lines", "selection_lines"]


@dataclasses.dataclass
class TrainingData:
    """What every fit step reads: one dataset's chirps, its split and the model inputs of every chirp."""

    dataset: Dataset
    table: FeatureTable
    split: Split
    spec: FeatureSpec
    X: np.ndarray          # (n, len(spec.bins)) float32 model inputs
    cls: np.ndarray        # (n,) layout row of the touched location, n_locations = no touch
    force: np.ndarray      # (n,) float32 N (NaN: no force sensor)
    usable: np.ndarray     # (n,) bool: may train (light presses below min_force_n may not)
    min_force_n: float = 0.5
    selection: dict = dataclasses.field(default_factory=dict)  # choices made so far (gamma: the SVM's selection)
    rig: Any = None        # the rig the artifact declares (default: the dataset's)
    n_svm: int | None = None  # the SVM reads the first n_svm bins (OSPA's gamma for it); default: every bin
    options: dict = dataclasses.field(default_factory=dict)  # how prepare() made it (refit() makes it again)
    refit_follows: bool = False  # fit_models refits every model on training + validation next (a choice may skip work)

    def __post_init__(self):
        if self.rig is None:
            self.rig = self.dataset.rig
        if self.n_svm is None:
            self.n_svm = len(self.spec.bins)

    def narrow(self, k: int) -> TrainingData:
        """The same chirps on the first ``k`` bins only (OSPA order: the best ``k``), e.g. the SVM's gamma."""
        k = int(min(k, len(self.spec.bins)))
        if k == len(self.spec.bins):
            return self
        return dataclasses.replace(self, spec=dataclasses.replace(self.spec, bins=self.spec.bins[:k]), X=self.X[:, :k],
                                   n_svm=min(self.n_svm, k))

    @property
    def layout(self):
        return self.dataset.layout

    @property
    def n_locations(self) -> int:
        return len(self.dataset.layout)

    def rows(self, part: str) -> np.ndarray:
        """Usable chirps of the ``train``, ``val`` or ``test`` sessions."""
        return self.split.mask(self.table, part) & self.usable

    @property
    def quiet(self) -> np.ndarray:
        return quiet_mask(self.table)

    def folds(self) -> tuple[list[tuple[np.ndarray, np.ndarray]], str]:
        """Where a choice is validated: ``([(fit rows, held-out rows)], how)``; ``[]`` when nothing can validate."""
        train, val = self.rows("train"), self.rows("val")
        if val.any():
            return ([(train, val), (val, train)], f"validation on {', '.join(self.split.val)} (and fitted there, scored "
                                                  f"on {', '.join(self.split.train)})")
        t = self.table
        seg = t["segment"] if "segment" in t.labels else None
        passes = press_passes(np.where(train, press_ids(t["location"], t["session"], seg), -1), t["location"])
        if passes.max() >= 1:
            last = passes == passes.max()
            return [(train & ~last, train & last)], "held-out last pass"
        return [], "one press per location and no validation session"

    def refit(self) -> TrainingData:
        """The same chirps with the validation sessions joined to the training ones, fitted again with ``selection``'s choices."""
        if not self.split.val:
            return self
        split = Split(self.split.train + self.split.val, (), self.split.test)
        o = {**self.options, "n_bins": self.n_svm, "mode": self.spec.mode, "alpha_s": self.spec.alpha_s, "beta_s": self.spec.beta_s}
        d = prepare(self.dataset, split=split, table=self.table, rig=self.rig, min_force_n=self.min_force_n, progress=False, **o)
        d.selection = dict(self.selection)
        d.options["refit_of"] = self.split.to_dict()
        return d


def prepare(data: str | Path | Dataset, *, n_bins: int | None = 300, mode: str = "relative", train_sessions=None,
            val_sessions=None, test_subjects=None, split: Split | None = None, table: FeatureTable | None = None,
            bins=None, alpha_s: float = FeatureSpec.alpha_s, beta_s: float = FeatureSpec.beta_s, rig=None,
            min_force_n: float = 0.5, allow_no_test: bool = False, wide: bool = False, progress: bool = True, log=None) -> TrainingData:
    """Load a dataset, split it by session or subject, choose OSPA's bins on the training split and build the model
    inputs of every chirp.  ``n_bins=None`` chooses gamma by validation; ``bins`` gives the band bins instead (the
    no-OSPA ablation); ``wide``: the inputs are every usable bin in OSPA's order, the SVM reads the first ``n_bins``."""
    ds = data if isinstance(data, Dataset) else Dataset(data)
    t = table if table is not None else load_features_cached(ds, progress=progress)
    if split is None:
        split = Split.make(t, train_sessions=train_sessions, val_sessions=val_sessions, test_subjects=test_subjects,
                           allow_no_test=allow_no_test)
    if unfinished := ds.unfinished([*split.train, *split.val]):
        warnings.warn(f"{ds.root}: session(s) {', '.join(unfinished)} stopped before they were complete (no session.json): "
                      f"training on what they hold; `sonicskin record --resume` (or `simulate --resume`) records the rest",
                      stacklevel=2)
    selection: dict = {}
    tr = t.select(split.mask(t, "train"))
    given_bins = bins
    if bins is None:
        if n_bins is None:  # validated on the training and validation sessions only
            selection[kinds.BASELINE] = select_gamma_on_table(t, ds.rig, train_sessions=list(split.train),
                                                     val_sessions=list(split.val), mode=mode, min_force_n=min_force_n,
                                                     log=log or (lambda m: warnings.warn(m, stacklevel=2)))
            n_bins = selection[kinds.BASELINE]["params"]["n_bins"]
        n_svm = usable_bins(ds.rig, n_bins, log=log)  # OSPA's gamma (the paper's 300 for None), clamped with a warning
        bins = select_bins(tr, ds.rig, int(ds.rig.allowed_mask.sum()) if wide else n_svm, min_force_n)
    else:
        n_svm = len(bins)
    spec = FeatureSpec(tuple(int(b) for b in bins), mode, beta_s=float(beta_s), alpha_s=float(alpha_s))
    if mode == "relative":
        beta0 = spec.reference(ds.rig.chirps_per_s).beta
        beta = rest_beta(t, beta0)
        if beta is None:
            msg = (f"{ds.root}: not every session has {MIN_REST_CHIRPS} consecutive hands-off chirps for Alg. 2's "
                   f"no-touch reference (touches only?); using absolute features (mode absolute)")
            warnings.warn(msg, stacklevel=2)
            spec = dataclasses.replace(spec, mode="absolute")
        elif beta < beta0:
            spec = dataclasses.replace(spec, beta_s=beta / ds.rig.chirps_per_s)
    X = spec.transform(t, ds.rig.chirps_per_s)
    cls, usable = training_targets(t, ds.layout, min_force_n)
    return TrainingData(ds, t, split, spec, X, cls, t["force_n"].astype(np.float32), usable, min_force_n, selection,
                        rig or ds.rig, n_svm, {"wide": wide, "bins": given_bins})


# -- the artifact ---------------------------------------------------------------------------------------------------
def _check_rows(data: TrainingData, n: int = 512) -> np.ndarray:
    """Parity and probe rows: training chirps only (nothing of a test session reaches the artifact)."""
    Xc = data.X[data.rows("train")]
    rng = np.random.default_rng(0)
    return Xc[rng.choice(Xc.shape[0], size=min(n, Xc.shape[0]), replace=False)]


#: The largest |stretch| of the channel's frequency axis an artifact is said to be trained for (drift tracking warns
#: beyond it: "record a new session").  On the simulated drift-2h link, warped accuracy stayed within 2.1 points of
#: the no-warm-up control up to 1.5e-3 (about 4.3 K on CFRP; benchmarks/bench_drift.py, design seeds 3 and 77).
TRAINED_STRETCH = 1.5e-3


def drift_reference(data: TrainingData, log=None) -> dict | None:
    """Drift tracking's training reference: the mean dB spectrum of the training sessions' rest (``None`` without)."""
    rest = data.quiet & data.split.mask(data.table, "train")
    if rest.sum() < 2:
        return None
    material = ((data.dataset.meta.get("source") or {}).get("scenario") or {}).get("material")
    try:
        tr = DriftTracker.from_rig(data.rig, data.table.X[rest].mean(axis=0), trained_stretch=TRAINED_STRETCH,
                                   material=material if isinstance(material, str) else None)
    except DriftError as e:
        if log:
            log(f"note: no drift tracking ({e})")
        return None
    return tr.to_dict()


def fit_models(data: TrainingData, wanted=(kinds.BASELINE,), *, refit: bool = True, options: dict | None = None, log=print
               ) -> tuple[TrainingData, dict[str, kinds.Fitted]]:
    """Fit the model kinds ``wanted`` (and those they require), then with a validation session and ``refit`` again."""
    options = options or {}
    order = kinds.fit_order(wanted)
    fits: dict[str, kinds.Fitted] = {}
    if refit and data.split.val:
        data = dataclasses.replace(data, refit_follows=True)
    for name in order:
        fits[name] = kinds.get(name, fitting=True).fit(data, fitted=fits, log=log, **options.get(name, {}))
    if not (refit and data.split.val):
        return data, fits
    final = data.refit()
    log(f"refitting on {', '.join(final.split.train)}: every labelled press (the estimates above are from the held-out pass)")
    refits: dict[str, kinds.Fitted] = {}
    for name in order:
        refits[name] = kinds.get(name, fitting=True).fit(final, fitted=refits, selection=fits[name].selection, log=log,
                                                         **options.get(name, {}))
    return final, refits


def write_artifact(data: TrainingData, out: str | Path, fits: dict[str, kinds.Fitted], *, training: dict | None = None,
                   learning_curve: bool = False, drift: bool = True, log=print) -> dict:
    """Export every fitted model into ``out`` with a sealed ``skin.json``, ``out`` replaced as a whole; returns the document."""
    if not fits:
        raise ValueError("write_artifact needs at least one fitted model")
    out = Path(out)
    check = _check_rows(data)
    sel = dict(data.selection)
    models: dict[str, dict] = {}
    times = {}
    with atomic_artifact(out) as tmp:
        for name, f in fits.items():
            kind = kinds.get(name, fitting=True)
            parity = kind.export(f, tmp / kind.file, check[:, :f.n_in])
            models[name] = {"file": kind.file, "kind": kind.graph, "n_in": int(f.n_in), "n_locations": data.n_locations,
                            "parity": parity, **f.entry}
            sel.update(f.selection)
            times[f"{name}_train_time_s"] = f.fit_s
        for name, (rmse, const) in force_checks(sel).items():  # a force no better than a constant is marked so
            if name in models:
                models[name]["force_reliable"] = bool(rmse < const)
        split = data.split.to_dict()
        refit = data.options.get("refit_of")
        skin = skin_json(tmp, rig=data.rig.to_dict(), layout=data.layout.to_dict(), spec=data.spec,
                         min_force_n=data.min_force_n,
                         training={"data": str(Path(data.dataset.root).resolve()), "split": refit or split, **times,
                                   **({"refit": True} if refit else {}), "wall": wall_record(
                                       data.dataset.meta.get("source"), data.dataset.rig, data.layout), **(training or {})},
                         models=models, probe_inputs=check[:PROBE_ROWS], selection=sel,
                         drift=drift_reference(data, log) if drift else None)
        if learning_curve and save_learning_curve(sel.get(kinds.BASELINE), tmp / "learning_curve.png",
                                                  title=f"{Path(data.dataset.root).name}: SVM accuracy vs presses per location"):
            log(f"wrote {out}/learning_curve.png")
    return skin


def fit_artifact(data: TrainingData, out: str | Path, wanted=(kinds.BASELINE,), *, refit: bool = True, options: dict | None = None,
                 training: dict | None = None, learning_curve: bool = False, log=print) -> dict:
    """The whole fit (:func:`fit_models`) and its artifact (:func:`write_artifact`)."""
    final, fits = fit_models(data, wanted, refit=refit, options=options, log=log)
    return write_artifact(final, out, fits, training=training, learning_curve=learning_curve, log=log)


def selection_lines(sel: dict | None) -> list[str]:
    """What every training verb prints about its choices: each kind's lines, then whether each force beats a constant."""
    return [line for name in kinds.names() for line in kinds.get(name).selection_lines(sel or {})] + [
        f"{name} force {'reliable' if r < c else 'UNRELIABLE'}: validated RMSE {r:.2f} N, a constant's {c:.2f} N" +
        ("" if r < c else " (its events say force_reliable false; no wrench is published)")
        for name, (r, c) in force_checks(sel).items()]


def force_checks(sel: dict | None) -> dict[str, tuple[float, float]]:
    """Per kind in ``sel`` whose force was validated: its RMSE and a constant's (the training mean's), N."""
    sel = sel or {}
    const = (sel.get("force") or {}).get("constant_rmse_n")
    rmse = {n: kinds.get(n).force_rmse(sel) for n in kinds.names() if any(k in sel for k in kinds.get(n).selection_keys)}
    return {n: (r, const) for n, r in rmse.items() if r is not None and const is not None}


def summary_lines(out: str | Path, skin: dict) -> list[str]:
    """What every training verb prints about its artifact: selection, refit, and its files with size and parity."""
    out = Path(out)
    lines = selection_lines(skin.get("selection"))
    tr = skin["training"]
    if tr.get("refit"):
        sp = tr["split"]
        lines.append(f"deployed models refitted on {' + '.join(sp['train'] + sp['val'])} (every labelled press; the "
                     f"estimates above are from the held-out pass)")
    files = [f"{m['file']} ({(out / m['file']).stat().st_size / 1e3:.0f} kB, parity max |d "
             f"{'logits' if 'max_abs_logits' in m['parity'] else 'scores'}| "
             f"{m['parity'].get('max_abs_logits', m['parity'].get('max_abs_scores', 0.0)):.1e})" for m in skin["models"].values()]
    lines.append(f"exported {out}: {', '.join(files)} and skin.json" if len(files) > 1 else f"wrote {out}/{files[0]} and skin.json")
    return lines


def build_svm_artifact(data, out, *, n_bins: int | None = None, mode: str = "relative", train_sessions=None,
                       min_force_n: float = 0.5, progress: bool = True, log=print, training: dict | None = None, **alg2) -> dict:
    """``fit-svm`` (and ``record``): an SVM-only artifact, torch-free, trained on every session (or ``train_sessions``),
    gamma chosen by validation on their presses unless ``n_bins`` (``alg2``: :func:`prepare`'s ``alpha_s``/``beta_s``;
    ``training``: added to skin.json's ``training``, e.g. the arm's ``link`` it was trained for)."""
    ds = data if isinstance(data, Dataset) else Dataset(data)
    d = prepare(ds, n_bins=n_bins, mode=mode, train_sessions=list(train_sessions or ds.sessions), val_sessions=[],
                min_force_n=min_force_n, allow_no_test=True, progress=progress, log=log, **alg2)
    skin = fit_artifact(d, out, learning_curve=True, training=training, log=log)
    for line in summary_lines(out, skin):
        log(line)
    return skin
