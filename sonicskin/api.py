"""The Python API for robot programs: touch events from a deployed skin, without torch.

An iterator for scripts (``for ev in sonicskin.listen("artifacts/moving", duration_s=5): ...``), and a callback or a
non-blocking :meth:`Listener.poll` for a controller loop, over one :class:`Listener`.  Examples: docs/api.md."""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

from .errors import SonicskinError, is_number
from .events import TouchEvent

__all__ = ["listen", "Listener"]

_END = object()


def _check_arguments(*, artifact, device, duration_s, watchdog_s, tx, rx, scenario=None, rig=None, fast=False,
                     realtime=False, overwrite=False, view=None, foxglove=None, on_event=None) -> None:
    """The keywords of :class:`Listener`, one :class:`SonicskinError` line each, before the loop's thread meets them."""
    if not isinstance(artifact, (str, Path)):
        raise SonicskinError(f"artifact must be the path of an artifact folder, got {artifact!r}")
    if not (device is None or isinstance(device, str) or (is_number(device, integer=True) and device >= 0)):
        raise SonicskinError(f"device must be None or 'sim', an audio device index >= 0 or a name, got {device!r}")
    if duration_s is not None and not (is_number(duration_s) and duration_s > 0):
        raise SonicskinError(f"duration_s must be > 0 (a finite number of seconds) or None (until stop()), got {duration_s!r}")
    if not (is_number(watchdog_s) and watchdog_s > 0):
        raise SonicskinError(f"watchdog_s must be a finite number of seconds > 0, got {watchdog_s!r}")
    for name, v in (("tx", tx), ("rx", rx)):
        if not (is_number(v, integer=True) and v >= 0):
            raise SonicskinError(f"{name} must be a 0-based channel number (an integer >= 0), got {v!r}")
    if not (scenario is None or isinstance(scenario, (str, Path))):
        raise SonicskinError(f"scenario must be a scenario name or YAML path (e.g. 'stationary'), got {scenario!r}")
    if not (rig is None or isinstance(rig, (str, Path))):
        raise SonicskinError(f"rig must be None (the artifact's own), a rig name or a YAML path, got {rig!r}")
    for name, v in (("fast", fast), ("realtime", realtime), ("overwrite", overwrite)):
        if not isinstance(v, bool):
            raise SonicskinError(f"{name} must be True or False, got {v!r}")
    if not (view is None or isinstance(view, bool) or (is_number(view, integer=True) and 0 <= view <= 65535)):
        raise SonicskinError(f"view must be True (any free port), a TCP port number 1-65535 (an int; 0: any free one) or "
                             f"None/False (no page), got {view!r}")
    if not (foxglove is None or foxglove is True or (is_number(foxglove, integer=True) and 0 <= foxglove <= 65535)):
        raise SonicskinError(f"foxglove must be True (port 8765), a TCP port number 1-65535 (an int; 0: any free one) or "
                             f"None (no server), got {foxglove!r}")
    if not (on_event is None or callable(on_event)):
        raise SonicskinError(f"on_event must be a function called with each TouchEvent (or None), got {on_event!r}")


class Listener:
    """Run a skin in a background thread; events go to ``on_event`` and to :meth:`poll` / iteration.

    ``artifact``: an artifact folder, or a whole arm (one loop per link; :attr:`summary` keyed by link).  ``device``:
    ``None``/``"sim"`` or an audio device index or name; ``scenario``, ``fast``: the simulated device's; ``on_event`` is
    called in the listener's thread (keep it short); ``mcap``/``ros2``/``foxglove``/``view``: the outputs of
    ``sonicskin live`` (docs/api.md).  A :class:`sonicskin.live.DeviceLost` is re-raised by :meth:`poll`, iteration and
    :meth:`stop`; every error of the arguments and of the device is a :class:`sonicskin.errors.SonicskinError`."""

    def __init__(self, artifact: str | Path, *, device: str | int | None = None, model: str | None = None,
                 duration_s: float | None = None, scenario: str | Path | None = None, rig: str | Path | None = None,
                 tx: int = 0, rx: int = 0, fast: bool = False, on_event: Callable[[TouchEvent], None] | None = None,
                 watchdog_s: float = 3.0, blocksize: int = 1024, mcap: str | Path | None = None, overwrite: bool = False,
                 view: bool | int | None = None, realtime: bool = False, ros2: bool | int | None = None,
                 foxglove: bool | int | None = None):
        from .session import open_run  # here: `import sonicskin` loads neither onnxruntime nor scikit-learn

        _check_arguments(artifact=artifact, device=device, duration_s=duration_s, watchdog_s=watchdog_s, tx=tx, rx=rx,
                         scenario=scenario, rig=rig, fast=fast, realtime=realtime, overwrite=overwrite, view=view,
                         foxglove=foxglove, on_event=on_event)
        self._queue: queue.Queue = queue.Queue()
        self._user_cb = on_event
        self.duration_s, self.watchdog_s = duration_s, watchdog_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self.summary: dict | None = None
        #: the opened run (:class:`sonicskin.session.Run`): its links, runtimes, source and live loops
        self.opened = open_run(artifact, device=device, model=model, scenario=scenario, rig=rig, tx=tx, rx=rx, fast=fast,
                               blocksize=blocksize, mcap=mcap, overwrite=overwrite, realtime=realtime, ros2=ros2,
                               foxglove=foxglove, duration_s=duration_s)
        self.loops = self.opened.loops(emit=lambda line: None, on_event=self._on_event, view=view)
        self.source, self.runtime, self.loop = self.opened.source, self.opened.runtimes[0], self.loops[0]  # the first link's
        self.view_url = self.opened.view.url if self.opened.view is not None else None

    def _on_event(self, ev: TouchEvent) -> None:
        self._queue.put(ev)
        if self._user_cb is not None:
            self._user_cb(ev)

    def _run(self) -> None:
        try:
            self.summary = self.opened.run(duration_s=self.duration_s, watchdog_s=self.watchdog_s, stop=self._stop)
        except BaseException as e:  # handed to the caller's thread
            self.error = e
        finally:
            self._queue.put(_END)

    # -- control -------------------------------------------------------------------------
    def start(self) -> Listener:
        """Start listening (again while it runs: nothing more); a stopped Listener does not start again."""
        if self._stop.is_set():
            raise SonicskinError("this Listener was stopped and its source closed; make a new Listener to listen again")
        if self._thread is not None and not self._thread.is_alive():  # it ran to its end (--duration, or its source ended)
            raise SonicskinError("this Listener's run has ended and its source is closed; make a new Listener to listen again")
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="sonicskin-listener", daemon=True)
            self._thread.start()
        return self

    def _halt(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)

    def stop(self) -> dict | None:
        """Stop and wait for the thread; returns the run's summary (as ``sonicskin live`` prints it)."""
        self._halt()
        self._raise()
        return self.summary

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _raise(self) -> None:
        if self.error is not None:
            e, self.error = self.error, None
            raise e

    def __enter__(self) -> Listener:
        return self.start()

    def __exit__(self, *exc) -> None:
        self._halt()
        if exc[0] is None:
            self._raise()

    def set_joint_state(self, positions: dict[str, float], t_unix_s: float | None = None) -> None:
        """The arm's joint positions (rad or m) at ``t_unix_s`` (default now): ``/joint_states`` and ``/tf``, so a viewer moves it."""
        for pub in self.opened.publishers:
            pub.joints(positions, t_unix_s)

    # -- events --------------------------------------------------------------------------
    def poll(self) -> list[TouchEvent]:
        """Events since the last call, without waiting (for a controller loop)."""
        out = []
        while True:
            try:
                ev = self._queue.get_nowait()
            except queue.Empty:
                break
            if ev is _END:
                self._queue.put(_END)  # stays ended for later calls
                break
            out.append(ev)
        self._raise()
        return out

    def __iter__(self) -> Iterator[TouchEvent]:
        self.start()
        while True:
            ev = self._queue.get()
            if ev is _END:
                self._queue.put(_END)
                break
            yield ev
        self._raise()


def listen(artifact: str | Path, *, device: str | int | None = None, duration_s: float | None = None, **kw) -> Iterator[TouchEvent]:
    """Touch events as they happen: ``for ev in listen("artifacts/x", duration_s=5): ...`` (keywords as :class:`Listener`)."""
    lst = Listener(artifact, device=device, duration_s=duration_s, **kw)
    try:
        yield from lst
    finally:
        lst._halt()
