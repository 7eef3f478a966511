"""Model kinds: what an artifact can deploy, one module each, one registry (:data:`KINDS`).

``svm`` (:mod:`.svm`), ``lda`` (:mod:`.lda`) and the network's runtime half (:mod:`.net`); its fit and export need
torch and come from the ``sonicskin.kinds`` entry point, loaded by :func:`get` only to fit one."""

from __future__ import annotations

import dataclasses
from importlib.metadata import entry_points
from typing import Any

from ..errors import UsageError

__all__ = ["ModelKind", "Fitted", "KINDS", "BASELINE", "NETWORK", "CLOSED_FORM", "register", "get", "names", "labels", "fit_order"]


@dataclasses.dataclass
class Fitted:
    """One fitted model: its estimator, ``skin.json`` entry fields, inputs read, its choices and its fit time."""

    model: Any
    entry: dict
    n_in: int
    selection: dict
    fit_s: float | None = None


class ModelKind:
    """One kind of deployable model.  Subclasses set the attributes and implement the methods they use."""

    name: str = ""          # key in skin.json's ``models`` and the CLI's ``--model``
    label: str = ""         # how tables name it
    graph: str = ""         # the entry's ``kind`` (what the ONNX graph is)
    file: str = ""          # the ONNX file in the artifact folder
    keys: frozenset = frozenset()   # the entry's fields besides the common ones
    selection_keys: tuple = ()      # keys of ``selection`` it reports
    requires: tuple = ()            # kinds fitted before it (their :class:`Fitted` are passed to :meth:`fit`)
    can_fit = True

    def outputs(self, n_loc: int) -> list[int | None]:
        """Width of each graph output (``None``: not checked on the probes)."""
        raise NotImplementedError

    def output_text(self, n_loc: int) -> str:
        return f"{len(self.outputs(n_loc))} outputs of widths {self.outputs(n_loc)}"

    def declared_widths(self, k: int, n_loc: int) -> tuple:
        """The last dimension graph output ``k`` may declare (besides its real width and ``None``)."""
        return ()

    def check_entry(self, doc, m: dict, field: str, *, n_in: int, layout_ids: list) -> None:
        """Its own fields of a ``skin.json`` entry (:class:`sonicskin.artifact_schema._Doc` checks, one line each)."""

    def head(self, entry: dict, layout):
        raise NotImplementedError

    def fit(self, data, *, fitted: dict, selection: dict | None = None, log=print, **options) -> Fitted:
        """Fit on the training rows of ``data``; ``selection``: choices already made (a refit), else chosen here."""
        raise NotImplementedError

    def export(self, fit: Fitted, path, X_check) -> dict:
        """Write the ONNX graph, check it decides as the original on ``X_check``; the parity figures."""
        raise NotImplementedError

    def selection_lines(self, sel: dict) -> list[str]:
        return []

    def force_rmse(self, sel: dict) -> float | None:
        """The validated RMSE (N) of the force it deploys (``None``: not validated): here the SVM's force model's."""
        f = sel.get("force") or {}
        return f["estimate"]["rmse_n"] if f.get("status") == "validated" else None


KINDS: dict[str, ModelKind] = {}
#: the paper's model: what ``live`` and ``listen()`` run by default, the ablations of ``evaluate``, gamma's owner
BASELINE = "svm"
#: the learned model every result sets beside the baseline
NETWORK = "net"
#: the closed-form model the network starts from
CLOSED_FORM = "lda"


def register(kind: ModelKind) -> ModelKind:
    KINDS[kind.name] = kind
    return kind


def get(name: str, *, fitting: bool = False) -> ModelKind:
    """The kind ``name``; ``fitting``: one that can be fitted (the network's comes from its entry point)."""
    if name not in KINDS:
        raise UsageError(f"model must be one of {', '.join(names())}, got {str(name)[:40]!r}")
    if fitting and not KINDS[name].can_fit:
        for ep in entry_points(group="sonicskin.kinds"):
            if ep.name == name:
                try:
                    return register(ep.load()())
                except ImportError as e:
                    raise UsageError(f"fitting the {KINDS[name].label} needs the training extra ({e}); install it with "
                                     f"pip install -c constraints.txt -e '.[train]'") from None
        raise UsageError(f"this installation cannot fit a {KINDS[name].label} (no entry point sonicskin.kinds:{name}); "
                         f"reinstall the package with its training extra")
    return KINDS[name]


def names() -> list[str]:
    """The kinds in report order: the network, the baseline, then the others."""
    return sorted(KINDS, key=lambda k: (k != NETWORK, k != BASELINE, k))


def labels() -> dict[str, str]:
    return {k: KINDS[k].label for k in names()}


def fit_order(wanted) -> list[str]:
    """``wanted`` with the kinds each requires first (each once)."""
    out: list[str] = []

    def add(n):
        for r in get(n).requires:
            add(r)
        if n not in out:
            out.append(n)

    for n in wanted:
        add(n)
    return out


from . import lda, net, svm  # noqa: E402,F401  (each registers itself)
