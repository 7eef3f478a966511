"""Augmentation along what varies between presses at one marker, measured from the user's own session (issue 26).

With one press per marker the network sees one cloud of chirps per marker.  :class:`Augmenter` draws new touch
chirps along the nuisance directions a later press will move along, each measured from the training session
itself or fixed by physics, never from a test session:

``press``
    the force ramp within each press: a chirp moved toward (or past) another chirp of the same press,
    ``x_i + lam (x_j - x_i)``, ``lam`` in ``[-e, 1 + e]``: a firmer or softer moment of the same touch.
``strength``
    the whole relative spectrum scaled by ``exp(N(0, sigma))``: a small touch changes the channel by
    ``dH ~ K(w) G_tx G_rx``, linear in the finger's impedance ``K`` (mostly its damping, which grows with force
    and differs from person to person), so in the small-change regime the relative dB pattern scales with it.
``aim``
    the fingertip landing off the marker: the chirp moved toward a neighbouring marker's mean pattern by
    ``alpha (mu_j - mu_k)``, ``alpha ~ |N(0, aim_cm / distance)|`` (linear interpolation of the pattern
    between markers; the finger's own contact patch already averages the pattern over ~1 cm).
``stretch``
    warm-up: the wall's modes move with ``sqrt(E)``, so the whole channel's frequency axis is stretched by
    ``s`` (-3.5e-4 per K on the simulated CFRP wall); the relative pattern is resampled at ``f (1 + s)``,
    ``s ~ U(-stretch, stretch)``, over every usable bin.
``gain``, ``tilt``
    a constant and a frequency-linear dB offset (transducer gain, bond and coupling change between the boot
    reference and the chirp), ``N(0, gain_db)``, ``N(0, tilt_db)`` across the band.
``motion``
    a hands-off chirp of the training session recorded while the robot moved, minus their mean, added at a
    random level ``U(0, motion_level)``: motion and noise as this rig records them.

Every augmentation is linear in the chirp except ``stretch`` (a resampling) and ``strength`` (a product); all
work on relative dB over every usable bin and the model's inputs are selected afterwards.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["AUGMENTATIONS", "Augmenter", "make_augmenter", "fit_augmented_net", "net_layers", "choose_force", "choose_net_layer"]

#: augmentations and their default size (see the module notes)
AUGMENTATIONS = {"press": 0.5, "strength": 0.25, "aim": 0.15, "stretch": 1e-3, "gain": 0.3, "tilt": 0.3, "motion": 1.0}


class Augmenter:
    """Draws one augmented copy of every training touch chirp per call.

    Parameters
    ----------
    X : (n, D) relative dB of the training touch chirps over every usable bin.
    y : (n,) marker labels; ``press`` : (n,) press ids (a run of chirps at one marker).
    cols : the model's input columns among the D (e.g. OSPA's bins); the draws are returned over them.
    freqs_hz : (D,) frequency of every column (``stretch``, ``tilt``).
    X_rest : (m, D) hands-off chirps of the training session (while the robot moves, if it does) (``motion``).
    positions_cm : (K, 2) marker positions in the order of ``np.unique(y)``; ``circumference_cm`` for a tube (``aim``).
    sizes : augmentation -> size (:data:`AUGMENTATIONS`); a missing or zero entry turns it off.
    """

    def __init__(self, X, y, press, *, cols=None, freqs_hz=None, X_rest=None, positions_cm=None,
                 circumference_cm: float | None = None, sizes: dict | None = None):
        self.X = np.asarray(X, np.float64)
        self.y = np.asarray(y)
        self.press = np.asarray(press)
        n, D = self.X.shape
        if self.y.shape != (n,) or self.press.shape != (n,):
            raise ValueError(f"X has {n} chirps but y {self.y.shape} and press {self.press.shape}; give one label and press id per chirp")
        self.cols = np.arange(D) if cols is None else np.asarray(cols, int)
        self.sizes = dict(AUGMENTATIONS if sizes is None else sizes)
        unknown = set(self.sizes) - set(AUGMENTATIONS)
        if unknown:
            raise ValueError(f"unknown augmentations {sorted(unknown)}; choose from {sorted(AUGMENTATIONS)}")
        self.classes, self.yi = np.unique(self.y, return_inverse=True)
        K = len(self.classes)
        self.means = np.stack([self.X[self.yi == k].mean(axis=0) for k in range(K)])
        # rows of the same press, for the force-ramp draws
        self._same = {p: np.flatnonzero(self.press == p) for p in np.unique(self.press)}
        self.f = None if freqs_hz is None else np.asarray(freqs_hz, np.float64)
        if self.f is not None and self.f.shape != (D,):
            raise ValueError(f"freqs_hz must give the frequency of each of the {D} columns, got shape {self.f.shape}")
        if self.f is not None:
            self._order = np.argsort(self.f, kind="stable")
            self._fs = self.f[self._order]
        for need, what in (("stretch", self.f), ("tilt", self.f)):
            if self.sizes.get(need) and what is None:
                raise ValueError(f"the {need} augmentation needs freqs_hz")
        self.rest = None
        if X_rest is not None and len(X_rest) >= 2:
            R = np.asarray(X_rest, np.float64)
            self.rest = R - R.mean(axis=0)
        self.neigh: list[tuple[np.ndarray, np.ndarray]] = []
        if positions_cm is not None:
            from sonicskin.nuisance import neighbour_rings

            self.neigh = neighbour_rings(positions_cm, K, circumference_cm)

    def restricted(self, k: int) -> Augmenter:
        """The same augmenter returning only the first ``k`` of its input columns."""
        import copy

        out = copy.copy(self)
        out.cols = self.cols[:k]
        return out

    def draw(self, rng: np.random.Generator, rows: np.ndarray | None = None) -> np.ndarray:
        """Augmented copies of the touch chirps ``rows`` (default: all), over the input columns."""
        rows = np.arange(len(self.X)) if rows is None else np.asarray(rows, int)
        X = self.X[rows].copy()
        s = self.sizes
        n, D = X.shape
        if s.get("press"):
            e = s["press"]
            j = np.array([rng.choice(self._same[p]) for p in self.press[rows]])
            lam = rng.uniform(-e, 1 + e, n)[:, None]
            X = X + lam * (self.X[j] - X)
        if s.get("strength"):
            X *= np.exp(rng.normal(0.0, s["strength"], n))[:, None]
        if s.get("aim") and self.neigh:
            for i, k in enumerate(self.yi[rows]):
                near, dist = self.neigh[k]
                if near.size:
                    m = rng.integers(near.size)
                    a = min(1.0, abs(rng.normal(0.0, s["aim"] / dist[m])))
                    X[i] += a * (self.means[near[m]] - self.means[k])
        if s.get("stretch") and self.f is not None:
            st = rng.uniform(-s["stretch"], s["stretch"], n)
            Xo = X[:, self._order]
            for i in range(n):
                Xo[i] = np.interp(self._fs * (1.0 + st[i]), self._fs, Xo[i])
            X[:, self._order] = Xo
        if self.f is not None and (s.get("gain") or s.get("tilt")):
            u = (self.f - self.f.mean()) / max(np.ptp(self.f), 1e-12)
            g, t = (rng.normal(0.0, s.get(k, 0.0) or 0.0, n)[:, None] for k in ("gain", "tilt"))
            X += g + t * u[None, :]
        elif s.get("gain"):
            X += rng.normal(0.0, s["gain"], n)[:, None]
        if s.get("motion") and self.rest is not None:
            pick = rng.integers(len(self.rest), size=n)
            X += rng.uniform(0.0, s["motion"], n)[:, None] * self.rest[pick]
        return X[:, self.cols]


# -- the network -----------------------------------------------------------------------------------------------
def net_layers() -> dict:
    """The location layers the augmented network can have: name -> options of :func:`fit_augmented_net`, plus
    ``n_inputs``: the network reads only the first (best, OSPA order) that many inputs (``None``: all)."""
    return {"MLP, every bin (augmented)": {"layer": "mlp"},
            "MLP, 1000 bins (augmented)": {"layer": "mlp", "n_inputs": 1000},
            "metric (normalized LDA)": {"layer": "metric", "metric_lr": 0.0, "unit_norm": True}}


def fit_augmented_net(X, cls, force, *, n_locations: int, augmenter: Augmenter | None = None, touch_rows=None,
                      layer: str = "metric", lda=None, metric_lr: float = 1e-3, epochs: int = 40, seed: int = 0,
                      batch_size: int = 128, hidden=(128, 128), dropout: float = 0.3, lr: float = 2e-3,
                      weight_decay: float = 1e-2, force_weight: float = 0.1, noise_db: float = 0.3, aug_share: float = 0.5,
                      target_margin: float | None = 8.0, n_trunk: int | None = None, unit_norm: bool = False,
                      n_members: int = 1, log=None):
    """Train a network on (X, cls, force) with augmented touch chirps; returns ``predict(X) -> (logits, force)``
    with ``predict.model`` the torch module (a :class:`models.SkinNet` / :class:`models.metric.MetricSkinNet`,
    exported as any SkinNet).

    ``X`` (n, n_in): the model inputs of every training chirp (touch and hands-off; ``cls == n_locations`` is no
    touch); ``touch_rows``: the rows of ``X`` the ``augmenter``'s chirps are (in its order).  Every epoch the touch
    rows are joined by one augmented copy of ``aug_share`` of them (labels and forces of their originals).
    ``layer``: ``"metric"`` (:class:`~models.metric.MetricVotes` initialised from ``lda``, a fitted
    :class:`sonicskin.nuisance.ShrinkageLDA` on the same inputs' touch chirps; ``metric_lr`` 0 keeps it frozen) or
    ``"mlp"`` (SkinNet without a kernel layer).  ``n_members`` > 1: that many networks trained with seeds ``seed``,
    ``seed + 1``, ... averaged (:class:`~models.metric.SkinEnsemble`).  ``n_trunk``: the metric network's trunk (touch, force) reads the
    first ``n_trunk`` inputs only, and with ``unit_norm`` its metric layer reads unit-length chirps (``lda`` then fitted
    on ``Normalizer()``-ed touch chirps) (:class:`~models.metric.MetricSkinNet`).
    """
    import torch
    import torch.nn.functional as F
    from sonicskin.models import SkinNet
    from sonicskin.models.metric import MetricSkinNet, SkinEnsemble

    from sonicskin import threads

    if n_members > 1:
        kw = dict(n_locations=n_locations, augmenter=augmenter, touch_rows=touch_rows, layer=layer, lda=lda,
                  metric_lr=metric_lr, epochs=epochs, batch_size=batch_size, hidden=hidden, dropout=dropout, lr=lr,
                  weight_decay=weight_decay, force_weight=force_weight, noise_db=noise_db, aug_share=aug_share,
                  target_margin=target_margin, n_trunk=n_trunk, unit_norm=unit_norm)
        members = [fit_augmented_net(X, cls, force, seed=seed + i, **kw).model for i in range(n_members)]
        return _predictor(SkinEnsemble(members).eval())
    threads.apply_torch()
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    X = np.ascontiguousarray(X, np.float32)
    cls = np.asarray(cls, np.int64)
    force = np.asarray(force, np.float32)
    n_in = X.shape[1]
    mean, std = X.mean(0), X.std(0) + 1e-3
    if layer == "metric":
        if lda is None:
            raise ValueError("the metric layer starts from a fitted ShrinkageLDA on the same inputs (lda=...)")
        model = MetricSkinNet(n_in, n_locations, tuple(hidden), dropout, n_trunk=n_trunk, unit_norm=unit_norm)
        model.init_from_lda(lda, mean, std, target_margin=target_margin)
    elif layer == "mlp":
        model = SkinNet(n_in, n_locations, tuple(hidden), dropout)
        model.set_normalization(mean, std)
    else:
        raise ValueError(f"layer must be 'metric' or 'mlp', got {layer!r}")
    metric_params = list(model.metric.parameters()) if layer == "metric" else []
    ids = {id(p) for p in metric_params}
    groups = [{"params": [p for p in model.parameters() if id(p) not in ids]}]
    for p in metric_params:
        p.requires_grad_(metric_lr > 0)
    if metric_params and metric_lr > 0:
        groups.append({"params": metric_params, "lr": metric_lr, "weight_decay": 0.0})
    opt = torch.optim.AdamW(groups, lr=lr, weight_decay=weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, epochs))
    touch_rows = np.asarray(touch_rows if touch_rows is not None else np.flatnonzero(cls < n_locations), int)
    t0 = time.perf_counter()
    model.train()
    for _ in range(epochs):
        Xe, ce, fe = X, cls, force
        if augmenter is not None and aug_share > 0:
            k = max(1, int(round(aug_share * len(touch_rows))))
            pick = rng.choice(len(touch_rows), size=k, replace=False)
            Xa = augmenter.draw(rng, pick).astype(np.float32)
            src = touch_rows[pick]
            Xe, ce, fe = np.vstack([X, Xa]), np.r_[cls, cls[src]], np.r_[force, force[src]]
        Xt, yt, ft = torch.from_numpy(Xe), torch.from_numpy(ce), torch.from_numpy(fe)
        perm = torch.randperm(len(Xt))
        for i in range(0, len(Xt), batch_size):
            b = perm[i:i + batch_size]
            x = Xt[b]
            if noise_db > 0:
                x = x + noise_db * torch.randn_like(x)
            logits, f_all = model(x)
            loss = F.cross_entropy(logits, yt[b])
            touched = yt[b] < n_locations
            has_f = touched & torch.isfinite(ft[b])
            if has_f.any():
                loss = loss + force_weight * F.mse_loss(f_all[has_f].gather(1, yt[b][has_f, None])[:, 0], ft[b][has_f])
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
    model.eval()
    if log:
        log(f"trained {layer} network {epochs} epochs in {time.perf_counter() - t0:.1f} s")

    return _predictor(model)


def _predictor(model):
    """``predict(X) -> (logits, force)`` of a trained torch model on float rows, the model at ``predict.model``."""
    import torch

    def predict(Xq):
        with torch.no_grad():
            lg, f = model(torch.from_numpy(np.ascontiguousarray(Xq, np.float32)))
        return lg.numpy(), f.numpy()

    predict.model = model
    return predict


def choose_force(model, X, cls, force, *, fit_rows, val_rows, location_ids, alpha: float = 10.0,
                 first: tuple = (None, 300), how: str = "validation") -> dict:
    """The network's force chosen on presses it did not train on (``val_rows``): its own head, or a pooled ridge
    (:class:`sonicskin.force.PooledForce`, fitted on ``fit_rows``) over every input or over the first ``k`` inputs
    (the best OSPA bins; zero weight on the rest, so :meth:`models.SkinNet.set_force` takes it unchanged).
    :func:`training.quick.choose_net_force` with the choice of inputs added: a ridge over thousands of bins fits
    one session's presses more loosely than over the few hundred the SVM's force reads.  Sets the model's force."""
    import torch

    from sonicskin.force import PooledForce

    ids = np.asarray(location_ids)
    n_loc, n_in = len(ids), X.shape[1]
    f = np.asarray(force, np.float64)
    fr = fit_rows & (cls < n_loc) & np.isfinite(f)
    vr = val_rows & (cls < n_loc) & np.isfinite(f)
    if fr.sum() < 8 or vr.sum() < 2 or np.unique(cls[fr]).size < n_loc:
        return {"force": "head", "force_how": "not validated (too few presses with a force reading)"}
    model.set_force(None)
    with torch.no_grad():
        head = model(torch.from_numpy(np.ascontiguousarray(X[vr], np.float32)))[1].numpy()
    cand = {"head": (np.clip(head[np.arange(vr.sum()), cls[vr]], 0, None), None)}
    for k in first:
        k = n_in if k is None else min(int(k), n_in)
        name = "pooled-ridge" if k == n_in else f"pooled-ridge (first {k} inputs)"
        if name in cand:
            continue
        pf = PooledForce(alpha).fit(X[fr][:, :k], f[fr], ids[cls[fr]])
        coef = np.zeros(n_in)
        coef[:k] = pf.coef_
        pred = np.clip(X[vr] @ coef + np.array([pf.loc_coef_.get(int(i), 0.0) for i in ids[cls[vr]]]) + pf.intercept_, 0, None)
        cand[name] = (pred, {"coef": coef, "loc": [pf.loc_coef_[int(i)] + pf.intercept_ for i in ids]})
    rmse = {k: float(np.sqrt(np.mean((p - f[vr]) ** 2))) for k, (p, _) in cand.items()}
    best = min(rmse, key=rmse.get)
    if cand[best][1] is not None:
        model.set_force(cand[best][1])
    return {"force": best, "force_how": f"{how}: " + ", ".join(f"{k} {v:.2f} N" for k, v in rmse.items()), "force_rmse": rmse}


def choose_net_layer(X, cls, force, *, n_locations: int, train, val, augmenter: Augmenter | None, touch_rows,
                     lda=None, lda_unit=None, kernel_fit=None, layers: dict | None = None, seed: int = 0,
                     epochs: int = 40, n_trunk: int = 300, log=None) -> dict:
    """Train each candidate location layer on the ``train`` rows and keep the one with the best touch accuracy on
    the ``val`` rows (ties: the first of ``layers``, default :func:`net_layers`).

    ``X`` (n, n_in): every chirp's inputs (every usable bin, OSPA order, so the trunk reads the best ``n_trunk``);
    ``touch_rows``: positions *within the train rows* of the augmenter's chirps (its input columns are ``X``'s; a layer
    with ``n_inputs`` reads the first that many, and ``predict.n_inputs`` says how many); ``lda`` / ``lda_unit``: fitted
    :class:`sonicskin.nuisance.ShrinkageLDA` on the training touch chirps (raw / unit-length) for the metric
    layers; ``kernel_fit``: a callable ``() -> predict`` training the package's kernel network (the SVM copy) to
    compete as ``"SVM kernel (frozen)"``.  Returns ``{"location_layer", "scores", "predict"}`` (the winner's
    ``predict``, trained on the train rows).
    """
    layers = dict(net_layers() if layers is None else layers)
    train, val = np.asarray(train, bool), np.asarray(val, bool)
    rows = np.flatnonzero(train)
    vt = val & (np.asarray(cls) < n_locations)
    scores, preds = {}, {}
    for name, opts in layers.items():
        opts = dict(opts)
        k = opts.pop("n_inputs", None) or X.shape[1]
        model_lda = lda_unit if opts.get("unit_norm") else lda
        if opts.get("layer") == "metric" and (model_lda is None or model_lda.n_features_in_ != k):
            continue
        aug = augmenter.restricted(k) if augmenter is not None and k < X.shape[1] else augmenter
        pred = fit_augmented_net(X[rows][:, :k], cls[rows], force[rows], n_locations=n_locations, augmenter=aug,
                                 touch_rows=touch_rows, lda=model_lda, seed=seed, epochs=epochs, n_trunk=n_trunk, **opts)
        pred.n_inputs = k
        lg, _ = pred(X[vt][:, :k])
        scores[name] = float(np.mean(lg[:, :n_locations].argmax(1) == cls[vt]))
        preds[name] = pred
    if kernel_fit is not None:
        pred = kernel_fit()
        lg, _ = pred(X[vt][:, :pred.model.n_in]) if pred.model.n_in < X.shape[1] else pred(X[vt])
        scores["SVM kernel (frozen)"] = float(np.mean(lg[:, :n_locations].argmax(1) == cls[vt]))
        preds["SVM kernel (frozen)"] = pred
    best = max(scores, key=lambda k: (scores[k], -list(scores).index(k)))
    if log:
        log("network location layer: " + best + " (validation: " + ", ".join(f"{k} {v:.0%}" for k, v in scores.items()) + ")")
    return {"location_layer": best, "scores": scores, "predict": preds[best]}


def make_augmenter(data, rows: np.ndarray, *, n_cols: int | None = None, sizes: dict | None = None):
    """The augmenter of one training session's touch chirps (a :class:`sonicskin.fit.TrainingData`'s ``rows``): every
    nuisance measured there (its presses' force ramps, its hands-off chirps while the robot moves, or at rest after
    the boot reference when it never moves, its markers' positions), over all of the data's inputs (OSPA order), drawn
    over the first ``n_cols``.  Returns the augmenter and, for each of the ``rows``, its row in the augmenter (-1: not
    a touch chirp)."""
    from sonicskin.selection import press_ids

    t = data.table
    rows = np.asarray(rows, bool)
    n_loc = data.n_locations
    touch = rows & (data.cls < n_loc)
    seg = t["segment"] if "segment" in t.labels else None
    press = press_ids(t["location"], t["session"], seg)
    sessions = np.isin(t["session"], sorted(set(t["session"][rows])))
    hands_off = sessions & (data.cls == n_loc)
    moving = hands_off & (t["moving"] > 0)
    rest = moving if moving.sum() >= 10 else hands_off & data.usable
    cls_touch = data.cls[touch]
    freqs = data.rig.freqs_hz[data.rig.band_bins][list(data.spec.bins)]
    aug = Augmenter(data.X[touch], cls_touch, press[touch], cols=np.arange(n_cols or data.X.shape[1]), freqs_hz=freqs,
                    X_rest=data.X[rest] if rest.sum() >= 2 else None,
                    positions_cm=data.layout.xy_cm[np.unique(cls_touch)], circumference_cm=data.layout.circumference_cm,
                    sizes=sizes)
    pos = np.full(len(rows), -1)
    pos[np.flatnonzero(touch)] = np.arange(int(touch.sum()))
    return aug, pos[np.flatnonzero(rows)]
