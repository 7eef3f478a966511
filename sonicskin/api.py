"""The Python API for robot programs: touch events from a deployed skin, without torch.

Two forms over one implementation (:class:`Listener`, a background thread running
:class:`sonicskin.live.LiveLoop`):

- an iterator, for scripts::

      for ev in sonicskin.listen("artifacts/moving", duration_s=5):
          print(ev.kind, ev.location, ev.x_cm, ev.y_cm, ev.force_n)

- a callback or a non-blocking poll, for a controller loop that owns its own timing::

      with sonicskin.Listener("artifacts/moving", device=2, on_event=handle) as skin:
          while robot.ok():
              for ev in skin.poll():   # events since the last call, never blocks
                  ...
              robot.step()

Events are :class:`sonicskin.events.TouchEvent`, the same objects whose JSON ``sonicskin live``
prints (schema in :mod:`sonicskin.events`).  ``device=None`` or ``"sim"`` is the simulated rig
(scripted touches of ``scenario``), as in ``sonicskin live``; an index or a name substring opens
that audio interface (``sonicskin devices``).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

from .errors import ConfigNotFoundError, SonicskinError
from .events import TouchEvent

__all__ = ["listen", "Listener"]

_END = object()


MAX_BLOCKSIZE = 2**20  # frames per audio block (5.5 s at 192 kHz); the CLI's --blocksize has the same cap (acquire)


def _check_arguments(*, artifact, device, duration_s, watchdog_s, tx, rx, blocksize, scenario=None, rig=None, fast=False,
                     on_event=None) -> None:
    """The keywords of :class:`Listener`, one :class:`SonicskinError` line each (a negative blocksize hung the
    simulated device, 0 divided by zero, strings compared with numbers in the loop's thread, ``fast="no"`` meant
    true, ``on_event="print"`` failed at the first touch, ``scenario=None`` was a TypeError)."""
    import math

    from .acquire import check_blocksize

    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    def count(v):
        return isinstance(v, int) and not isinstance(v, bool)

    if not isinstance(artifact, (str, Path)):
        raise SonicskinError(f"artifact must be the path of an artifact folder, got {artifact!r}")
    if not (device is None or isinstance(device, str) or (count(device) and device >= 0)):
        raise SonicskinError(f"device must be None or 'sim', an audio device index >= 0 or a name, got {device!r}")
    if duration_s is not None and not (number(duration_s) and math.isfinite(duration_s) and duration_s > 0):
        raise SonicskinError(f"duration_s must be > 0 (a finite number of seconds) or None (until stop()), got {duration_s!r}")
    if not (number(watchdog_s) and math.isfinite(watchdog_s) and watchdog_s > 0):
        raise SonicskinError(f"watchdog_s must be a finite number of seconds > 0, got {watchdog_s!r}")
    for name, v in (("tx", tx), ("rx", rx)):
        if not (count(v) and v >= 0):
            raise SonicskinError(f"{name} must be a 0-based channel number (an integer >= 0), got {v!r}")
    check_blocksize(blocksize)
    if not isinstance(scenario, (str, Path)):
        raise SonicskinError(f"scenario must be a scenario name or YAML path (e.g. 'stationary'), got {scenario!r}")
    if not (rig is None or isinstance(rig, (str, Path))):
        raise SonicskinError(f"rig must be None (the artifact's own), a rig name or a YAML path, got {rig!r}")
    if not isinstance(fast, bool):
        raise SonicskinError(f"fast must be True or False, got {fast!r}")
    if not (on_event is None or callable(on_event)):
        raise SonicskinError(f"on_event must be a function called with each TouchEvent (or None), got {on_event!r}")


def _load_config(load, what: str):
    """A rig or scenario config; a name that is no config is :class:`ConfigNotFoundError` (still a FileNotFoundError)."""
    try:
        return load(what)
    except FileNotFoundError as e:
        raise ConfigNotFoundError(str(e)) from None


class Listener:
    """Run a skin in a background thread; events go to ``on_event`` and to :meth:`poll` / iteration.

    Parameters
    ----------
    artifact : artifact folder (``sonicskin fit-svm`` / ``sonicskin export``), or a whole arm: its arm file, or the folder
        ``sonicskin fit-svm --links`` wrote (holding ``arm.yaml``); then one loop runs per link, each event names its
        link and carries the contact in the link's frame, and :attr:`summary` is keyed by link.
    device : ``None`` or ``"sim"`` (the simulated rig), or an audio device index or name.
    model : ``"svm"`` or ``"net"``.
    duration_s : stop after this many seconds (wall clock); ``None``: until :meth:`stop`.
    scenario : simulated device only: the scenario of the link and its scripted touches (name or YAML);
        its marker layout must be the artifact's.
    rig : rig name or YAML (default: the artifact's own).
    tx, rx : output and input channel (0-based) of a real interface.
    fast : simulated device only: run faster than real time (``True`` or ``False``).
    on_event : a function called in the listener's thread with each :class:`TouchEvent`; keep it short.
    mcap : with an arm: also write every touch as ROS 2 messages in the link frames into this MCAP file
        (:class:`sonicskin.rosbag.McapEventWriter`; ``sonicskin live --links ARM --mcap FILE``).
    view : ``True`` or a port: show the skin live in a browser (``sonicskin live --view``); its address is
        :attr:`view_url`, served until the run ends.
    watchdog_s : a device (or the simulated one, at any pace) that delivers no audio for this long ends the run with
        :class:`sonicskin.live.DeviceLost` (re-raised by :meth:`poll`, iteration and :meth:`stop`); so does a run
        whose input holds no usable chirp (:class:`sonicskin.live.InputUnusable`, a ``DeviceLost``).

    Every error of the arguments and of the device is a :class:`sonicskin.errors.SonicskinError` with one line that
    names the fix (:class:`~sonicskin.acquire.AudioError` and ``DeviceLost`` among them).
    """

    def __init__(self, artifact: str | Path, *, device: str | int | None = None, model: str = "svm",
                 duration_s: float | None = None, scenario: str | Path = "stationary", rig: str | Path | None = None,
                 tx: int = 0, rx: int = 0, fast: bool = False, on_event: Callable[[TouchEvent], None] | None = None,
                 watchdog_s: float = 3.0, blocksize: int = 1024, mcap: str | Path | None = None,
                 view: bool | int | None = None):
        from .acquire import Link, SimulatedSource, SoundDeviceSource
        from .live import LiveLoop
        from .rig import Rig
        from .runtime import SkinRuntime

        _check_arguments(artifact=artifact, device=device, duration_s=duration_s, watchdog_s=watchdog_s, tx=tx, rx=rx,
                         blocksize=blocksize, scenario=scenario, rig=rig, fast=fast, on_event=on_event)
        self._queue: queue.Queue = queue.Queue()
        self._user_cb = on_event
        self._mcap = None
        self.duration_s, self.watchdog_s = duration_s, watchdog_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self.summary: dict | None = None
        from .arm import arm_file_of, open_arm

        arm_file = arm_file_of(artifact)
        if arm_file is not None:  # a whole arm: one loop per link over one source, events carry their link
            arm = open_arm(arm_file, device=device, model=model, rig=rig, fast=fast, blocksize=blocksize)
            self.links, self.runtime, self.source = arm.links, arm.runtimes[0], arm.source
            self.loops = arm.loops(emit=lambda line: None, on_event=self._on_event)
            self.loop = self.loops[0]
            if mcap is not None:
                arm.require_frames("mcap=")
            self._mcap_path = mcap
            self._start_view(view, arm.scenarios)
            return
        if mcap is not None:
            raise SonicskinError("mcap= writes touches in the robot's frames, which an arm file gives its links: pass the "
                                 "arm (its arm.yaml, or the folder `sonicskin fit-svm --links` wrote) as the artifact")
        self._mcap_path = None
        self.links = None
        art = Path(artifact)
        if not (art / "skin.json").is_file():
            raise SonicskinError(f"{art} is not a sonicskin artifact (no skin.json there); create one with "
                                 f"`sonicskin fit-svm` or `sonicskin export`")
        the_rig = _load_config(Rig.load, rig) if rig is not None else None
        self.runtime = SkinRuntime(art, model, rig=the_rig)
        if device is None or device == "sim":
            from .sim import Scenario, Simulator, build_timeline

            sc = _load_config(Scenario.load, scenario)
            layout = sc.make_layout()
            if self.runtime.layout != layout:
                raise SonicskinError(f"the artifact knows {len(self.runtime.layout)} markers but scenario {sc.name!r} has "
                                     f"{len(layout)} in another layout; pass the scenario it was trained on (scenario=...)")
            live_sc = sc.replace(seed=sc.seed + 1000, sessions=1)
            the_rig = the_rig or self.runtime.rig
            self.source = SimulatedSource(Simulator(live_sc, the_rig), build_timeline(live_sc, the_rig), realtime=not fast,
                                          blocksize=blocksize)
        else:
            self.source = SoundDeviceSource(the_rig or self.runtime.rig, device, link=Link(tx=tx, rx=rx), blocksize=blocksize)
        self.loop = LiveLoop(self.runtime, self.source, emit=lambda line: None, on_event=self._on_event)
        self.loops = [self.loop]
        self._start_view(view, [("skin", live_sc)] if device in (None, "sim") else None)

    def _start_view(self, view, scenarios) -> None:
        """``view``: ``True`` (any free port) or a port: serve the live page (:mod:`sonicskin.view`); :attr:`view_url`."""
        self.view = self.view_url = None
        if view is None or view is False:
            return
        from .view import parse_view_port, view_loops

        self.view = view_loops(self.loops, scenarios=scenarios, port=parse_view_port(view))
        self.view_url = self.view.url

    def _on_event(self, ev: TouchEvent) -> None:
        if self._mcap is not None:
            self._mcap.write(ev)
        self._queue.put(ev)
        if self._user_cb is not None:
            self._user_cb(ev)

    def _run(self) -> None:
        try:
            from .live import run_loops

            if self._mcap_path is not None:
                import time

                from .rosbag import McapEventWriter

                self._mcap = McapEventWriter(self._mcap_path, t0_unix_s=time.time())
            with self.source:
                sums = run_loops(self.loops, self.source, duration_s=self.duration_s, watchdog_s=self.watchdog_s,
                                 stop=self._stop)
                self.summary = sums[0] if self.links is None else {lk.name: x for lk, x in zip(self.links, sums)}
        except BaseException as e:  # handed to the caller's thread
            self.error = e
        finally:
            if self._mcap is not None:
                self._mcap.close()  # complete however the run ended
            if self.view is not None:
                self.view.stop()
            self._queue.put(_END)

    # -- control -------------------------------------------------------------------------
    def start(self) -> Listener:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="sonicskin-listener", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> dict | None:
        """Stop and wait for the thread; returns the run's summary (as ``sonicskin live`` prints it)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
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
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        if exc[0] is None:
            self._raise()

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
    """Touch events of a skin as they happen: ``for ev in listen("artifacts/x", duration_s=5): ...``.

    Keywords as :class:`Listener`.  The run stops when the loop ends (``duration_s``, a finite
    simulated session) or when the caller leaves the loop (``break``); errors of the device are
    raised here.
    """
    lst = Listener(artifact, device=device, duration_s=duration_s, **kw)
    try:
        yield from lst
    finally:
        lst._stop.set()
        if lst._thread is not None:
            lst._thread.join(timeout=10)
