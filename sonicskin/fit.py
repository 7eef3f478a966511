"""One fit: a dataset's feature table and a split -> a fitted SVM head, a trained network -> one artifact.

Every verb that trains goes through here: ``fit-svm``, ``record``, ``export`` (a Lightning checkpoint's network
beside the SVM), ``compare``, ``seeds``, ``evaluate`` and ``reproduce``.  The steps:

1. :func:`prepare` -> :class:`TrainingData`: the features table, the split (sessions or people, never chirps),
   OSPA's bins chosen on the training sessions (gamma validated when not given), the model inputs of every chirp
   (:class:`~sonicskin.features.FeatureSpec`), the class and force targets;
2. :func:`fit_svm` -> :class:`SVMFit`: model selection on the training/validation presses
   (:mod:`sonicskin.selection`), scaler + RBF SVC, Alg. 2's training reference, the detector threshold, the force
   model;
3. the network (torch side, imported only when one is trained: :mod:`sonicskin.training.fit`) -> ``NetFit``;
4. :func:`write_artifact`: both exported to ONNX with parity checks, ``skin.json`` sealed, swapped in atomically.

Nothing of a test session's labels reaches any step: only the rows of ``split.train`` and ``split.val`` are read
for fitting and choosing (``tests/test_selection.py`` changes a test session and checks the fit is bit-identical).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .dataset import Dataset, FeatureTable
from .feature_cache import load_features_cached
from .features import MIN_REST_CHIRPS, FeatureSpec, quiet_mask, rest_beta, select_bins, training_targets
from .split import Split

__all__ = ["TrainingData", "SVMFit", "prepare", "fit_svm", "fit_svm_head", "ovo_decision", "write_artifact",
           "fit_artifact", "build_svm_artifact", "summary_lines"]


@dataclasses.dataclass
class TrainingData:
    """What every fit step reads: one dataset's chirps, its split and the model inputs of every chirp.

    ``X`` holds the inputs of *every* chirp of ``table`` (each session relative to its own labelled hands-off
    reference in ``relative`` mode); only the rows of the training and validation sessions are ever used for
    fitting: test sessions are replayed through the deployed artifact (:class:`sonicskin.head.Stream`).
    """

    dataset: Dataset
    table: FeatureTable
    split: Split
    spec: FeatureSpec
    X: np.ndarray          # (n, len(spec.bins)) float32 model inputs
    cls: np.ndarray        # (n,) layout row of the touched location, n_locations = no touch
    force: np.ndarray      # (n,) float32 N (NaN: no force sensor)
    usable: np.ndarray     # (n,) bool: may train (light presses below min_force_n may not)
    min_force_n: float = 0.5
    selection: dict = dataclasses.field(default_factory=dict)  # choices made so far (gamma: selection["svm"])
    rig: Any = None        # the rig the artifact declares (default: the dataset's)
    n_svm: int | None = None  # the SVM reads the first n_svm bins (OSPA's gamma for it); default: every bin

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


def prepare(data: str | Path | Dataset, *, n_bins: int | None = 300, mode: str = "relative", train_sessions=None,
            val_sessions=None, test_subjects=None, split: Split | None = None, table: FeatureTable | None = None,
            bins=None, alpha_s: float = 1200.0, rig=None, min_force_n: float = 0.5, allow_no_test: bool = False,
            wide: bool = False, progress: bool = True, log=None) -> TrainingData:
    """Load a dataset, split it by session or subject, choose OSPA's bins on the training split and build the model
    inputs of every chirp.

    ``n_bins=None`` chooses gamma (with the SVM's C and kernel width, kept in ``selection["svm"]``) by validation
    on the training and validation sessions (:func:`sonicskin.selection.select_gamma_on_table`).  ``bins`` gives
    the band bins explicitly instead (e.g. every band bin, the paper's no-OSPA ablation).  ``split``/``table``:
    given instead of made here.  ``wide``: the inputs are every usable bin in OSPA's order (what the network may read:
    its location layer is validated on prefixes of them), and the SVM reads the first ``n_bins`` (``TrainingData.n_svm``;
    a prefix, since OSPA ranks the bins once).  ``alpha_s``: Alg. 2's refresh interval.  ``rig``: the rig the artifact declares
    (default: the dataset's; the paper's no-matched-filter ablation passes it without its PWM notches).  Relative
    inputs need Alg. 2's rest in every session: shorter rest is used down to
    :data:`~sonicskin.features.MIN_REST_CHIRPS` (with a warning), a table of touches only falls back to absolute
    inputs.
    """
    ds = data if isinstance(data, Dataset) else Dataset(data)
    t = table if table is not None else load_features_cached(ds, progress=progress)
    if split is None:
        split = Split.make(t, train_sessions=train_sessions, val_sessions=val_sessions, test_subjects=test_subjects,
                           allow_no_test=allow_no_test)
    selection: dict = {}
    tr = t.select(split.mask(t, "train"))
    if bins is None:
        if n_bins is None:  # validated on the training and validation sessions only
            from .selection import select_gamma_on_table

            selection["svm"] = select_gamma_on_table(t, ds.rig, train_sessions=list(split.train),
                                                     val_sessions=list(split.val), mode=mode, min_force_n=min_force_n,
                                                     log=log or (lambda m: warnings.warn(m, stacklevel=2)))
            n_bins = selection["svm"]["params"]["n_bins"]
        n_usable = int(ds.rig.allowed_mask.sum())
        bins = select_bins(tr, ds.rig, n_usable if wide else n_bins, min_force_n)
        n_svm = min(int(n_bins or len(bins)), len(bins))
    else:
        n_svm = len(bins)
    spec = FeatureSpec(tuple(int(b) for b in bins), mode, alpha_s=float(alpha_s))
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
                        rig or ds.rig, n_svm)


# -- the SVM head --------------------------------------------------------------------------------------------------
def ovo_decision(pipe, X: np.ndarray, block: int = 2048) -> np.ndarray:
    """``pipe.decision_function(X)`` of a fitted scaler + RBF ``SVC(decision_function_shape="ovo")``, with the
    kernel matrix from one BLAS product per block of chirps (libsvm's own loop is 10-20x slower on thousands of
    bins).  Equal to scikit-learn's up to float64 rounding (``tests/test_reproduce.py`` checks it)."""
    svc = pipe[-1]
    Z = np.asarray(pipe[:-1].transform(X), np.float64)
    S = np.asarray(svc.support_vectors_, np.float64)
    coef, icpt, nsv = np.asarray(svc.dual_coef_), np.asarray(svc.intercept_), np.asarray(svc.n_support_)
    k = len(nsv)
    start = np.r_[0, np.cumsum(nsv)]
    s2 = np.einsum("ij,ij->i", S, S)
    out = np.empty((len(Z), k * (k - 1) // 2))
    for lo in range(0, len(Z), block):
        z = Z[lo:lo + block]
        d2 = np.einsum("ij,ij->i", z, z)[:, None] + s2[None, :] - 2.0 * (z @ S.T)
        K = np.exp(-svc._gamma * np.maximum(d2, 0.0))
        p = 0
        for i in range(k):
            for j in range(i + 1, k):
                si, sj = slice(start[i], start[i + 1]), slice(start[j], start[j + 1])
                out[lo:lo + block, p] = K[:, si] @ coef[j - 1, si] + K[:, sj] @ coef[i, sj] + icpt[p]
                p += 1
    return out[:, 0] if k == 2 else out  # binary: scikit-learn's public coef and intercept are already sign-flipped


def fit_svm_head(X: np.ndarray, cls: np.ndarray, force: np.ndarray, quiet: np.ndarray, *, n_locations: int,
                 location_ids, C: float = 10.0, kernel_gamma="scale", force_model: str = "fourier1",
                 force_alpha: float = 10.0, detector: str = "input-rms"):
    """Fit scaler + SVC on touch chirps (``cls < n_locations``), then the Alg. 2 reference scores, the detection
    threshold (Youden's J on the training chirps, of the ``detector`` statistic: the input-RMS change, or the paper's
    max calibrated score) and the force model (per-location curves, or ``"pooled-ridge"`` over the inputs and the
    location, see :class:`sonicskin.force.PooledForce`).  Returns the sklearn pipeline and its JSON-able parameters
    (the ``skin.json`` entry the :class:`sonicskin.head.SVMHead` reads)."""
    from sklearn.pipeline import Pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    from .calibration import TouchDetector
    from .force import PerLocationForce, PooledForce, energy_db
    from .head import DETECTOR_BINS, score_vector, touch_statistic

    touch = cls < n_locations
    pipe = Pipeline([("scale", StandardScaler()), ("svc", SVC(kernel="rbf", C=C, gamma=kernel_gamma,
                                                              decision_function_shape="ovo"))])
    pipe.fit(X[touch], cls[touch])
    if len(pipe.classes_) != n_locations:
        raise ValueError(f"training data touches {len(pipe.classes_)} of the {n_locations} locations; "
                         f"record every location at least once")
    V = score_vector(ovo_decision(pipe, X), n_locations, X)
    # A table of touches only has no rest: no Alg. 2 reference (zero) and no detector (threshold 0 on a statistic
    # >= 0: every chirp is a touch); "detection": false says so in skin.json.
    rest = quiet.sum() >= 2 and (~touch).any()
    ref = V[quiet].mean(axis=0) if rest else np.zeros(V.shape[1])
    n_det = min(DETECTOR_BINS, X.shape[1])
    stat = touch_statistic(V - ref, n_locations, n_det, detector=detector)[:, None]
    det = TouchDetector().fit(stat[touch], stat[~touch]) if rest else None
    all_bins = np.arange(X.shape[1])
    e_ref = float(energy_db(X[quiet], all_bins).mean()) if rest else 0.0
    E = energy_db(X, all_bins) - e_ref
    ids = np.asarray(location_ids)
    has_f = touch & np.isfinite(force)  # recordings without a force sensor carry NaN forces
    fm = PooledForce(force_alpha) if force_model == PooledForce.NAME else PerLocationForce(force_model)
    if has_f.sum() >= 8 and len(np.unique(cls[has_f])) == n_locations and np.ptp(force[has_f]) > 0:
        if isinstance(fm, PooledForce):
            fm.fit(X[has_f], force[has_f], ids[cls[has_f]])
        else:
            fm.fit(E[has_f], force[has_f], ids[cls[has_f]])
    else:
        fm = PerLocationForce("fourier1")  # no force sensor (or a constant force): force is absent (NaN), never 0 N
        fm.curves_ = {}
    params = {"reference_scores": ref.tolist(), "threshold": det.threshold_ if rest else 0.0, "detector": detector,
              "detector_bins": n_det, "detection": bool(rest), "energy_ref_db": e_ref,
              "train_false_touch_rate": det.false_touch_rate_ if rest else None,
              "train_missed_touch_rate": det.missed_touch_rate_ if rest else None,
              "force": fm.to_dict()}
    return pipe, params


@dataclasses.dataclass
class SVMFit:
    """A fitted SVM head: the scaler + SVC pipeline, its ``skin.json`` parameters, the model selection, the fit time."""

    pipe: Any
    params: dict
    selection: dict
    fit_s: float


def fit_svm(data: TrainingData, *, select: bool = True, C: float = 10.0, kernel_width: float | None = None,
            force_model: str = "fourier1", detector: str = "input-rms", log=print) -> SVMFit:
    """Fit the SVM head on the training chirps of ``data``.

    ``select``: C, kernel width, force model validated on the training and validation presses
    (:func:`sonicskin.selection.select_on_inputs`; gamma was chosen by :func:`prepare`); otherwise the given values
    (the paper's: C 10, ``gamma="scale"``, per-location Fourier-1).  The detection threshold is Youden's J on the
    training chirps; with a validation session its missed and false touches there are reported in the selection."""
    from .selection import detection_on_validation, select_on_inputs

    data = data.narrow(data.n_svm)  # the SVM's gamma (a prefix of the inputs in OSPA order)
    train, val = data.rows("train"), data.rows("val")
    sel = dict(data.selection)
    if select:
        sel = select_on_inputs(data.X, data.table, cls=data.cls, train_mask=train, val_mask=val,
                               n_locations=data.n_locations, location_ids=data.layout.ids, selection=sel,
                               min_force_n=data.min_force_n, log=log)
    sp = (sel.get("svm") or {}).get("params", {}) if select else {}
    fsel = (sel.get("force") or {}) if select else {}
    width = sp.get("kernel_width", kernel_width)
    t0 = time.perf_counter()
    pipe, params = fit_svm_head(data.X[train], data.cls[train], data.force[train], data.quiet[train],
                                n_locations=data.n_locations, location_ids=data.layout.ids, C=sp.get("C", C),
                                kernel_gamma="scale" if width is None else width / data.X.shape[1],
                                force_model=fsel.get("model", force_model), force_alpha=fsel.get("alpha") or 10.0,
                                detector=detector)
    fit_s = time.perf_counter() - t0
    if select and params["detection"] and val.any() and detector == "input-rms":  # what the threshold does on validation
        det = detection_on_validation(data.X, data.table, cls=data.cls, val_mask=val, n_locations=data.n_locations,
                                      threshold=params["threshold"])
        if det is not None:
            sel["detection"] = det
    return SVMFit(pipe, params, sel, fit_s)


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
    """Drift tracking's training reference (:meth:`sonicskin.drift.DriftTracker.to_dict`): the mean dB spectrum of the
    training sessions' hands-off chirps at rest over the whole band, with the wall's material when the dataset names
    it (its kappa gives the temperature equivalent).  ``None`` without rest (a table of touches only) or without a
    mode pattern to track."""
    from .drift import DriftError, DriftTracker

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


def write_artifact(data: TrainingData, out: str | Path, *, svm: SVMFit | None = None, net=None, training: dict | None = None,
                   learning_curve: bool = False, drift: bool = True, log=print) -> dict:
    """Export ``svm`` (skl2onnx) and ``net`` (a ``sonicskin.training.fit.NetFit``: torch.onnx) with their parity
    checks into ``out`` with a sealed ``skin.json`` (:func:`sonicskin.artifact.skin_json`); ``out`` is replaced as a
    whole at the end (:func:`sonicskin.artifact.atomic_artifact`).  ``drift``: store drift tracking's training
    reference (:func:`drift_reference`), so every stream maps its chirps back onto the training frequency axis.
    Returns the ``skin.json`` document."""
    from .artifact import PROBE_ROWS, atomic_artifact, export_svm, skin_json

    if svm is None and net is None:
        raise ValueError("write_artifact needs a fitted SVM, a trained network or both")
    out = Path(out)
    check = _check_rows(data)
    sel = dict(svm.selection if svm is not None else data.selection)
    models: dict[str, dict] = {}
    times = {}
    with atomic_artifact(out) as tmp:
        if svm is not None:
            n_svm = int(svm.pipe[0].n_features_in_)  # the first n_svm inputs (OSPA order)
            parity = export_svm(svm.pipe, data.n_locations, tmp / "svm.onnx", check[:, :n_svm])
            models["svm"] = {"file": "svm.onnx", "kind": "svc-ovo", "n_in": n_svm,
                             "n_locations": data.n_locations, "parity": parity, **svm.params}
            times["svm_train_time_s"] = svm.fit_s
        if net is not None:
            import contextlib
            import io

            from sonicskin.export.onnx import export_net  # torch: only a verb that trained a network gets here
            from sonicskin.training.cli import quiet_third_party

            with quiet_third_party(), contextlib.redirect_stdout(io.StringIO()):  # torch.onnx's progress lines
                parity = export_net(net.model, tmp / "net.onnx", check[:, :net.model.n_in])
            entry = {"file": "net.onnx", "kind": "skinnet", "n_in": int(net.model.n_in), "n_locations": data.n_locations,
                     "parity": parity, "hparams": net.hparams}
            if net.detector is not None:
                entry["detector"] = net.detector
            models["net"] = entry
            sel["net"] = {**(sel.get("net") or {}), **net.selection}
            times["net_train_time_s"] = net.train_time_s
        skin = skin_json(tmp, rig=data.rig.to_dict(), layout=data.layout.to_dict(), spec=data.spec,
                         min_force_n=data.min_force_n,
                         training={"data": str(Path(data.dataset.root).resolve()), "split": data.split.to_dict(), **times,
                                   **(training or {})},
                         models=models, probe_inputs=check[:PROBE_ROWS], selection=sel,
                         drift=drift_reference(data, log) if drift else None)
        if learning_curve:
            from .selection import save_learning_curve

            if save_learning_curve(sel, tmp / "learning_curve.png",
                                   title=f"{Path(data.dataset.root).name}: SVM accuracy vs presses per location"):
                log(f"wrote {out}/learning_curve.png")
    return skin


def fit_artifact(data: TrainingData, out: str | Path, *, net=None, svm: SVMFit | None = None, select: bool = True,
                 detector: str = "input-rms", net_options: dict | None = None, training: dict | None = None,
                 learning_curve: bool = False, log=print) -> dict:
    """The whole fit: the SVM head (``svm``, or fitted here), the network, the artifact.

    ``net``: ``None`` (an SVM-only artifact, torch-free), ``"train"`` (trained here in-process,
    :func:`sonicskin.training.fit.train_network` with ``net_options``), or a trained ``torch.nn.Module`` (e.g. a
    Lightning checkpoint's), whose touch decision and force are then chosen here
    (:func:`sonicskin.training.fit.finish_network`)."""
    if svm is None:
        svm = fit_svm(data, select=select, detector=detector, log=log)
    net_fit = None
    if net is not None:
        from sonicskin.training.fit import finish_network, train_network  # torch: only when a network is asked for

        if isinstance(net, str):
            if net != "train":
                raise ValueError(f"net must be None, 'train' or a torch module, got {net!r}")
            net_fit = train_network(data, svm=svm, select=select, **(net_options or {}))
        else:
            net_fit = finish_network(net, data, svm=svm, **(net_options or {}))
    return write_artifact(data, out, svm=svm, net=net_fit, training=training, learning_curve=learning_curve, log=log)


def summary_lines(out: str | Path, skin: dict) -> list[str]:
    """What every training verb prints about the artifact it wrote: the model selection, then its files with their
    size and export parity."""
    from .selection import format_selection

    out = Path(out)
    models = skin["models"]

    def size(name: str) -> str:
        return f"{(out / models[name]['file']).stat().st_size / 1e3:.0f} kB"

    lines = format_selection(skin.get("selection"))
    if "net" in models:
        svm = (f", svm.onnx ({size('svm')}, parity max |d scores| {models['svm']['parity']['max_abs_scores']:.1e})"
               if "svm" in models else "")
        lines.append(f"exported {out}: net.onnx ({size('net')}, parity max |d logits| "
                     f"{models['net']['parity']['max_abs_logits']:.1e}){svm}")
    else:
        lines.append(f"wrote {out}/svm.onnx ({size('svm')}, parity max |d scores| "
                     f"{models['svm']['parity']['max_abs_scores']:.1e}) and skin.json")
    return lines


def build_svm_artifact(data, out, *, n_bins: int | None = None, mode: str = "relative", train_sessions=None,
                       min_force_n: float = 0.5, progress: bool = True, log=print) -> dict:
    """``fit-svm`` (and ``record``): an SVM-only artifact from a dataset, torch-free, trained on every session (or
    ``train_sessions``) with no validation or test split.  ``n_bins=None`` chooses gamma (with C, kernel width, force
    model) by validation on the training sessions' presses (:mod:`sonicskin.selection`), or keeps the paper's 300
    with a warning when it cannot validate.  ``out`` is replaced as a whole when everything is written."""
    ds = data if isinstance(data, Dataset) else Dataset(data)
    d = prepare(ds, n_bins=n_bins, mode=mode, train_sessions=list(train_sessions or ds.sessions), val_sessions=[],
                min_force_n=min_force_n, allow_no_test=True, progress=progress, log=log)
    skin = fit_artifact(d, out, learning_curve=True, log=log)
    for line in summary_lines(out, skin):
        log(line)
    return skin
